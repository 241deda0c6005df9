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

from pivotd.gimbal.kinematics import camera_position, joints_to_world_direction
from pivotd.sim.analysis import in_cone
from pivotd.viz.recording import Recording


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
    cams = np.array([camera_position(p, q, mount) for p, q in zip(run.pose_pos[i[keep]], quats, strict=True)])
    piv = np.array([joints_to_world_direction(a[0], a[1], q, mount) for a, q in zip(js.angles[keep], quats,
                                                                                    strict=True)])
    fwd = np.array([joints_to_world_direction(0.0, 0.0, q, mount) for q in quats])
    flt = cfg.map.filters
    alpha = cfg.pivot.half_angle
    points = run.landmarks
    seen = np.zeros(points.shape[0], bool)
    n_piv = np.zeros(keep.size, np.int64)
    n_fwd = np.zeros(keep.size, np.int64)
    if keep.size and points.shape[0]:
        tree = cKDTree(points)
        for k, near in enumerate(tree.query_ball_point(cams, flt.max_range)):
            near = np.asarray(near, dtype=np.int64)
            rel = points[near] - cams[k]
            vis = in_cone(rel, piv[k], alpha, flt.min_range, flt.max_range)
            seen[near[vis]] = True
            n_piv[k] = int(vis.sum())
            n_fwd[k] = int(in_cone(rel, fwd[k], alpha, flt.min_range, flt.max_range).sum())
    shape3 = (keep.size, 3)
    return Views(js.t[keep], cams.reshape(shape3), piv.reshape(shape3), fwd.reshape(shape3), n_piv, n_fwd, seen)
