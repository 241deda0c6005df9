"""Attainable-weight normalisation of the trajectory objective (pivotd.pivot.normalise)."""

from __future__ import annotations

import math
import re

import numpy as np
import pytest

from pivotd.pivot.normalise import Normalisation, attainable_weights
from pivotd.pivot.pairs import dense_geometry, gather_pairs, ragged_geometry
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory


def _patch(rng: np.random.Generator, direction, n: int, spread: float = 0.05, r: float = 100.0) -> np.ndarray:
    d = np.asarray(direction, float)
    v = d / np.linalg.norm(d) + rng.normal(scale=spread, size=(n, 3))
    return r * v / np.linalg.norm(v, axis=1, keepdims=True)


def _attainable(points, waypoints, retained, alpha, dist_w=False, weights=None):
    pairs = gather_pairs(points, weights, retained, waypoints.shape[0])
    geom, total = ragged_geometry(pairs, waypoints, dist_w)
    return attainable_weights(geom, alpha), total


def test_two_opposite_clusters_attainable_is_the_larger_cluster():
    rng = np.random.default_rng(0)
    P = np.vstack([_patch(rng, [1, 0, 0], 300, r=5.0), _patch(rng, [-1, 0, 0], 100, r=5.0)])
    T = np.array([[0.0, 0.0, 0.0], [0.0, 0.1, 0.0], [0.0, 0.2, 0.1]])
    att, total = _attainable(P, T, [np.arange(400)] * 3, math.radians(15))
    np.testing.assert_allclose(total, 400.0)
    np.testing.assert_allclose(att, 300.0)
    # weighted: the small cluster made heavier wins
    w = np.r_[np.ones(300), np.full(100, 4.0)]
    att_w, total_w = _attainable(P, T, [np.arange(400)] * 3, math.radians(15), weights=w)
    np.testing.assert_allclose(total_w, 700.0)
    np.testing.assert_allclose(att_w, 400.0)
    # the shared (dense) geometry gives the same
    geom, _ = dense_geometry(P, T, np.ones(400), False)
    np.testing.assert_allclose(attainable_weights(geom, math.radians(15)), 300.0)


def test_attainable_is_a_real_cone_weight_close_to_the_best():
    """Against an exhaustive search over cones centred on every landmark (hard count): never above, within 10 %."""
    rng = np.random.default_rng(3)
    P = np.vstack([_patch(rng, d, n, spread=0.3, r=8.0) for d, n in
                   [([1, 0, 0], 150), ([0, 1, 0.3], 120), ([-1, -1, 0], 200), ([0, 0, -1], 60)]])
    T = np.array([[0.0, 0.0, 0.0], [1.0, 0.5, 0.0]])
    for alpha in (math.radians(10), math.radians(30)):
        att, _ = _attainable(P, T, [np.arange(P.shape[0])] * 2, alpha)
        for i in range(2):
            B = P - T[i]
            B /= np.linalg.norm(B, axis=1, keepdims=True)
            cos = B @ B.T
            best = float(np.count_nonzero(cos >= math.cos(alpha), axis=0).max())
            assert att[i] <= best + 1e-9
            assert att[i] >= 0.9 * best


def test_attainable_does_not_depend_on_the_order_of_the_retained_landmarks():
    rng = np.random.default_rng(1)
    P = rng.normal(size=(3000, 3)) * [6.0, 3.0, 1.0]
    T = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0], [1.0, 0.2, 0.0]])
    keep = rng.choice(3000, 1200, replace=False)
    a, _ = _attainable(P, T, [keep] * 3, math.radians(20), dist_w=True)
    for _ in range(3):
        b, _ = _attainable(P, T, [rng.permutation(keep) for _ in range(3)], math.radians(20), dist_w=True)
        np.testing.assert_allclose(a, b, rtol=1e-6)


