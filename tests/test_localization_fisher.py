"""The Fisher-information baseline: exact pose information, and it prefers spread-out landmarks."""

from pathlib import Path

import numpy as np

from pivotd.geometry import so3_exp
from pivotd.localization.camera import CameraModel, camera_rotation, project
from pivotd.localization.fisher import best_view, information_score, pose_information
from pivotd.localization.policies import FisherPolicy
from pivotd.localization.scenes import LocScene
from pivotd.localization.stack import load_config
from pivotd.localization.world import World

CAM = CameraModel()
DEMO = Path(__file__).resolve().parent.parent / "config" / "demo.yaml"


def _pixels(R_wc, centre, pts, xi):
    """Pixels after perturbing the camera-frame points by (δθ, δt): p' = exp(δθ)·p + δt."""
    pc = (pts - centre) @ R_wc
    pc = pc @ so3_exp(xi[:3]).T + xi[3:]
    return project(CAM, np.eye(3), np.zeros(3), pc)[0]


def test_information_matches_a_numerical_jacobian():
    rng = np.random.default_rng(0)
    R = camera_rotation(np.array([0.8, 0.6, 0.1]))
    c = np.array([0.5, -0.2, 0.3])
    pts = c + np.column_stack([rng.uniform(-2, 2, 40), rng.uniform(-1.5, 1.5, 40), rng.uniform(3, 8, 40)]) @ R.T
    assert project(CAM, R, c, pts)[2].all()
    J = np.zeros((80, 6))
    h = 1e-6
    for k in range(6):
        e = np.zeros(6)
        e[k] = h
        J[:, k] = ((_pixels(R, c, pts, e) - _pixels(R, c, pts, -e)) / (2 * h)).ravel()
    info = pose_information(CAM, R[None], c, pts)[0]
    np.testing.assert_allclose(info, J.T @ J, rtol=1e-5, atol=1e-7 * np.abs(J.T @ J).max())


def _spread_and_clump(n: int = 30, seed: int = 0):
    rng = np.random.default_rng(seed)
    spread = np.column_stack([rng.uniform(-2.5, 2.5, n), rng.uniform(3, 9, n), rng.uniform(-1.5, 1.5, n)])
    clump = np.array([0.0, -5.0, 0.0]) + rng.normal(0, 0.05, (n, 3))
    return spread, clump


def test_spread_out_landmarks_score_higher_than_a_clump_of_the_same_count():
    spread, clump = _spread_and_clump()
    R = camera_rotation(np.array([[0.0, 1.0, 0.0], [0.0, -1.0, 0.0]]))
    pts = np.concatenate([spread, clump])
    in_view = [int(project(CAM, r, np.zeros(3), pts)[2].sum()) for r in R]
    assert in_view == [30, 30]
    best, scores = best_view(CAM, R, np.zeros(3), pts)
    assert best == 0
    assert scores[0] > scores[1] + 5.0
    assert information_score(pose_information(CAM, R[:1], np.zeros(3), clump)) < scores[0]


def test_fisher_policy_turns_to_the_spread_out_side():
    spread, clump = _spread_and_clump(40, seed=3)
    pts = np.concatenate([spread, clump]) + np.array([0.0, 0.0, 0.5])
    route = np.array([[-0.25, 0.0, 0.3], [0.25, 0.0, 0.3], [0.75, 0.0, 0.3]])
    scene = LocScene("spread_vs_clump", pts, None, pts[:1] + 100.0, 0.2, route, None, np.array([0.0, 1.0, 2.0]))
    world = World(load_config(DEMO), scene, CAM)
    policy = FisherPolicy(world)
    centre = world.camera_centres(*world.body_poses(np.array([0.5])))[0]
    d = policy.direction_at(centre, world.body_poses(np.array([0.5]))[1][0], "test")
    assert d[1] > 0.7  # towards +y (the spread-out landmarks), not −y (the clump)


def test_information_of_many_views_sums_only_the_landmarks_in_each_image():
    """Views that see different subsets (and one that sees nothing): each view's information equals the
    one computed from exactly its in-image landmarks."""
    rng = np.random.default_rng(5)
    pts = rng.uniform(-6, 6, (300, 3))
    d = rng.normal(size=(12, 3))
    R = camera_rotation(np.vstack([d / np.linalg.norm(d, axis=1, keepdims=True), [[0.0, 0.0, 1.0]]]))
    far = pts * 100.0  # beyond the depth range: no view sees them
    info = pose_information(CAM, R, np.zeros(3), np.vstack([pts, far]))
    for o in range(R.shape[0]):
        seen = pts[project(CAM, R[o], np.zeros(3), pts)[2]]
        ref = pose_information(CAM, R[o][None], np.zeros(3), seen)[0] if len(seen) else np.zeros((6, 6))
        np.testing.assert_allclose(info[o], ref, rtol=1e-10, atol=1e-9)
        np.testing.assert_allclose(info[o], info[o].T)
    assert np.count_nonzero([np.any(i) for i in info]) >= 6
