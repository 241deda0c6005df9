"""Step-limited grid reference for trajectory plans (pivotd.pivot.brute.brute_force_trajectory)."""

import itertools

import numpy as np
import pytest

from pivotd.geometry import angle_between
from pivotd.pivot.brute import best_grid_chain, brute_force_trajectory, grid_neighbours, grid_visibility
from pivotd.pivot.lattice import sphere_grid
from pivotd.pivot.scenes import competing_clusters_path
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory


def _steps_deg(C):
    return np.degrees(angle_between(C[1:], C[:-1]))


def test_neighbours_are_exactly_the_directions_within_the_step():
    grid = sphere_grid(15.0)
    nb = grid_neighbours(grid, np.radians(32.0))
    ang = np.degrees(np.arccos(np.clip(grid @ grid.T, -1, 1)))
    for k in range(grid.shape[0]):
        assert set(nb[k].tolist()) == set(np.flatnonzero(ang[k] <= 32.0 + 1e-4).tolist())


def test_chain_is_the_exhaustive_optimum_on_a_small_grid():
    rng = np.random.default_rng(3)
    grid = sphere_grid(30.0)
    G = grid.shape[0]
    V = rng.integers(0, 20, size=(4, G)).astype(np.float32)
    limit = 65.0
    ok = np.degrees(np.arccos(np.clip(grid @ grid.T, -1, 1))) <= limit + 1e-4
    best = -1.0
    for path in itertools.product(range(G), repeat=4):
        if all(ok[a, b] for a, b in itertools.pairwise(path)):
            best = max(best, float(sum(V[i, k] for i, k in enumerate(path))))
    path = best_grid_chain(V, grid, limit)
    assert all(ok[a, b] for a, b in itertools.pairwise(path))
    assert V[np.arange(4), path].sum() == best
    free = best_grid_chain(V, grid, None)
    assert np.array_equal(V[np.arange(4), free], V.max(axis=1))


def test_visibility_counts_match_a_direct_count():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    grid = sphere_grid(10.0)
    V = grid_visibility(scene.points, scene.path[:3], alpha, grid)
    for i in range(3):
        b = scene.points - scene.path[i]
        b /= np.linalg.norm(b, axis=1, keepdims=True)
        cos = b @ grid.T
        # float32 inside: landmarks within 1e-5 of the cone's edge may go either way
        assert np.all(V[i] >= np.count_nonzero(cos >= np.cos(alpha) + 1e-5, axis=0))
        assert np.all(V[i] <= np.count_nonzero(cos >= np.cos(alpha) - 1e-5, axis=0))
        assert V[i].max() > 0


@pytest.fixture(scope="module")
def competing_plan():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    plan = optimize_trajectory(scene.points, scene.path, alpha, 0.6,
                               options=TrajectoryOptions.paper(distance_weights=False))
    return scene, alpha, plan


def test_reference_respects_the_step_and_bounds_the_free_plan(competing_plan):
    scene, alpha, plan = competing_plan
    limit = float(_steps_deg(plan.directions).max())
    dirs, vis = brute_force_trajectory(scene.points, scene.path, alpha, limit)
    assert _steps_deg(dirs).max() <= limit + 1e-6
    _, vis_free = brute_force_trajectory(scene.points, scene.path, alpha, None)
    assert vis.sum() <= vis_free.sum()
    assert np.all(vis_free >= vis)


def test_smooth_plan_is_close_to_the_best_plan_with_its_largest_step(competing_plan):
    # the λ = 0.6 plan (hard counts, no distance weights) against the exact grid optimum among all plans
    # whose steps are no larger than its own: measured 98.8 %
    scene, alpha, plan = competing_plan
    limit = float(_steps_deg(plan.directions).max())
    _, vis = brute_force_trajectory(scene.points, scene.path, alpha, limit)
    assert plan.visible.sum() >= 0.97 * vis.sum()
