"""Spread weights (pivotd.pivot.weights): dense clumps saturate, spread landmarks count fully."""

import math

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize
from pivotd.pivot.trajectory import optimize_trajectory
from pivotd.pivot.weights import SpreadSettings, cell_keys, spread_weights, waypoint_spread_weights

SETTINGS = SpreadSettings(cell=math.radians(10.0), depth_ratio=2.0, saturation=2.0)


def cone_points(rng, axis, half_deg, n, depth=(2.0, 8.0)):
    """n landmarks (n, 3) [m] uniformly in a cone of half-angle ``half_deg`` about ``axis``, at random depths."""
    axis = normalize(np.asarray(axis, float))
    helper = np.array([0.0, 0.0, 1.0]) if abs(axis[2]) < 0.9 else np.array([1.0, 0.0, 0.0])
    u = normalize(np.cross(axis, helper))
    v = np.cross(axis, u)
    cos_t = rng.uniform(math.cos(math.radians(half_deg)), 1.0, n)
    sin_t = np.sqrt(1 - cos_t**2)
    phi = rng.uniform(0, 2 * math.pi, n)
    dirs = cos_t[:, None] * axis + sin_t[:, None] * (np.cos(phi)[:, None] * u + np.sin(phi)[:, None] * v)
    return dirs * rng.uniform(*depth, n)[:, None]


def test_a_spread_set_outweighs_a_clump_of_the_same_count():
    rng = np.random.default_rng(0)
    clump = cone_points(rng, [1, 0.2, 0], 1.0, 200, depth=(3.0, 3.5))
    spread = cone_points(rng, [1, 0.2, 0], 30.0, 200)
    wc, ws = spread_weights(clump, SETTINGS), spread_weights(spread, SETTINGS)
    assert wc.shape == ws.shape == (200,)
    assert np.all((wc > 0) & (wc <= 1)) and np.all((ws > 0) & (ws <= 1))
    # the clump spans at most a few cells (≤ 2 × 2 bearing cells × 1 shell), each contributing ≤ k = 2
    assert wc.sum() <= 4 * SETTINGS.saturation + 1e-9
    assert ws.sum() > 10 * wc.sum()


def test_sparse_landmarks_keep_their_full_weight_and_a_cell_contributes_at_most_k():
    # one landmark per 30° of azimuth on a ring at 4 m: every landmark alone in its cell
    az = np.radians(np.arange(0, 360, 30) + 3.0)
    ring = 4.0 * np.column_stack([np.cos(az), np.sin(az), np.zeros_like(az)])
    assert np.array_equal(spread_weights(ring, SETTINGS), np.ones(12))
    # 50 coincident-ish landmarks in one cell: total weight = k, shared equally
    rng = np.random.default_rng(1)
    blob = np.array([3.0, 0.4, 0.2]) + rng.normal(0, 1e-3, (50, 3))
    assert np.unique(cell_keys(blob, SETTINGS)).size == 1
    w = spread_weights(blob, SETTINGS)
    assert w.sum() == pytest.approx(SETTINGS.saturation) and np.ptp(w) == 0
    # depth shells: the same bearing at 1 m and at 5 m are different cells
    near_far = np.array([[1.0, 0.1, 0.0], [5.0, 0.5, 0.0]])
    k = cell_keys(near_far, SETTINGS)
    assert k[0] != k[1]


def test_weights_do_not_depend_on_the_order():
    rng = np.random.default_rng(2)
    pts = np.vstack([cone_points(rng, [0, 1, 0], 2.0, 80), cone_points(rng, [1, 0, 0.3], 40.0, 120)])
    w = spread_weights(pts, SETTINGS)
    perm = rng.permutation(pts.shape[0])
    assert np.array_equal(spread_weights(pts[perm], SETTINGS), w[perm])


def test_waypoint_weights_read_only_the_retained_landmarks():
    rng = np.random.default_rng(3)
    cams = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0]])
    pts = cone_points(rng, [1, 0, 0], 30.0, 300) + np.array([2.0, 0.0, 0.0])
    retained = [np.arange(0, 300, 2), np.arange(100, 250)]
    w = waypoint_spread_weights(pts, cams, retained, SETTINGS)
    for i, r in enumerate(retained):
        assert np.array_equal(w[i], spread_weights(pts[r] - cams[i], SETTINGS))
    # landmarks that no waypoint retains change nothing, however many and wherever they are
    more = np.vstack([pts, cone_points(rng, [1, 0, 0], 3.0, 5000) + np.array([2.0, 0.0, 0.0])])
    w2 = waypoint_spread_weights(more, cams, retained, SETTINGS)
    assert all(np.array_equal(a, b) for a, b in zip(w, w2, strict=True))


