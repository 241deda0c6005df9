"""The single-pose optimizer's building blocks: spirals, hard-count search, greedy distinct picks, refinement."""

import math

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize, tangent_basis
from pivotd.pivot.lattice import spiral_caps
from pivotd.pivot.scenes import hard_scene
from pivotd.pivot.view import (
    ViewOptions,
    _greedy_distinct,
    _refine,
    _search_levels,
    _spiral_frame,
    local_search,
)


def test_spirals_of_all_levels_follow_the_sunflower_formula():
    radii, points = [0.13, 0.03, 0.01, 0.003], [32, 24, 24, 7]
    levels = spiral_caps(radii, points)
    assert [lv.shape for lv in levels] == [(p + 1, 3) for p in points]
    golden = math.pi * (3.0 - math.sqrt(5.0))
    for r, p, lv in zip(radii, points, levels, strict=True):
        assert np.array_equal(lv[0], [1.0, 0.0, 0.0])  # the cap's centre first
        i = np.arange(p) + 0.5
        rho, phi = r * np.sqrt(i / p), i * golden
        want = np.stack([np.cos(rho), np.sin(rho) * np.cos(phi), np.sin(rho) * np.sin(phi)], axis=1)
        assert np.abs(lv[1:] - want).max() < 1e-12
        assert np.allclose(np.linalg.norm(lv, axis=1), 1.0)
        assert np.arccos(np.clip(lv[:, 0], -1, 1)).max() <= r * (1 + 1e-12)  # all within the cap


def _reference_search(c, B, alpha, radii, points):
    """local_search's rule scored on every landmark (exact counts, no bands): per level the first spiral direction
    with the highest count replaces the axis when it sees strictly more than the axis."""
    cos_c = B @ c
    band = np.abs(np.arccos(np.clip(cos_c, -1, 1)) - alpha) <= sum(radii)
    toward_B = B[band].sum(axis=0)
    cos_a = np.float32(math.cos(alpha) - 1e-7)
    B32 = B.astype(np.float32)
    for local in spiral_caps(radii, points):
        cand = local @ _spiral_frame(c, toward_B)
        vals = np.count_nonzero(cand.astype(np.float32) @ B32.T >= cos_a, axis=1)
        k = int(np.argmax(vals))
        if vals[k] > vals[0]:
            c = cand[k] / np.linalg.norm(cand[k])
    return c


@pytest.mark.parametrize("family", ["clusters", "blob", "ring"])
def test_local_search_on_its_bands_moves_like_a_search_on_all_landmarks(family):
    # the bands only drop landmarks that are inside or outside every cone of a level: the same moves
    alpha = math.radians(15.0)
    opts = ViewOptions()
    radii, points = _search_levels(alpha, opts, opts.cap_ratio * alpha, opts.cap_points)
    scene = hard_scene(family, seed=5, poses=4, scale=0.3)
    rng = np.random.default_rng(2)
    for t in scene.path:
        B = normalize(scene.points - t)
        BT = np.ascontiguousarray(B.T, dtype=np.float32)
        w = np.ones(B.shape[0], np.float32)
        c = normalize(B[rng.integers(B.shape[0])] + 0.2 * rng.normal(size=3))
        got = local_search(c, BT, w, alpha, c.astype(np.float32) @ BT, radii, points)
        want = _reference_search(c, B, alpha, radii, points)
        assert angle_between(got, want) < 1e-6  # the same moves (the orienting mean differs in rounding)
        seen = np.count_nonzero(B @ got >= math.cos(alpha) - 1e-7)
        assert seen >= np.count_nonzero(B @ c >= math.cos(alpha) - 1e-7)  # never worse than its start


def _greedy_reference(D, cos_min, k):
    picks = []
    for i in range(D.shape[0]):
        if len(picks) == k:
            break
        if all(float(D[i] @ D[j]) < cos_min for j in picks):
            picks.append(i)
    return picks


@pytest.mark.parametrize("m", [1, 7, 64, 65, 200])
def test_greedy_distinct_matches_the_plain_greedy_walk(m):
    rng = np.random.default_rng(m)
    D = normalize(np.array([1.0, 0.0, 0.0]) + 0.6 * rng.normal(size=(m, 3))).astype(np.float32)
    for cos_min, k in ((math.cos(0.1), 12), (math.cos(0.4), 6), (math.cos(0.05), m + 3), (0.99, 0)):
        assert _greedy_distinct(D, cos_min, k) == _greedy_reference(D, np.float32(cos_min), k)
    assert _greedy_distinct(D[:0], 0.5, 4) == []


def test_refinement_of_two_axes_in_one_basin_stops_the_second_near_the_first():
    # one dense cluster: both starts climb the same basin; the second stops within distinct_ratio · α of the first
    rng = np.random.default_rng(4)
    centre = normalize(np.array([0.3, 0.2, 1.0]))
    B = normalize(centre + 0.12 * rng.normal(size=(4000, 3)))
    B = np.concatenate([B, normalize(rng.normal(size=(1000, 3)))])
    BT = np.ascontiguousarray(B.T, dtype=np.float32)
    w = np.ones(B.shape[0], np.float32)
    alpha, opts = math.radians(15.0), ViewOptions()
    tangent = tangent_basis(centre, polar=None)[0]  # level
    starts = normalize(np.array([centre + 0.12 * tangent, centre - 0.16 * tangent]))
    cos_c = starts.astype(np.float32) @ BT
    both, _ = _refine(BT, w, starts, cos_c, alpha, opts, True)
    alone, _ = _refine(BT, w, starts[:1], cos_c[:1], alpha, opts, True)
    assert angle_between(both[0], alone[0]) < math.radians(0.5)  # the first row climbs as it would alone
    assert angle_between(both[0], centre) < math.radians(3.0)
    reach = opts.distinct_ratio * alpha + math.radians(opts.step_max_deg)
    assert angle_between(both[1], both[0]) < reach
