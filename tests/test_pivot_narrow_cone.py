"""Narrow cones (half-angles 0.5°–6°): optimize_view against the exact single-pose optimum."""

import numpy as np
import pytest

from pivotd.geometry import normalize, tangent_basis
from pivotd.pivot.brute import brute_force_view, exact_view
from pivotd.pivot.lattice import sphere_grid
from pivotd.pivot.scenes import HARD_FAMILIES, hard_path, hard_scene
from pivotd.pivot.view import ViewOptions, boundary_axes, optimize_view


def _clustered(rng: np.random.Generator, n: int) -> np.ndarray:
    """Landmarks (≈ n, 3): 3–11 anisotropic clusters of very different sizes and spreads plus 8 % clutter."""
    k = int(rng.integers(3, 12))
    sizes = rng.dirichlet(np.full(k, 0.7)) * n * 0.92
    parts = []
    for size in sizes:
        centre = rng.uniform(-50, 50, 3)
        sigma = np.exp(rng.uniform(np.log(0.2), np.log(15.0), 3))
        rot = np.linalg.qr(rng.normal(size=(3, 3)))[0]
        parts.append(centre + (rng.normal(size=(max(1, int(size)), 3)) * sigma) @ rot.T)
    parts.append(rng.uniform(-60, 60, (int(0.08 * n), 3)))
    return np.concatenate(parts)


def _seen(B: np.ndarray, w: np.ndarray, d: np.ndarray, alpha: float) -> float:
    return float((B @ d >= np.cos(alpha) - 1e-12) @ w)


def test_boundary_axes_put_both_bearings_on_the_cone_edge():
    rng = np.random.default_rng(0)
    alpha = np.radians(2.0)
    B = normalize(np.array([0.0, 0.0, 1.0]) + 0.03 * rng.normal(size=(60, 3)))
    A = boundary_axes(B, alpha)
    assert A.shape[0] > 0 and np.allclose(np.linalg.norm(A, axis=1), 1.0)
    on_edge = np.isclose(A @ B.T, np.cos(alpha), atol=1e-12, rtol=0.0).sum(axis=1)
    assert (on_edge >= 2).all()


@pytest.mark.parametrize("half_deg", [1.0, 4.0])
def test_exact_view_beats_every_direction_of_a_fine_grid(half_deg):
    rng = np.random.default_rng(int(half_deg))
    alpha = np.radians(half_deg)
    B = normalize(np.array([1.0, 0.2, 0.1]) + 0.05 * rng.normal(size=(300, 3)))
    w = rng.uniform(0.5, 2.0, 300)
    d, value = exact_view(B, w, alpha)
    assert value == pytest.approx(_seen(B, w, d, alpha))
    grid = sphere_grid(0.25)
    grid = grid[grid @ normalize(np.array([1.0, 0.2, 0.1])) > np.cos(np.radians(12.0))]
    _, grid_value = brute_force_view(B, w, alpha, grid=grid)
    assert value >= grid_value - 1e-4
    with pytest.raises(ValueError, match="max_centres"):
        exact_view(B, w, alpha, max_centres=10)


@pytest.mark.parametrize("half_deg", [0.5, 1.0, 2.0, 3.0, 5.0])
def test_narrow_cones_on_random_clustered_scenes_match_the_exact_optimum(half_deg):
    alpha = np.radians(half_deg)
    ratios = []
    for seed in range(6):
        rng = np.random.default_rng([seed, int(10 * half_deg)])
        points = _clustered(rng, 500)
        weights = rng.uniform(0.2, 3.0, points.shape[0]) if seed % 2 else None
        w = np.ones(points.shape[0]) if weights is None else weights
        for sensor in rng.uniform(-40, 40, (6, 3)):
            B = normalize(points - sensor)
            best = exact_view(B, weights, alpha)[1]
            ratios.append(_seen(B, w, optimize_view(B, weights, alpha).direction, alpha) / best)
    q = 100 * np.array(ratios)
    assert q.mean() >= 99.5 and np.percentile(q, 5) >= 98.0 and q.min() >= 95.0, (q.mean(), q.min())


@pytest.mark.parametrize("half_deg", [1.0, 3.0])
def test_narrow_cones_on_the_hard_families_match_the_exact_optimum(half_deg):
    alpha = np.radians(half_deg)
    ratios = []
    for family in HARD_FAMILIES:
        scene = hard_scene(family, seed=3, poses=5, scale=0.05)
        for sensor in scene.path:
            B = normalize(scene.points - sensor)
            best = exact_view(B, None, alpha)[1]
            r = optimize_view(B, None, alpha)
            assert r.visible == _seen(B, np.ones(B.shape[0]), r.direction, alpha)
            ratios.append(r.visible / best)
    q = 100 * np.array(ratios)
    assert q.mean() >= 99.5 and q.min() >= 95.0, (q.mean(), q.min())


def test_a_dense_spot_smaller_than_the_cone_inside_a_wide_cloud_is_found():
    # a wide uniform cloud (many landmarks in every cell of any coarse histogram) hiding a 0.4°-wide spot
    # of 60 landmarks far from the cloud's centre: the best 1° cone holds the spot
    rng = np.random.default_rng(7)
    cloud = normalize(np.array([0.0, 1.0, 0.0]) + 0.35 * rng.normal(size=(6000, 3)))
    spot_dir = normalize(np.array([0.3, 1.0, 0.25]))
    spot = normalize(spot_dir + np.radians(0.2) * rng.normal(size=(60, 3)))
    B = np.concatenate([cloud, spot])
    alpha = np.radians(1.0)
    r = optimize_view(B, None, alpha)
    assert np.degrees(np.arccos(min(1.0, float(r.direction @ spot_dir)))) < 1.0
    assert r.visible >= 60


