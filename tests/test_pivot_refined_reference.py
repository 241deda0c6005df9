"""The refined single-pose reference (2° grid + branch-and-bound refinement) against exhaustive fine grids."""

import numpy as np
import pytest

from pivotd.geometry import normalize, tangent_basis
from pivotd.pivot.brute import brute_force_view, refined_view
from pivotd.pivot.lattice import grid_covering_radius, sphere_grid
from pivotd.pivot.scenes import HARD_FAMILIES, hard_scene
from pivotd.pivot.visibility import hard_count


def _bearings(scene, pose):
    return normalize(scene.points - scene.path[pose])


@pytest.mark.slow  # seconds of CPU: in `make test`, not in `make test-fast`
def test_covering_radius_bounds_the_distance_to_the_grid():
    rng = np.random.default_rng(0)
    for res in (2.0, 5.0):
        grid = sphere_grid(res)
        rho = grid_covering_radius(res)
        u = normalize(rng.normal(size=(20000, 3)))
        nearest = np.arccos(np.clip((u @ grid.T).max(axis=1), -1.0, 1.0))
        assert nearest.max() <= rho
        assert nearest.max() >= 0.8 * rho  # and it is not a loose bound
        assert rho < np.radians(res)


@pytest.mark.parametrize("family", HARD_FAMILIES)
def test_refined_reference_brackets_an_exhaustive_fine_grid(family):
    alpha = np.radians(15.0)
    scene = hard_scene(family, seed=3, poses=2, scale=0.02)
    for pose in range(2):
        B = _bearings(scene, pose)
        ref = refined_view(B, None, alpha)
        _, coarse = brute_force_view(B, None, alpha, 2.0)
        _, fine = brute_force_view(B, None, alpha, 0.5)
        assert ref.exact
        assert ref.value == hard_count(ref.direction, B, alpha)
        assert coarse <= ref.value <= ref.bound
        assert fine <= ref.bound  # a certified upper bound
        assert ref.value >= fine  # the refinement finds at least what a 4× finer grid finds


def test_refined_reference_beats_the_grid_on_a_narrow_peak():
    # two tight clumps exactly 2α apart (edge to edge): only a narrow band of axes holds both
    rng = np.random.default_rng(1)
    alpha = np.radians(10.0)
    axis = normalize(np.array([0.3, 0.5, 0.8]))
    side, up = tangent_basis(axis)
    half = alpha - np.radians(0.2)
    clumps = [np.cos(half) * axis + s * np.sin(half) * side for s in (-1.0, 1.0)]
    B = normalize(np.concatenate([c + 0.0005 * rng.normal(size=(40, 3)) for c in clumps] + [
        normalize(rng.normal(size=(30, 3)))]))
    ref = refined_view(B, None, alpha)
    _, coarse = brute_force_view(B, None, alpha, 2.0)
    assert ref.value >= coarse
    assert ref.value >= 80  # both clumps
    assert np.degrees(np.arccos(np.clip(ref.direction @ axis, -1, 1))) < 0.5
    del up


def test_refined_reference_respects_weights_and_empty_input():
    alpha = np.radians(20.0)
    B = normalize(np.array([[1.0, 0, 0], [0.99, 0.05, 0], [-1.0, 0, 0]]))
    ref = refined_view(B, np.array([1.0, 1.0, 5.0]), alpha)
    assert ref.value == pytest.approx(5.0)
    assert ref.direction @ np.array([-1.0, 0, 0]) >= np.cos(alpha) - 1e-9
    empty = refined_view(np.zeros((0, 3)), None, alpha)
    assert empty.value == 0.0 and empty.exact
