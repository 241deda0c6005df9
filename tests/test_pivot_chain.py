"""Chain initialisation (pivotd.pivot.chain): node spacing, Viterbi choice, spherical fill."""

import numpy as np

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
    """The textbook Viterbi of best_chain, one fancy-indexed step per node, same float32 arithmetic."""
    K, G = scores.shape
    scores = scores.astype(np.float32)
    value = scores[0] * np.float32(span[0])
    ang = np.arccos(np.clip(grid @ grid.T, -1.0, 1.0))
    if anchor is not None:
        value = value + (smooth * (grid @ anchor - 1.0)).astype(np.float32)
    back = np.zeros((K, G), dtype=int)
    for k in range(1, K):
        s = max(round(span[k]), 1)
        trans = ((s * smooth) * (np.cos(ang / s) - 1.0)).astype(np.float32).T
        total = trans + value[None, :]
        back[k] = np.argmax(total, axis=1)
        value = total[np.arange(G), back[k]] + scores[k] * np.float32(span[k])
    path = [int(np.argmax(value))]
    for k in range(K - 1, 0, -1):
        path.append(int(back[k, path[-1]]))
    return np.array(path[::-1])


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
