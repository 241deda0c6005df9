"""Absolute pose from 2D–3D correspondences: PnP + RANSAC with poselib, and pose errors.

poselib is optional (the ``bench`` extra); :func:`require_poselib` reports its absence in one line.
Pose convention: camera-to-world rotation R_wc (3, 3) and camera centre c (3,) [m]; poselib's pose maps
world to camera, x_c = R·X + t, so R = R_wcᵀ and c = −Rᵀt.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
from pivotd.localization.camera import CameraModel

MIN_CORRESPONDENCES = 4  # P3P needs 3 plus one to disambiguate


def require_poselib():
    """The poselib module, or InputError naming the extra that provides it."""
    try:
        import poselib
    except ImportError:
        raise InputError("poselib is not installed: pip install 'pivotd[bench]'") from None
    return poselib


@dataclass(frozen=True)
class PoseEstimate:
    """R_wc (3, 3), centre (3,) [m], RANSAC inliers; None fields when no pose was found."""

    R_wc: np.ndarray | None
    centre: np.ndarray | None
    inliers: int


@dataclass(frozen=True)
class RansacSettings:
    """Inlier threshold [px], minimum inliers for an accepted pose, iteration bounds."""

    max_reproj_error: float = 4.0
    min_inliers: int = 8
    min_iterations: int = 100
    max_iterations: int = 10000


def estimate_pose(model: CameraModel, uv: np.ndarray, X: np.ndarray, seed: int,
                  settings: RansacSettings | None = None) -> PoseEstimate:
    """PnP + RANSAC (with non-linear refinement) on pixels ``uv`` (K, 2) and map points ``X`` (K, 3)."""
    st = settings or RansacSettings()
    if uv.shape[0] < max(MIN_CORRESPONDENCES, st.min_inliers):
        return PoseEstimate(None, None, 0)
    poselib = require_poselib()
    camera = {"model": "PINHOLE", "width": model.width, "height": model.height, "params": model.params}
    ransac = {"max_reproj_error": st.max_reproj_error, "seed": int(seed) & 0x7FFFFFFF,
              "min_iterations": st.min_iterations, "max_iterations": st.max_iterations}
    pose, info = poselib.estimate_absolute_pose(np.ascontiguousarray(uv, float), np.ascontiguousarray(X, float),
                                                camera, ransac, {})
    inliers = int(info.get("num_inliers", 0))
    if inliers < st.min_inliers:
        return PoseEstimate(None, None, inliers)
    R = np.asarray(pose.R, float)
    t = np.asarray(pose.t, float)
    return PoseEstimate(R.T, -R.T @ t, inliers)


def pose_error(est: PoseEstimate, R_wc: np.ndarray, centre: np.ndarray) -> tuple[float, float]:
    """Translation error [m] and rotation error [deg] against the ground truth (inf when no pose)."""
    if est.R_wc is None:
        return float("inf"), float("inf")
    dt = float(np.linalg.norm(est.centre - centre))
    cos = (np.trace(est.R_wc.T @ R_wc) - 1.0) / 2.0
    return dt, float(np.degrees(np.arccos(np.clip(cos, -1.0, 1.0))))
