"""Smooth visibility, its gradient on SO(3), hard counts and k_s (paper eqs. 5–12)."""

import warnings

import numpy as np
import pytest

from pivotd.geometry import normalize, optical_frame_from_direction, so3_exp
from pivotd.pivot.visibility import gradient, hard_count, ks_from_width, objective, smooth_visibility


def _scene(rng, n=200):
    bearings = normalize(rng.normal(size=(n, 3)) + np.array([2.0, 0.5, 0.0]))
    return bearings, rng.uniform(0.2, 2.0, n)


@pytest.mark.parametrize("seed", range(5))
def test_gradient_matches_finite_difference_along_random_tangents(seed):
    rng = np.random.default_rng(seed)
    bearings, weights = _scene(rng)
    c = normalize(np.array([1.0, 0.2, -0.1]) + 0.3 * rng.normal(size=3))
    alpha, ks = np.radians(25.0), ks_from_width(np.radians(25.0), np.radians(6.0))
    J = gradient(c, bearings, weights, alpha, ks)
    for _ in range(5):
        omega = np.cross(c, rng.normal(size=3))  # rotations about axes ⟂ c move the axis
        h = 1e-6
        f_plus = objective(so3_exp(h * omega) @ c, bearings, weights, alpha, ks)
        f_minus = objective(so3_exp(-h * omega) @ c, bearings, weights, alpha, ks)
        fd = (f_plus - f_minus) / (2 * h)
        assert J @ omega == pytest.approx(fd, rel=1e-5, abs=1e-6)


def test_gradient_is_tangent():
    rng = np.random.default_rng(1)
    bearings, weights = _scene(rng)
    for _ in range(20):
        c = normalize(rng.normal(size=3))
        J = gradient(c, bearings, weights, np.radians(20), 50.0)
        assert abs(J @ c) < 1e-9 * max(1.0, np.linalg.norm(J))
        assert np.linalg.norm(J) > 0


def test_exponential_updates_keep_a_rotation_for_thousands_of_steps():
    rng = np.random.default_rng(2)
    bearings, weights = _scene(rng, 300)
    R = optical_frame_from_direction(np.array([0.0, 0.0, 1.0]))
    alpha = np.radians(15)
    ks = ks_from_width(alpha, np.radians(3))
    for _ in range(5000):
        J = gradient(R[:, 2], bearings, weights, alpha, ks)
        R = so3_exp(J / (np.pi * len(bearings))) @ R  # eq. 13 with ε = 1/(nπ)
    assert np.allclose(R.T @ R, np.eye(3), atol=1e-9)
    assert np.linalg.det(R) == pytest.approx(1.0, abs=1e-9)
    # and it climbed: the final axis sees more than the start
    assert hard_count(R[:, 2], bearings, alpha) > hard_count(np.array([0.0, 0.0, 1.0]), bearings, alpha)


def test_ks_from_width_sets_the_transition_band():
    alpha, width = np.radians(20), np.radians(4)
    ks = ks_from_width(alpha, width)
    inner = smooth_visibility(np.cos(alpha - width / 2), alpha, ks)
    outer = smooth_visibility(np.cos(alpha + width / 2), alpha, ks)
    assert inner == pytest.approx(1 / (1 + np.exp(-2)), abs=0.02)
    assert outer == pytest.approx(1 / (1 + np.exp(2)), abs=0.02)
    assert smooth_visibility(np.cos(alpha), alpha, ks) == pytest.approx(0.5)
    with pytest.raises(ValueError):
        ks_from_width(alpha, 0.0)


def test_sharp_sigmoid_does_not_overflow():
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        v = smooth_visibility(np.array([-1.0, 0.0, 1.0]), np.radians(10), 1e6)
    assert np.array_equal(v, [0.0, 0.0, 1.0])


def test_hard_count_counts_the_cone_boundary_inclusively():
    alpha = np.radians(30)
    b = np.array([[1.0, 0, 0], [np.cos(alpha), np.sin(alpha), 0], [np.cos(0.6), -np.sin(0.6), 0], [-1.0, 0, 0]])
    assert hard_count(np.array([1.0, 0, 0]), b, alpha) == 2


def test_weights_scale_the_objective():
    rng = np.random.default_rng(3)
    bearings, _ = _scene(rng, 50)
    c = np.array([1.0, 0, 0])
    f1 = objective(c, bearings, None, 0.4, 30.0)
    f2 = objective(c, bearings, np.full(50, 2.0), 0.4, 30.0)
    assert f2 == pytest.approx(2 * f1)
    with pytest.raises(ValueError):
        objective(c, bearings, np.ones(3), 0.4, 30.0)