def test_settings_are_checked():
    for bad in (dict(cell=0.0), dict(cell=4.0), dict(cell=0.1, depth_ratio=1.0),
                dict(cell=0.1, saturation=0.0), dict(cell=float("nan"))):
        with pytest.raises(ValueError):
            SpreadSettings(**bad)


def clump_or_spread_scene():
    """Three waypoints along +x; a dense 2° clump of 240 landmarks to the left (+y), 80 landmarks spread over
    a 25° cone to the right (−y): a count looks left, a spread-aware weighting looks right."""
    rng = np.random.default_rng(4)
    wps = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.0, 0.0]])
    clump = cone_points(rng, [0, 1, 0], 2.0, 240, depth=(4.0, 4.5)) + wps[1]
    spread = cone_points(rng, [0, -1, 0], 25.0, 80, depth=(2.0, 8.0)) + wps[1]
    return wps, np.vstack([clump, spread])


def test_optimizer_follows_the_spread_set_with_spread_weights():
    wps, pts = clump_or_spread_scene()
    retained = [np.arange(pts.shape[0])] * 3
    alpha = math.radians(30.0)
    plain = optimize_trajectory(pts, wps, alpha, 0.6, retained=retained)
    pw = waypoint_spread_weights(pts, wps, retained, SETTINGS)
    spread = optimize_trajectory(pts, wps, alpha, 0.6, retained=retained, pair_weights=pw)
    assert angle_between(plain.directions[1], np.array([0.0, 1.0, 0.0])) < math.radians(35)
    assert angle_between(spread.directions[1], np.array([0.0, -1.0, 0.0])) < math.radians(35)
    # all-ones factors are the plain problem
    ones = optimize_trajectory(pts, wps, alpha, 0.6, retained=retained,
                               pair_weights=[np.ones(len(r)) for r in retained])
    assert np.allclose(ones.directions, plain.directions)


def test_pair_weights_are_checked():
    wps, pts = clump_or_spread_scene()
    retained = [np.arange(10)] * 3
    with pytest.raises(ValueError, match="pair_weights"):
        optimize_trajectory(pts, wps, 0.5, 0.6, retained=retained, pair_weights=[np.ones(10)] * 2)
    with pytest.raises(ValueError, match=r"pair_weights\[1\]"):
        optimize_trajectory(pts, wps, 0.5, 0.6, retained=retained, pair_weights=[np.ones(10), np.ones(9), np.ones(10)])
    with pytest.raises(ValueError, match=r"pair_weights\[2\]"):
        optimize_trajectory(pts, wps, 0.5, 0.6, retained=retained,
                            pair_weights=[np.ones(10), np.ones(10), -np.ones(10)])
    with pytest.raises(ValueError, match="needs retained"):
        optimize_trajectory(pts, wps, 0.5, 0.6, pair_weights=[np.ones(len(pts))] * 3)


def test_the_receding_horizon_planner_applies_the_spread_weights():
    from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner
    from pivotd.gimbal.kinematics import JointLimits, Mount
    from pivotd.maps.filters import RetainedFilter
    from pivotd.maps.formats import LandmarkCloud
    from pivotd.maps.store import MapStore

    _, pts = clump_or_spread_scene()
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=pts, weights=np.ones(len(pts))))
    limits = JointLimits(math.radians(-170), math.radians(170), math.radians(-60), math.radians(60), False)
    path = np.column_stack([np.linspace(-1.0, 2.0, 13), np.zeros(13), np.zeros(13)])
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    looks = {}
    for name, spread in (("count", None), ("spread", SETTINGS)):
        st = PlannerSettings(fov=math.radians(60), lam=0.6, spacing=0.5, horizon=6, spread=spread,
                             retained_filter=RetainedFilter(min_range=0.1, max_range=20.0))
        pl = RecedingHorizonPlanner(st, Mount(), limits)
        pl.set_path(path, None, 1)
        plan = None
        for x in (0.0, 0.2, 0.55):  # replans reuse the grid waypoints' weights; a new waypoint gets its own
            anchor = None if plan is None else plan.directions[0]
            plan = pl.replan(store.snapshot(), np.array([x, 0.0, 0.0]), quat, anchor)
        looks[name] = plan.directions[0]
    assert looks["count"][1] > 0.7  # the clump (+y)
    assert looks["spread"][1] < -0.7  # the spread set (−y)
