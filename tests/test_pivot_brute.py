"""Brute-force reference and the synthetic scenes."""

import numpy as np

from pivotd.geometry import normalize
from pivotd.pivot.brute import brute_force_view
from pivotd.pivot.lattice import sphere_grid
from pivotd.pivot.scenes import monte_carlo_levels, monte_carlo_map, monte_carlo_poses


def test_sphere_grid_covers_the_sphere_at_its_resolution():
    grid = sphere_grid(4.0)
    assert np.allclose(np.linalg.norm(grid, axis=1), 1)
    probe = normalize(np.random.default_rng(0).normal(size=(3000, 3)))
    nearest = np.degrees(np.arccos(np.clip(probe @ grid.T, -1, 1)).min(axis=1))
    assert nearest.max() <= 4.0
    assert abs(len(sphere_grid(2.0)) - 4 * np.pi / np.radians(2.0) ** 2) < 0.15 * len(sphere_grid(2.0))


def test_brute_force_matches_an_exhaustive_count():
    rng = np.random.default_rng(1)
    B = normalize(rng.normal(size=(300, 3)) + np.array([1.5, 0, 0]))
    alpha = np.radians(20)
    d, best = brute_force_view(B, None, alpha, 3.0)
    cos = B @ sphere_grid(3.0).T
    counts = np.count_nonzero(cos >= np.cos(alpha), axis=0)
    assert best == counts.max()
    assert np.count_nonzero(B @ d >= np.cos(alpha) - 1e-6) == best


def test_brute_force_uses_weights():
    B = np.array([[1.0, 0, 0], [1.0, 0, 0], [0, 1.0, 0]])
    d, best = brute_force_view(B, np.array([1.0, 1.0, 5.0]), np.radians(5), 2.0)
    assert best == 5.0 and d[1] > 0.99
    d, best = brute_force_view(np.zeros((0, 3)), None, 0.3)
    assert best == 0.0


def test_monte_carlo_scene_matches_the_paper():
    levels = monte_carlo_levels()
    assert len(levels) == 10 and levels[0] == 2000 and levels[-1] == 18000
    full = monte_carlo_map()
    assert full.shape == (18000, 3)
    assert full[:, :2].min() >= -400 and full[:, :2].max() <= 400
    assert full[:, 2].min() >= 0 and full[:, 2].max() <= 20
    small = monte_carlo_map(0)
    assert np.array_equal(small, full[:2000])  # nested
    assert np.array_equal(monte_carlo_map(3), monte_carlo_map(3))  # deterministic
    poses = monte_carlo_poses()
    assert poses.shape == (400, 3) and np.all(poses[:, 2] == 20)
    assert len(np.unique(poses[:, 0])) == 20
