"""Pinhole camera with a level roll: projection, line of sight and noisy landmark observations.

Camera frame: ROS optical (x right, y down, z forward). A world viewing direction ``d`` becomes the
camera-to-world rotation of :func:`pivotd.geometry.optical_frame_from_direction` (image up kept as close
to world +z as possible: roll level). Pixel (u, v) = (fx·x/z + cx, fy·y/z + cy).

What a frame sees (:func:`visible`): landmarks with depth in [min_depth, max_depth], inside the image,
whose line of sight is not blocked by the occupancy grid (:mod:`pivotd.maps.occlusion`), and — when the
landmark has a known surface normal — seen at most ``max_incidence_deg`` off that normal (features are
not matched at grazing angles). What the estimator gets (:func:`observe`): each visible landmark
detected with ``detection_probability``, pixel noise N(0, pixel_noise²) per axis, and
``outlier_ratio`` of the correspondences replaced by wrong matches (a random map landmark paired with
a random pixel). Landmark dropout (a share of the map missing for a whole run) is drawn once per run
by :func:`dropout_mask`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import optical_frame_from_direction
from pivotd.localization.stack import OccupancyGrid


@dataclass(frozen=True)
class CameraModel:
    """Pinhole intrinsics [px], depth range [m] and the observation model.

    cx, cy default to the image centre. detection_probability, outlier_ratio and dropout are shares in
    [0, 1]; pixel_noise is σ [px]; max_incidence_deg [deg] applies to landmarks with a known normal.
    """

    width: int = 640
    height: int = 480
    fx: float = 500.0
    fy: float = 500.0
    cx: float | None = None
    cy: float | None = None
    min_depth: float = 0.3
    max_depth: float = 10.0
    detection_probability: float = 0.9
    pixel_noise: float = 1.0
    outlier_ratio: float = 0.1
    dropout: float = 0.0
    max_incidence_deg: float | None = 75.0

    def __post_init__(self) -> None:
        if not (self.width > 0 and self.height > 0 and self.fx > 0 and self.fy > 0):
            raise InputError(f"camera: need positive image size and focal lengths, got {self.width}x{self.height}, "
                             f"fx={self.fx}, fy={self.fy}")
        if not 0 <= self.min_depth < self.max_depth:
            raise InputError(f"camera: need 0 ≤ min_depth < max_depth, got {self.min_depth}, {self.max_depth}")
        for name in ("detection_probability", "outlier_ratio", "dropout"):
            value = getattr(self, name)
            if not 0.0 <= value <= 1.0:
                raise InputError(f"camera: {name} must be in [0, 1], got {value}")
        if not self.pixel_noise >= 0:
            raise InputError(f"camera: pixel_noise must be ≥ 0 px, got {self.pixel_noise}")

    @property
    def principal_point(self) -> tuple[float, float]:
        """(cx, cy) [px]."""
        return (0.5 * self.width if self.cx is None else self.cx, 0.5 * self.height if self.cy is None else self.cy)

    @property
    def params(self) -> list[float]:
        """[fx, fy, cx, cy], the PINHOLE parameter order."""
        return [self.fx, self.fy, *self.principal_point]

    @property
    def half_fov(self) -> tuple[float, float]:
        """Horizontal and vertical half-angles of view [rad]."""
        cx, cy = self.principal_point
        return math.atan(max(cx, self.width - cx) / self.fx), math.atan(max(cy, self.height - cy) / self.fy)


def camera_rotation(direction: np.ndarray) -> np.ndarray:
    """Camera-to-world rotation(s) (..., 3, 3) for world optical axes ``direction`` (..., 3), roll level."""
    return optical_frame_from_direction(np.asarray(direction, float))


def image_coordinates(model: CameraModel, pc: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixel columns u (...,), rows v (...,) and the in-view mask (...,) of camera-frame points ``pc`` (..., 3).

    In view: depth within the depth range and the pixel inside the image (no occlusion test here).
    """
    z = pc[..., 2]
    safe = np.where(np.abs(z) < 1e-12, 1e-12, z)
    cx, cy = model.principal_point
    u = model.fx * pc[..., 0] / safe + cx
    v = model.fy * pc[..., 1] / safe + cy
    inside = ((z >= model.min_depth) & (z <= model.max_depth) & (u >= 0) & (u < model.width)
              & (v >= 0) & (v < model.height))
    return u, v, inside


