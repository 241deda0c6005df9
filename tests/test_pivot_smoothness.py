"""The smoothness term's pair value (pivotd.pivot.smoothness): the paper's c·c' without a knee, linear in the step
beyond it, and the trajectory optimizer with a knee."""

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize
from pivotd.pivot.smoothness import pair_slope, pair_value, path_value
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory, trajectory_problem


def _cost(deg, knee_deg):
    return 1.0 - pair_value(np.cos(np.radians(deg)), np.radians(knee_deg))


def test_without_a_knee_the_value_is_the_cosine():
    x = np.linspace(-1, 1, 11)
    assert np.array_equal(pair_value(x, 0.0), x)
    assert pair_slope(x, 0.0) == 1.0


@pytest.mark.parametrize("knee_deg", [0.5, 1.0, 10.0])
def test_small_steps_cost_as_the_paper_and_large_ones_in_proportion_to_their_size(knee_deg):
    small = knee_deg / 20
    assert _cost(small, knee_deg) == pytest.approx(1 - np.cos(np.radians(small)), rel=2e-3)
    big = 30 * knee_deg
    if big < 150:
        # beyond the knee doubling the step doubles the cost (the paper's term: ×4)
        assert _cost(2 * big, knee_deg) / _cost(big, knee_deg) == pytest.approx(
            2 * np.sin(np.radians(big)) / np.sin(np.radians(big / 2)) / 2, rel=0.05)
        # one turn of 2Δ costs about what two of Δ cost
        assert _cost(2 * big, knee_deg) == pytest.approx(2 * _cost(big, knee_deg), rel=0.1)
    assert np.all(np.diff(_cost(np.linspace(0, 180, 361), knee_deg)) > 0)  # monotone in the step


@pytest.mark.parametrize("knee_deg", [0.5, 3.0, 45.0])
def test_slope_is_the_derivative_of_the_value(knee_deg):
    knee = np.radians(knee_deg)
    x = np.cos(np.radians(np.array([0.1, 1.0, 5.0, 30.0, 90.0, 170.0])))
    h = 1e-7
    numeric = (pair_value(x + h, knee) - pair_value(x - h, knee)) / (2 * h)
    assert np.allclose(pair_slope(x, knee), numeric, rtol=1e-5)
    assert np.all((pair_slope(x, knee) > 0) & (pair_slope(x, knee) <= 1))


def test_path_value_sums_the_pairs():
    rng = np.random.default_rng(0)
    C = normalize(rng.normal(size=(6, 3)))
    knee = np.radians(2.0)
    want = sum(pair_value(float(C[i] @ C[i + 1]), knee) for i in range(5))
    assert path_value(C, knee) == pytest.approx(want, rel=1e-12)
    assert path_value(C, 0.0) == pytest.approx(float(np.sum(C[1:] * C[:-1])), rel=1e-12)


def _two_patches():
    """A 30 m straight path; a dense patch 3 m to the left along its first half, another 3 m to the right along
    its second half, and a sparse band of landmarks ahead all along: the best plan holds the left patch, turns
    about 180° where the right one starts, and holds that."""
    rng = np.random.default_rng(5)
    left = np.c_[rng.uniform(0, 15, 1500), np.full(1500, 3.0), rng.uniform(-1, 1, 1500)]
    right = np.c_[rng.uniform(15, 30, 1500), np.full(1500, -3.0), rng.uniform(-1, 1, 1500)]
    ahead = np.c_[np.full(60, 40.0), rng.uniform(-8, 8, 60), rng.uniform(-1, 1, 60)]
    pts = np.vstack([left, right, ahead])
    way = np.c_[np.linspace(0, 30, 61), np.zeros(61), np.zeros(61)]
    return pts, way


def test_with_a_knee_the_plan_turns_at_once_where_the_view_changes_and_sees_more():
    """The paper's term spreads the 180° turn over many waypoints, through views of neither patch; with a 1° knee
    the plan makes the turn in a few steps and sees more landmarks in total."""
    pts, way = _two_patches()
    alpha = np.radians(30)
    plain = optimize_trajectory(pts, way, alpha, 0.6, options=TrajectoryOptions.paper(distance_weights=False))
    knee = optimize_trajectory(pts, way, alpha, 0.6,
                               options=TrajectoryOptions.paper(distance_weights=False, smooth_knee_deg=1.0))

    def turning(C):  # waypoints whose step exceeds 5°
        return int(np.count_nonzero(np.degrees(angle_between(C[1:], C[:-1])) > 5.0))

    assert knee.visible.sum() > 1.05 * plain.visible.sum(), (knee.visible.sum(), plain.visible.sum())
    assert turning(knee.directions) < turning(plain.directions), (turning(knee.directions),
                                                                   turning(plain.directions))


@pytest.mark.parametrize("knee_deg", [0.0, 2.0])
def test_the_objective_adds_the_pairs_and_the_anchor_pair(knee_deg):
    rng = np.random.default_rng(0)
    T = rng.normal(size=(6, 3))
    P = T[rng.integers(0, 6, 300)] + 4.0 * normalize(rng.normal(size=(300, 3)))
    C = normalize(rng.normal(size=(6, 3)))
    anchor = normalize(rng.normal(size=3))
    opts = TrajectoryOptions.paper(smooth_knee_deg=knee_deg)
    paired = trajectory_problem(P, T, np.radians(30), 0.6, options=opts)
    doubled = trajectory_problem(P, T, np.radians(30), 1.2, options=opts)
    anchored = trajectory_problem(P, T, np.radians(30), 0.6, anchor=anchor, options=opts)
    (v1, f1), (v2, f2), (v3, f3) = paired.judge(C), anchored.judge(C), doubled.judge(C)
    assert np.array_equal(v1, v2) and np.array_equal(v1, v3) and v1.sum() > 0  # the same visible counts
    knee, smooth = np.radians(knee_deg), paired.smooth
    assert smooth > 0 and doubled.smooth == pytest.approx(2 * smooth)
    assert f3 - f1 == pytest.approx(smooth * path_value(C, knee), rel=1e-9)  # λκ Σ v(c_{i+1}·c_i)
    assert f2 - f1 == pytest.approx(smooth * pair_value(float(anchor @ C[0]), knee), rel=1e-9)
