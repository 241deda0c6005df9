"""Chain initialisation (pivotd.pivot.chain): node spacing, Viterbi choice, spherical fill."""

import numpy as np
import pytest
from viterbi_reference import viterbi_reference

from pivotd.geometry import angle_between
from pivotd.pivot.chain import best_chain, node_indices, slerp_fill
from pivotd.pivot.lattice import sphere_grid


def _unit(v):
    v = np.asarray(v, float)
    return v / np.linalg.norm(v, axis=-1, keepdims=True)


def test_node_indices_spread_and_keep_the_ends():
    assert np.array_equal(node_indices(5, 64), np.arange(5))
    nodes = node_indices(498, 64)
    assert nodes[0] == 0 and nodes[-1] == 497 and nodes.size == 64
    assert np.ptp(np.diff(nodes)) <= 1


def test_slerp_fill_interpolates_along_great_circles():
    rng = np.random.default_rng(0)
    for _ in range(100):
        n = int(rng.integers(3, 50))
        first, last = int(rng.integers(0, 3)), n - 1 - int(rng.integers(0, 3))
        nodes = np.unique(np.concatenate([[first], rng.choice(np.arange(first, last + 1), 4), [last]]))
        dirs = _unit(rng.normal(size=(nodes.size, 3)))
        out = slerp_fill(n, nodes, dirs)
        assert np.allclose(np.linalg.norm(out, axis=1), 1.0)
        assert np.allclose(out[nodes], dirs, atol=1e-12)
        assert np.allclose(out[: nodes[0]], dirs[0]) and np.allclose(out[nodes[-1] :], dirs[-1])
        for a, b, da, db in zip(nodes[:-1], nodes[1:], dirs[:-1], dirs[1:], strict=True):
            total = angle_between(da, db)
            steps = angle_between(out[a + 1 : b + 1], out[a:b])
            assert np.allclose(steps, total / (b - a), atol=1e-9)  # constant speed on the great circle


def test_slerp_fill_turns_between_antipodal_nodes():
    d = np.array([[1.0, 0, 0], [-1.0, 0, 0], [-1.0, 0, 0]])
    out = slerp_fill(9, np.array([0, 4, 8]), d)
    steps = np.degrees(angle_between(out[1:5], out[:4]))
    assert np.allclose(steps, 45.0)
    assert np.allclose(out[4:], [-1.0, 0, 0])


def test_best_chain_trades_visibility_against_turning():
    grid = sphere_grid(30.0)
    x = int(np.argmax(grid @ [1.0, 0, 0]))
    y = int(np.argmax(grid @ [-1.0, 0, 0]))
    scores = np.zeros((3, grid.shape[0]), np.float32)
    scores[:, x] = 1.0
    scores[1, y] = 1.2  # the middle node alone prefers the opposite direction
    span = np.ones(3)
    assert list(best_chain(scores, grid, span, 0.0)) == [x, y, x]
    assert list(best_chain(scores, grid, span, 1.0)) == [x, x, x]  # two 180° turns cost 2·2 > 0.2


def _turn_value(ang, knee):
    """Value − 1 of a step of ``ang`` [rad]: −(1 − cos) without a knee, else minus the pseudo-Huber cost of its chord
    2 sin(ang / 2) (written from the chord, not from the cosine as pivotd.pivot.smoothness does)."""
    if knee <= 0:
        return np.cos(ang) - 1.0
    chord = 2.0 * np.sin(ang / 2.0)
    return -knee**2 * (np.sqrt(1.0 + (chord / knee) ** 2) - 1.0)


def _best_chain_reference(scores, grid, span, smooth, anchor=None, knee=0.0):
    """best_chain as the textbook Viterbi (tests/viterbi_reference.py), in float32 like it."""
    scores = scores.astype(np.float32)
    val = scores * np.asarray(span, np.float32)[:, None]
    if anchor is not None:
        val[0] = val[0] + (smooth * _turn_value(np.arccos(np.clip(grid @ anchor, -1.0, 1.0)), knee)).astype(np.float32)
    ang = np.arccos(np.clip(grid @ grid.T, -1.0, 1.0))
    pen = np.stack([((max(round(s), 1) * smooth) * _turn_value(ang / max(round(s), 1), knee)).astype(np.float32).T
                    for s in span[1:]])
    return viterbi_reference(val, pen)


def _chain_objective(path, scores, grid, span, smooth, anchor, knee):
    """The chain's objective (pivotd.pivot.chain) of a choice of grid directions ``path`` (K,)."""
    ang = np.arccos(np.clip(np.sum(grid[path[1:]] * grid[path[:-1]], axis=1), -1.0, 1.0))
    steps = np.maximum(np.round(span[1:]), 1)
    total = float(np.sum(scores[np.arange(path.size), path] * span))
    total += float(np.sum(steps * smooth * _turn_value(ang / steps, knee)))
    if anchor is not None:
        total += smooth * float(_turn_value(np.arccos(np.clip(grid[path[0]] @ anchor, -1, 1)), knee))
    return total


@pytest.mark.parametrize("knee_deg", [0.0, 1.0, 5.0])
def test_best_chain_equals_the_textbook_viterbi(knee_deg):
    """Exactly without a knee; with one, the same choice up to float32 ties of the two ways of computing a turn's
    cost (checked on the objective: equal within 1e-4)."""
    rng = np.random.default_rng(3)
    grid = sphere_grid(30.0)
    knee = np.radians(knee_deg)
    for trial in range(12):
        K = int(rng.integers(2, 12))
        # coarse scores (multiples of 1/8) make exact ties common
        scores = (rng.integers(0, 9, (K, grid.shape[0])) / 8.0) if trial % 2 else rng.random((K, grid.shape[0]))
        span = rng.integers(1, 5, K).astype(float)
        anchor = _unit(rng.normal(size=3)) if trial % 3 == 0 else None
        smooth = float(rng.choice([0.05, 0.6, 15.0]))
        got = best_chain(scores, grid, span, smooth, anchor, knee=knee)
        ref = _best_chain_reference(scores, grid, span, smooth, anchor, knee)
        if knee_deg == 0.0:
            assert np.array_equal(got, ref)
        else:
            args = (scores, grid, span, smooth, anchor, knee)
            assert _chain_objective(got, *args) == pytest.approx(_chain_objective(ref, *args), abs=1e-4)


def test_a_knee_makes_one_quick_turn_cheaper_than_a_slow_one():
    """Two nodes 4 waypoints apart, a 120° turn between them, a view that gains 4 × 0.1 = 0.4 by turning. The
    paper's term charges the turn 4 (1 − cos 30°) = 0.54 even spread over the 4 steps (1.5 at once); with a 1°
    knee it costs about its size in radians times the knee, 0.04, however it is made: the chain turns."""
    grid = sphere_grid(30.0)
    a = int(np.argmax(grid @ [1.0, 0, 0]))
    b = int(np.argmax(grid @ _unit([-0.5, np.sqrt(3) / 2, 0])))
    turn = float(np.degrees(angle_between(grid[a], grid[b])))
    assert abs(turn - 120.0) < 16.0
    # node 0 sees only a, node 1 sees a a little and b much better; spans 1 and 4
    scores = np.zeros((2, grid.shape[0]), np.float32)
    scores[0, a] = 1.0
    scores[1, a], scores[1, b] = 0.2, 0.3
    span = np.array([1.0, 4.0])
    smooth = 1.0
    assert list(best_chain(scores, grid, span, smooth)) == [a, a]
    assert list(best_chain(scores, grid, span, smooth, knee=np.radians(1.0))) == [a, b]
