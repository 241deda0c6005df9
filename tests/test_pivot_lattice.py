"""Direction lattices (pivotd.pivot.lattice): unit directions where each lattice says they are."""

import math

import numpy as np
import pytest

from pivotd.geometry import direction_to_pan_tilt
from pivotd.pivot.lattice import azimuth_elevation_grid, fibonacci_sphere, grid_covering_radius, sphere_grid


def test_fibonacci_lattice_is_unit_and_spreads_its_points_evenly():
    S = fibonacci_sphere(2000)
    assert S.shape == (2000, 3)
    np.testing.assert_allclose(np.linalg.norm(S, axis=1), 1.0, atol=1e-12)
    np.testing.assert_allclose(S.mean(axis=0), 0.0, atol=2e-3)  # balanced
    cos = S @ S.T
    np.fill_diagonal(cos, -1.0)
    nearest = np.degrees(np.arccos(np.clip(cos.max(axis=1), -1, 1)))
    spacing = math.degrees(math.sqrt(4 * math.pi / 2000))
    assert 0.6 * spacing < nearest.min() and nearest.max() < 1.2 * spacing, (nearest.min(), nearest.max(), spacing)


def test_every_direction_is_within_the_covering_radius_of_the_sphere_grid():
    grid, rho = sphere_grid(6.0), grid_covering_radius(6.0)
    assert 6.0 / 2 < math.degrees(rho) < 6.0
    probe = fibonacci_sphere(20000)
    far = np.arccos(np.clip((probe @ grid.T).max(axis=1), -1, 1)).max()
    assert far <= rho and far > 0.8 * rho, (math.degrees(far), math.degrees(rho))
    with pytest.raises(ValueError, match="resolution_deg"):
        sphere_grid(0.0)


def test_azimuth_elevation_grid_steps_both_angles_and_leaves_out_the_poles():
    D = azimuth_elevation_grid(30.0)
    assert D.shape == (12 * 5, 3)
    np.testing.assert_allclose(np.linalg.norm(D, axis=1), 1.0, atol=1e-12)
    pan, tilt = direction_to_pan_tilt(D)
    np.testing.assert_allclose(np.degrees(pan[::5]), np.arange(-180.0, 180.0, 30.0), atol=1e-9)
    np.testing.assert_allclose(np.degrees(-tilt[:5]), [-60.0, -30.0, 0.0, 30.0, 60.0], atol=1e-9)  # elevations
