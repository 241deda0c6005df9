"""PnP + RANSAC (poselib) recovers known camera poses; pose errors are measured against ground truth."""

import numpy as np
import pytest

from pivotd.localization.camera import CameraModel, camera_rotation, observe, project, visible
from pivotd.localization.estimator import PoseEstimate, estimate_pose, pose_error

CAM = CameraModel(detection_probability=1.0, pixel_noise=0.0, outlier_ratio=0.0)


def _scene(seed: int):
    rng = np.random.default_rng(seed)
    centre = rng.uniform(-2, 2, 3)
    d = rng.normal(size=3)
    d /= np.linalg.norm(d)
    R = camera_rotation(d)
    pc = np.column_stack([rng.uniform(-3, 3, 150), rng.uniform(-2, 2, 150), rng.uniform(2, 9, 150)])
    pts = centre + pc @ R.T
    return R, centre, pts


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_clean_correspondences_give_the_exact_pose(seed):
    R, c, pts = _scene(seed)
    uv, _, inside = project(CAM, R, c, pts)
    est = estimate_pose(CAM, uv[inside], pts[inside], seed=seed)
    dt, dr = pose_error(est, R, c)
    assert est.inliers == int(inside.sum())
    assert dt < 1e-6 and dr < 1e-5


def test_noise_and_thirty_percent_outliers_stay_accurate():
    R, c, pts = _scene(7)
    cam = CameraModel(detection_probability=1.0, pixel_noise=0.5, outlier_ratio=0.3)
    seen = visible(cam, R, c, pts, np.arange(len(pts)))
    uv, X = observe(cam, R, c, pts, seen, np.random.default_rng(3))
    dt, dr = pose_error(estimate_pose(cam, uv, X, seed=3), R, c)
    assert dt < 0.05 and dr < 0.5


def test_too_few_correspondences_give_no_pose_and_infinite_error():
    R, c, pts = _scene(0)
    uv, _, inside = project(CAM, R, c, pts)
    est = estimate_pose(CAM, uv[inside][:5], pts[inside][:5], seed=0)
    assert est.R_wc is None
    assert pose_error(est, R, c) == (float("inf"), float("inf"))


def test_pose_error_measures_offsets():
    R, c, _ = _scene(0)
    rot = camera_rotation(np.array([np.cos(0.1), np.sin(0.1), 0.0])) @ camera_rotation(np.array([1.0, 0, 0])).T
    est = PoseEstimate(rot @ R, c + np.array([0.3, 0.4, 0.0]), 50)
    dt, dr = pose_error(est, R, c)
    assert dt == pytest.approx(0.5)
    assert dr == pytest.approx(np.degrees(0.1), rel=1e-6)
