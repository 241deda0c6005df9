"""Chain initialisation (pivotd.pivot.chain): node spacing, Viterbi choice, spherical fill."""

import numpy as np
from viterbi_reference import viterbi_reference

from pivotd.geometry import angle_between
from pivotd.pivot.brute import sphere_grid
from pivotd.pivot.chain import best_chain, node_indices, slerp_fill


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


def _best_chain_reference(scores, grid, span, smooth, anchor=None):
    """best_chain as the textbook Viterbi (tests/viterbi_reference.py), with the same float32 arithmetic."""
    scores = scores.astype(np.float32)
    val = scores * np.asarray(span, np.float32)[:, None]
    if anchor is not None:
        val[0] = val[0] + (smooth * (grid @ anchor - 1.0)).astype(np.float32)
    ang = np.arccos(np.clip(grid @ grid.T, -1.0, 1.0))
    pen = np.stack([((max(round(s), 1) * smooth) * (np.cos(ang / max(round(s), 1)) - 1.0)).astype(np.float32).T
                    for s in span[1:]])
    return viterbi_reference(val, pen)


def test_best_chain_equals_the_textbook_viterbi_exactly():
    rng = np.random.default_rng(3)
    grid = sphere_grid(30.0)
    for trial in range(12):
        K = int(rng.integers(2, 12))
        # coarse scores (multiples of 1/8) make exact ties common
        scores = (rng.integers(0, 9, (K, grid.shape[0])) / 8.0) if trial % 2 else rng.random((K, grid.shape[0]))
        span = rng.integers(1, 5, K).astype(float)
        anchor = _unit(rng.normal(size=3)) if trial % 3 == 0 else None
        smooth = float(rng.choice([0.05, 0.6, 15.0]))
        assert np.array_equal(best_chain(scores, grid, span, smooth, anchor),
                              _best_chain_reference(scores, grid, span, smooth, anchor))