def test_narrow_cone_answer_does_not_depend_on_the_landmark_order():
    rng = np.random.default_rng(11)
    points = _clustered(rng, 3000)  # above the subsample size: the large-map path
    assert points.shape[0] > ViewOptions().sample
    B = normalize(points - rng.uniform(-40, 40, 3))
    for half_deg in (1.0, 3.0):
        alpha = np.radians(half_deg)
        base = optimize_view(B, None, alpha)
        for k in range(3):
            perm = np.random.default_rng(k).permutation(B.shape[0])
            other = optimize_view(B[perm], None, alpha)
            assert abs(other.visible - base.visible) <= 0.005 * base.visible


def test_narrow_path_takes_an_init_direction():
    rng = np.random.default_rng(5)
    B = normalize(_clustered(rng, 2000) - rng.uniform(-40, 40, 3))
    alpha = np.radians(2.0)
    free = optimize_view(B, None, alpha)
    seeded = optimize_view(B, None, alpha, init=free.direction)
    assert seeded.visible >= free.visible
    assert np.allclose(seeded.rotation[:, 2], seeded.direction)


def test_equal_weights_other_than_one_give_the_unweighted_answer():
    rng = np.random.default_rng(3)
    B = normalize(_clustered(rng, 1500) - rng.uniform(-40, 40, 3))
    alpha = np.radians(2.0)
    plain = optimize_view(B, None, alpha)
    scaled = optimize_view(B, np.full(B.shape[0], 100.0), alpha)
    assert scaled.visible == plain.visible


def test_exact_local_search_beats_a_dense_sample_of_its_disc():
    from pivotd.pivot.view import _exact_local

    rng = np.random.default_rng(9)
    alpha, r = np.radians(1.0), np.radians(0.6)
    c = normalize(np.array([0.2, -0.4, 1.0]))
    B = normalize(c + np.radians(1.2) * rng.normal(size=(150, 3)))
    w = rng.uniform(0.5, 2.0, 150)
    BT = np.ascontiguousarray(B.T, dtype=np.float32)
    axis = _exact_local(c, BT, w.astype(np.float32), alpha, r, 1000)
    assert float(axis @ c) >= np.cos(r) - 1e-9
    t1, t2 = tangent_basis(c)
    rho, phi = r * np.sqrt(rng.uniform(0, 1, 40000)), rng.uniform(0, 2 * np.pi, 40000)
    S = np.cos(rho)[:, None] * c + np.sin(rho)[:, None] * (np.cos(phi)[:, None] * t1 + np.sin(phi)[:, None] * t2)
    cos_sb = S @ B.T
    sampled = ((cos_sb >= np.cos(alpha)) @ w).max()
    assert _seen(B, w, axis, alpha) >= sampled - 1e-9


def test_narrow_bench_judges_against_the_exact_optimum():
    from pivotd.bench.narrow import quality_rows

    def looks_at_x(B, w, alpha):  # a deliberately poor optimizer: the bench must show it
        from types import SimpleNamespace

        return SimpleNamespace(direction=np.array([1.0, 0.0, 0.0]))

    good = quality_rows((2.0,), seeds=1, poses=2, scale=0.03)
    bad = quality_rows((2.0,), seeds=1, poses=2, scale=0.03, view=looks_at_x)
    assert good[0]["poses"] == bad[0]["poses"] == 12
    assert good[0]["exact_min_pct"] >= 95.0 and good[0]["exact_mean_pct"] <= 100.0 + 1e-9
    assert bad[0]["exact_mean_pct"] < 60.0


@pytest.mark.parametrize("family", ["near_far", "blob"])
def test_cold_trajectory_with_a_narrow_cone_finds_the_basins_the_single_view_search_finds(family):
    """At 2° the chain's grid and the widened stages miss a small dense cluster: the plan looked elsewhere and saw
    a few percent of what the waypoints' own optima see. The seeded second solve keeps the higher objective."""
    from dataclasses import replace

    from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory

    hp = hard_path(family, 0, waypoints=20, scale=0.1)
    alpha = np.radians(2.0)
    opts = TrajectoryOptions.paper(distance_weights=False)
    independent = optimize_trajectory(hp.points, hp.path, alpha, 0.0, options=opts)
    plan = optimize_trajectory(hp.points, hp.path, alpha, 0.6, options=opts)
    unseeded = optimize_trajectory(hp.points, hp.path, alpha, 0.6, options=replace(opts, narrow_seed_nodes=0))
    assert plan.objective >= unseeded.objective
    assert plan.visible.sum() >= 0.85 * independent.visible.sum()
    steps = np.degrees(np.arccos(np.clip(np.sum(plan.directions[1:] * plan.directions[:-1], axis=1), -1, 1)))
    assert steps.max() < 5.0  # still a smooth plan


def test_narrow_bench_plan_rows_compare_seeded_and_unseeded_cold_plans():
    from pivotd.bench.narrow import plan_rows

    rows = plan_rows((2.0,), scale=0.05, waypoints=12)
    assert [r["family"] for r in rows] == list(HARD_FAMILIES)
    for r in rows:
        assert 0.0 <= r["unseeded_pct"] <= 100.0 + 1e-9 and 0.0 <= r["seeded_pct"] <= 100.0 + 1e-9
        assert 0.0 <= r["max_step_deg"] < 45.0
    near_far = next(r for r in rows if r["family"] == "near_far")
    assert near_far["seeded_pct"] > near_far["unseeded_pct"] + 20.0  # the seed finds the small dense cluster