def to_camera(R_wc: np.ndarray, centre: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Camera coordinates (N, 3), or (O, N, 3) for O rotations ``R_wc`` (O, 3, 3), of world ``points`` (N, 3)."""
    rel = np.asarray(points, float) - np.asarray(centre, float)
    R = np.asarray(R_wc, float)
    return rel @ R if R.ndim == 2 else np.einsum("nk,okj->onj", rel, R)


def project(model: CameraModel, R_wc: np.ndarray, centre: np.ndarray,
            points: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pixels (N, 2), depths (N,) [m] and the in-view mask (N,) of world ``points`` (N, 3) seen by a camera
    with camera-to-world rotation ``R_wc`` (3, 3) at ``centre`` (3,) [m] (see :func:`image_coordinates`)."""
    pc = to_camera(R_wc, centre, points)
    u, v, inside = image_coordinates(model, pc)
    return np.stack([u, v], axis=1), pc[:, 2], inside


def in_view_counts(model: CameraModel, R_wc: np.ndarray, centre: np.ndarray, points: np.ndarray) -> np.ndarray:
    """Landmarks (O,) of ``points`` (N, 3) inside the image of each orientation ``R_wc`` (O, 3, 3)."""
    return image_coordinates(model, to_camera(R_wc, centre, points))[2].sum(axis=1)


def line_of_sight(model: CameraModel, grid: OccupancyGrid | None, centre: np.ndarray, points: np.ndarray,
                  normals: np.ndarray | None = None) -> np.ndarray:
    """Indices (K,) of ``points`` (N, 3) that some orientation of a camera at ``centre`` (3,) could see.

    Within ``max_depth`` of the centre and at least ``min_depth`` away, facing the camera within the
    incidence limit when ``normals`` (N, 3) are given, and not occluded by ``grid``. This is what the
    camera's position alone decides; :func:`visible` adds the orientation.
    """
    rel = np.asarray(points, float) - np.asarray(centre, float)
    dist = np.sqrt(np.einsum("ij,ij->i", rel, rel))
    ok = (dist <= model.max_depth) & (dist >= model.min_depth)
    if normals is not None and model.max_incidence_deg is not None:
        cos_inc = -np.einsum("ij,ij->i", rel, normals) / np.maximum(dist, 1e-12)
        ok &= cos_inc >= math.cos(math.radians(model.max_incidence_deg))
    idx = np.flatnonzero(ok)
    if grid is not None and idx.size:
        idx = idx[~grid.occluded(np.asarray(centre, float), np.asarray(points, float)[idx])]
    return idx


def visible(model: CameraModel, R_wc: np.ndarray, centre: np.ndarray, points: np.ndarray,
            sight: np.ndarray) -> np.ndarray:
    """Indices (K,) of the landmarks among ``sight`` (from :func:`line_of_sight`) inside the image."""
    _, _, inside = project(model, R_wc, centre, points[sight])
    return sight[inside]


def dropout_mask(model: CameraModel, count: int, rng: np.random.Generator) -> np.ndarray:
    """(count,) bool: landmarks present in this run (each missing with probability ``dropout``)."""
    return rng.random(count) >= model.dropout


def observe(model: CameraModel, R_wc: np.ndarray, centre: np.ndarray, points: np.ndarray, seen: np.ndarray,
            rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """Noisy 2D–3D correspondences of one frame: pixels (K, 2) and map points (K, 3).

    ``seen``: indices of the landmarks in view (present, unoccluded, in the image). Each is detected with
    ``detection_probability`` and perturbed by pixel noise; then ``outlier_ratio`` of the matches are
    wrong (a random map point paired with a uniformly random pixel). Shapes are (0, 2), (0, 3) when empty.
    """
    det = seen[rng.random(seen.size) < model.detection_probability]
    X = np.asarray(points, float)[det]
    uv, _, _ = project(model, R_wc, centre, X)
    uv = uv + rng.normal(0.0, model.pixel_noise, uv.shape) if model.pixel_noise > 0 else uv
    n = det.size
    if n and model.outlier_ratio > 0:
        bad = rng.random(n) < model.outlier_ratio
        k = int(bad.sum())
        if k:
            X[bad] = np.asarray(points, float)[rng.integers(0, len(points), k)]
            uv[bad] = rng.random((k, 2)) * [model.width, model.height]
    return uv, X