def test_attainable_follows_the_retained_landmarks_only():
    """Landmarks outside the retained sets are never read: NaN rows there change nothing."""
    rng = np.random.default_rng(2)
    P = rng.normal(size=(500, 3)) * 4.0
    T = np.array([[0.0, 0.0, 0.0], [0.5, 0.0, 0.0]])
    keep = [np.arange(0, 500, 2), np.arange(1, 500, 3)]
    a, _ = _attainable(P, T, keep, math.radians(25))
    big = np.full((200_000, 3), np.nan)
    idx = [r * 400 for r in keep]
    for r, j in zip(keep, idx, strict=True):
        big[j] = P[r]
    b, _ = _attainable(big, T, idx, math.radians(25))
    np.testing.assert_array_equal(a, b)


def _wall_scene():
    """A sparse patch ahead of the anchor, a textured wall 100° away and 2000 landmarks all around."""
    rng = np.random.default_rng(1)
    a = np.array([0.0, 1.0, 0.0])
    b = np.array([math.cos(math.radians(-10)), math.sin(math.radians(-10)), 0.0])
    bg = rng.normal(size=(2000, 3))
    bg *= 100.0 / np.linalg.norm(bg, axis=1, keepdims=True)
    P = np.vstack([_patch(rng, a, 30), _patch(rng, b, 120), bg])
    T = np.zeros((20, 3))
    T[:, 0] = np.arange(20) * 0.5
    return P, T, a, b


def test_attainable_normalisation_turns_to_the_textured_wall():
    P, T, a, b = _wall_scene()
    alpha, lam = math.radians(30), 0.6
    ret = [np.arange(P.shape[0])] * T.shape[0]
    out = {}
    for norm in Normalisation:
        r = optimize_trajectory(P, T, alpha, lam, anchor=a, retained=ret,
                                options=TrajectoryOptions.paper(distance_weights=False, normalise=norm))
        out[norm] = r
    total, attain = out[Normalisation.TOTAL], out[Normalisation.ATTAINABLE]
    to_wall = lambda r: np.degrees(np.arccos(np.clip(r.directions @ b, -1, 1)))  # noqa: E731
    # total weight: the wall's gain (≈ 90 of ≈ 2150 per waypoint) is worth less than the 100° turn
    assert to_wall(total)[-5:].min() > 60.0
    # attainable weight: the same gain is a third of what each waypoint can see; the plan turns to the wall
    assert to_wall(attain)[-10:].max() < 25.0
    assert attain.visible.sum() > 1.25 * total.visible.sum()
    # each term is ≤ ~1: the objective without smoothness is at most N (soft edge tolerance)
    assert attain.objective - lam * TrajectoryOptions.smooth_scale * (
        float(np.sum(attain.directions[1:] * attain.directions[:-1])) + float(a @ attain.directions[0])
    ) <= T.shape[0] * 1.1


def test_normalise_option_is_validated():
    P, T, _, _ = _wall_scene()
    with pytest.raises(ValueError, match=re.escape("normalise must be one of total | attainable, got 'best'")):
        optimize_trajectory(P, T, 0.5, 0.6, options=TrajectoryOptions.paper(normalise="best"))
    assert Normalisation.parse("attainable") is Normalisation.ATTAINABLE


def test_planner_normalise_key_reaches_the_optimizer_and_is_checked(tmp_path):
    from pivotd.config import load_config
    from pivotd.daemon.wiring import build_planner
    from pivotd.errors import ConfigError

    good = tmp_path / "good.yaml"
    good.write_text("name: n\nmap:\n  allow_empty: true\nplanner:\n  normalise: attainable\n")
    cfg = load_config(good)
    assert cfg.planner.normalise is Normalisation.ATTAINABLE
    assert build_planner(cfg).settings.options.normalise is Normalisation.ATTAINABLE
    bad = tmp_path / "bad.yaml"
    bad.write_text("name: n\nmap:\n  allow_empty: true\nplanner:\n  normalise: best\n")
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    message = str(info.value)
    assert "\n" not in message
    assert re.search(r"bad\.yaml:5: planner\.normalise: must be one of total, attainable; got 'best'", message), message
