"""Single-pose PIVOT: toy example, brute-force agreement, equivariance, weights and edge cases."""

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize, so3_exp
from pivotd.pivot.brute import brute_force_view
from pivotd.pivot.scenes import two_clusters
from pivotd.pivot.view import ViewOptions, optimize_view
from pivotd.pivot.visibility import hard_count


def _bearings(points):
    return normalize(points)


def _azimuth_deg(d):
    return float(np.degrees(np.arctan2(d[1], d[0])))


def _clustered(rng, n_clusters=4, per=80, spread=0.25):
    centres = normalize(rng.normal(size=(n_clusters, 3)))
    sizes = rng.integers(per // 2, per * 2, n_clusters)
    parts = [normalize(c + spread * rng.normal(size=(s, 3))) for c, s in zip(centres, sizes, strict=True)]
    return np.concatenate(parts)


def test_toy_example_without_fov_limit_points_between_the_clusters():
    scene = two_clusters()
    r = optimize_view(_bearings(scene.points), None, np.radians(89.0))
    assert abs(_azimuth_deg(r.direction)) < 20.0  # clusters sit at ±70°
    assert r.visible == 160


def test_toy_example_with_45_deg_turns_to_the_larger_cluster():
    scene = two_clusters()
    r = optimize_view(_bearings(scene.points), None, np.radians(45.0))
    assert abs(_azimuth_deg(r.direction) - 70.0) < 10.0
    assert r.visible == 100


def test_result_fields_are_consistent():
    rng = np.random.default_rng(0)
    B = _clustered(rng)
    alpha = np.radians(20)
    r = optimize_view(B, None, alpha)
    assert np.allclose(r.rotation @ [0, 0, 1], r.direction, atol=1e-12)
    assert np.allclose(r.rotation.T @ r.rotation, np.eye(3), atol=1e-9)
    assert r.visible == hard_count(r.direction, B, alpha)
    assert 0 < r.objective <= len(B)
    assert r.iterations > 0


def test_agrees_with_brute_force_on_small_random_scenes():
    ratios = []
    for seed in range(12):
        rng = np.random.default_rng(seed)
        B = _clustered(rng)
        alpha = np.radians(rng.uniform(10, 35))
        r = optimize_view(B, None, alpha)
        _, best = brute_force_view(B, None, alpha, 2.0)
        ratios.append(r.visible / best)
    assert min(ratios) >= 0.93
    assert np.mean(ratios) >= 0.99


def test_rotating_the_scene_rotates_the_answer():
    rng = np.random.default_rng(7)
    B = _clustered(rng, n_clusters=3)
    alpha = np.radians(20)
    r = optimize_view(B, None, alpha)
    for _ in range(3):
        Q = so3_exp(rng.normal(size=3))
        rq = optimize_view(B @ Q.T, None, alpha)
        assert rq.visible == pytest.approx(r.visible, abs=2)
        assert np.degrees(angle_between(rq.direction, Q @ r.direction)) < 2.0


def test_weights_move_the_answer_to_the_heavier_cluster():
    scene = two_clusters()
    B = _bearings(scene.points)
    w = np.ones(len(B))
    w[100:] = 5.0  # the 60 features of the smaller cluster now outweigh the 100 of the larger
    r = optimize_view(B, w, np.radians(45.0))
    assert abs(_azimuth_deg(r.direction) + 70.0) < 10.0
    r0 = optimize_view(B, np.where(np.arange(len(B)) < 100, 0.0, 1.0), np.radians(45.0))
    assert abs(_azimuth_deg(r0.direction) + 70.0) < 10.0


def test_zero_landmarks():
    r = optimize_view(np.zeros((0, 3)), None, 0.3)
    assert r.visible == 0 and r.objective == 0.0
    assert np.linalg.norm(r.direction) == pytest.approx(1.0)
    r = optimize_view(np.zeros((0, 3)), None, 0.3, init=np.array([0.0, 2.0, 0.0]))
    assert np.allclose(r.direction, [0, 1, 0])


def test_one_landmark_is_centred():
    d = normalize(np.array([0.3, -0.5, 0.8]))
    r = optimize_view(d[None], None, np.radians(10))
    assert r.visible == 1
    assert np.degrees(angle_between(r.direction, d)) < 10


def test_all_landmarks_behind_the_start():
    rng = np.random.default_rng(3)
    B = normalize(np.array([-1.0, 0.0, 0.0]) + 0.1 * rng.normal(size=(100, 3)))
    r = optimize_view(B, None, np.radians(30), init=np.array([1.0, 0.0, 0.0]))
    assert r.visible >= 98
    assert r.direction[0] < -0.9


def test_landmark_at_the_sensor_is_ignored():
    rng = np.random.default_rng(4)
    B = normalize(np.array([0.0, 1.0, 0.0]) + 0.1 * rng.normal(size=(50, 3)))
    B = np.vstack([B, np.zeros((3, 3))])
    r = optimize_view(B, None, np.radians(30))
    assert r.visible >= 48
    assert np.isfinite(r.direction).all()


@pytest.mark.parametrize("bad", [np.nan, np.inf])
def test_nan_input_raises_a_clear_error(bad):
    B = np.ones((5, 3))
    B[2, 1] = bad
    with pytest.raises(ValueError, match="row 2"):
        optimize_view(B, None, 0.3)
    with pytest.raises(ValueError, match="weights"):
        optimize_view(np.eye(3), np.array([1.0, bad, 1.0]), 0.3)
    with pytest.raises(ValueError, match="alpha"):
        optimize_view(np.eye(3), None, bad)


@pytest.mark.parametrize("alpha_deg", [0.5, 89.5])
def test_extreme_half_angles(alpha_deg):
    rng = np.random.default_rng(5)
    B = _clustered(rng, n_clusters=2, per=100, spread=0.1)
    alpha = np.radians(alpha_deg)
    r = optimize_view(B, None, alpha)
    assert np.isfinite(r.direction).all()
    _, best = brute_force_view(B, None, alpha, 1.0 if alpha_deg < 1 else 2.0)
    assert r.visible >= (0.97 * best if alpha_deg > 45 else max(1, 0.5 * best))


def test_alpha_outside_range_is_rejected():
    with pytest.raises(ValueError):
        optimize_view(np.eye(3), None, 0.0)
    with pytest.raises(ValueError):
        optimize_view(np.eye(3), None, np.pi)


def test_options_are_honoured():
    rng = np.random.default_rng(6)
    B = _clustered(rng)
    r = optimize_view(B, None, np.radians(20), options=ViewOptions(max_iterations=1, refine=1))
    assert r.iterations <= 1


def test_unnormalised_and_huge_bearings_give_the_unit_answer():
    rng = np.random.default_rng(8)
    B = _clustered(rng)
    alpha = np.radians(20)
    ref = optimize_view(B, None, alpha)
    for scale in (3.0, 1e30, 1e300):  # beyond float32's range the bearings are rescaled in float64 first
        r = optimize_view(B * scale, None, alpha)
        assert r.visible == ref.visible
        assert np.degrees(angle_between(r.direction, ref.direction)) < 1e-3


def test_rotation_is_the_optical_frame_of_the_direction():
    from pivotd.geometry import optical_frame_from_direction

    for d in ([0.0, 0.0, 1.0], [0.0, 0.0, -1.0], [0.3, -0.5, 0.8]):
        B = normalize(np.array(d) + 0.01 * np.random.default_rng(9).normal(size=(30, 3)))
        r = optimize_view(B, None, np.radians(10))
        assert np.allclose(r.rotation, optical_frame_from_direction(r.direction), atol=1e-9)
