"""Where the camera looked during a recorded run, and what it saw, next to a forward-facing camera.

Each measured joint state with a fresh pose (at most ``control.pose_timeout_s`` old) is one frame: the camera
position and optical axis through the gimbal mount, and the same camera fixed at pan = tilt = 0. Landmarks
count as visible inside the cone of half-angle α = fov/2 at a distance within ``map.filters``' range (the
paper's hard count). Candidates per frame come from a k-d tree ball of the maximum range, so the cost follows
the landmarks near the route, not the whole map.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.spatial import cKDTree

from pivotd.geometry import pan_tilt_to_direction
from pivotd.gimbal.kinematics import base_from_world, camera_position
from pivotd.sim.analysis import in_cone
from pivotd.viz.recording import Recording

_FRAMES_PER_BATCH = 256  # frames whose candidate pairs are tested together (bounds the temporaries)


@dataclass(frozen=True)
class Views:
    """Frames (F,): times t [s], camera positions (F, 3) [m], optical axes (F, 3) of the gimbal (``pivot``) and
    of a forward-facing camera (``forward``), visible counts of each (F,), and ``seen`` (M,) bool: landmarks
    inside the gimbal camera's FoV in at least one frame."""

    t: np.ndarray
    cameras: np.ndarray
    pivot: np.ndarray
    forward: np.ndarray
    n_pivot: np.ndarray
    n_forward: np.ndarray
    seen: np.ndarray


def camera_views(run: Recording, max_frames: int = 1500) -> Views:
    """The frames of ``run`` (every measured joint state with a fresh pose, thinned evenly to ``max_frames``)."""
    cfg = run.cfg
    js = run.measured
    i = np.searchsorted(run.pose_t, js.t, side="right") - 1
    fresh = (i >= 0) & (js.t - run.pose_t[np.maximum(i, 0)] <= cfg.control.pose_timeout_s)
    keep = np.flatnonzero(fresh)
    if keep.size > max_frames:
        keep = keep[np.linspace(0, keep.size - 1, max_frames).round().astype(int)]
    mount = cfg.gimbal.mount
    quats = run.pose_quat[i[keep]]
    cams = camera_position(run.pose_pos[i[keep]], quats, mount).reshape(-1, 3)  # batched: (F, 3)
    to_world = base_from_world(quats, mount).reshape(-1, 3, 3)  # world -> base; its transpose maps back
    piv = np.einsum("fji,fj->fi", to_world, pan_tilt_to_direction(js.angles[keep, 0], js.angles[keep, 1]))
    fwd = np.einsum("fji,fj->fi", to_world, pan_tilt_to_direction(np.zeros(keep.size), np.zeros(keep.size)))
    flt = cfg.map.filters
    alpha = cfg.pivot.half_angle
    points = run.landmarks
    seen = np.zeros(points.shape[0], bool)
    n_piv = np.zeros(keep.size, np.int64)
    n_fwd = np.zeros(keep.size, np.int64)
    if keep.size and points.shape[0]:
        tree = cKDTree(points)
        for start in range(0, keep.size, _FRAMES_PER_BATCH):
            frames = np.arange(start, min(start + _FRAMES_PER_BATCH, keep.size))
            pairs = cKDTree(cams[frames]).sparse_distance_matrix(tree, flt.max_range, output_type="ndarray")
            frame_of = start + pairs["i"].astype(np.int64)  # one (frame, landmark) pair per candidate
            idx = pairs["j"].astype(np.int64)
            rel = (points[idx] - cams[frame_of])[:, None, :]
            vis = in_cone(rel, piv[frame_of], alpha, flt.min_range, flt.max_range)[:, 0]
            vis_fwd = in_cone(rel, fwd[frame_of], alpha, flt.min_range, flt.max_range)[:, 0]
            seen[idx[vis]] = True
            n_piv[frames] = np.bincount(frame_of[vis] - start, minlength=frames.size)
            n_fwd[frames] = np.bincount(frame_of[vis_fwd] - start, minlength=frames.size)
    shape3 = (keep.size, 3)
    return Views(js.t[keep], cams.reshape(shape3), piv.reshape(shape3), fwd.reshape(shape3), n_piv, n_fwd, seen)
