"""Global initialisation of a trajectory: dynamic programming over a grid of directions on S².

Gradient ascent only finds the nearest local optimum; on paths whose best view switches between
competing feature clusters that leaves a jump (a local optimum the smoothness gradient cannot undo:
c × (c_prev + c_next) vanishes for antipodal neighbours). This module picks, for a subset of "node"
waypoints, one grid direction each maximising

    Σ_nodes s_n · V_n(d_n)  +  λκ Σ_transitions s · (v(cos(Δ_n / s)) − 1)

where v is the smoothness term's pair value (:mod:`pivotd.pivot.smoothness`; v(x) = x without a knee),
V_n is the hard visible fraction of the node's (subsampled) landmarks, s the number of waypoints a
node stands for and Δ_n the angle between consecutive node directions (a turn of Δ spread evenly over s
waypoints). The result, interpolated along the path by slerp, seeds the gradient ascent.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from pivotd.geometry import slerp
from pivotd.pivot.brute import best_grid_chain
from pivotd.pivot.lattice import sphere_grid
from pivotd.pivot.smoothness import pair_value

__all__ = ["Exact", "best_chain", "grid_scores", "initial_directions", "node_indices", "refine_top_scores",
           "slerp_fill", "step_limited_directions"]


def node_indices(n: int, max_nodes: int) -> np.ndarray:
    """At most ``max_nodes`` evenly spread waypoint indices, always including the first and last."""
    if n <= max_nodes:
        return np.arange(n)
    return np.unique(np.round(np.linspace(0, n - 1, max_nodes)).astype(np.intp))


def grid_scores(bearings: np.ndarray, weights: np.ndarray, grid: np.ndarray, alpha: float) -> np.ndarray:
    """Hard visible fraction (K, G) per grid direction of unit ``bearings`` (K, L, 3) with ``weights`` (K, L)."""
    K = bearings.shape[0]
    total = weights.sum(axis=1, dtype=np.float64)
    out = np.zeros((K, grid.shape[0]), dtype=np.float32)
    g32 = grid.T.astype(np.float32)
    cos_a = np.float32(np.cos(alpha))
    chunk = max(1, int(4_000_000 // max(bearings.shape[1] * grid.shape[0], 1)))
    for s in range(0, K, chunk):
        x = bearings[s : s + chunk] @ g32  # (k, L, G) cosines
        np.greater_equal(x, cos_a, out=x, casting="unsafe")  # 1.0 inside, 0.0 outside, in place
        out[s : s + chunk] = np.matmul(weights[s : s + chunk, None, :], x)[:, 0, :]
    return out / np.where(total > 0, total, 1.0)[:, None].astype(np.float32)


def best_chain(
    scores: np.ndarray,
    grid: np.ndarray,
    span: np.ndarray,
    smooth: float,
    anchor: np.ndarray | None = None,
    knee: float = 0.0,
) -> np.ndarray:
    """Grid index per node (K,) maximising the module's objective (Viterbi).

    scores (K, G): visible fractions; span (K,): waypoints each node stands for (≥ 1); smooth: λκ ≥ 0;
    anchor (3,): a fixed direction before node 0 (cost of turning from it counts once); knee [rad]: the
    smoothness term's knee (:mod:`pivotd.pivot.smoothness`).
    """
    K, G = scores.shape
    if smooth <= 0:
        return np.argmax(scores, axis=1)
    scores = scores.astype(np.float32)
    value = scores[0] * np.float32(span[0])
    ang = np.arccos(np.clip(grid @ grid.T, -1.0, 1.0))
    if anchor is not None:
        value = value + (smooth * (pair_value(grid @ anchor, knee) - 1.0)).astype(np.float32)
    back = np.zeros((K, G), dtype=np.intp)
    gain = scores * span.astype(np.float32)[:, None]
    total = np.empty((G, G), dtype=np.float32)  # (to, from), reused: three numpy calls per node
    take = total.reshape(-1).take
    row_start = np.arange(G) * G
    idx = np.empty(G, dtype=np.intp)
    cache: dict[int, np.ndarray] = {}
    for k in range(1, K):
        s = max(round(span[k]), 1)
        trans = cache.get(s)
        if trans is None:  # indexed (to, from): the argmax runs along contiguous rows
            trans = np.ascontiguousarray(((s * smooth) * (pair_value(np.cos(ang / s), knee) - 1.0))
                                         .astype(np.float32).T)
            cache[s] = trans
        np.add(trans, value, out=total)
        total.argmax(axis=1, out=back[k])
        np.add(row_start, back[k], out=idx)
        value = take(idx) + gain[k]
    path = np.empty(K, dtype=np.intp)
    path[-1] = int(np.argmax(value))
    for k in range(K - 1, 0, -1):
        path[k - 1] = back[k, path[k]]
    return path


def slerp_fill(n: int, nodes: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Unit directions (n, 3) for every waypoint, spherically interpolated between node directions (K, 3)."""
    out = np.empty((n, 3))
    out[: nodes[0] + 1] = dirs[0]
    out[nodes[-1] :] = dirs[-1]
    if nodes.size > 1:
        idx = np.arange(nodes[0], nodes[-1] + 1)
        seg = np.clip(np.searchsorted(nodes, idx, side="right") - 1, 0, nodes.size - 2)
        a, b = nodes[seg], nodes[seg + 1]
        t = (idx - a) / np.maximum(b - a, 1)
        out[idx] = slerp(dirs[seg], dirs[seg + 1], t)
    return out / np.linalg.norm(out, axis=1, keepdims=True)


def initial_directions(
    bearings: np.ndarray,
    weights: np.ndarray,
    alpha: float,
    smooth: float,
    nodes: np.ndarray,
    n: int,
    *,
    resolution_deg: float = 12.0,
    anchor: np.ndarray | None = None,
    knee: float = 0.0,
) -> np.ndarray:
    """Chain initialisation (n, 3) from unit ``bearings`` (K, L, 3) and ``weights`` (K, L) of the node
    waypoints ``nodes`` (K,) (increasing indices into the n waypoints, see :func:`node_indices`).

    λ = 0 (``smooth`` 0) picks each node's best grid direction independently (pass every waypoint as a node).
    """
    grid = sphere_grid(resolution_deg)
    nodes = np.asarray(nodes, dtype=np.intp)
    scores = grid_scores(bearings, weights, grid, alpha)
    span = np.diff(nodes, prepend=nodes[0] - 1).astype(float) if nodes.size > 1 else np.ones(1)
    choice = best_chain(scores, grid, span, smooth, anchor, knee)
    return slerp_fill(n, nodes, grid[choice])


Exact = Callable[[int, np.ndarray], np.ndarray]


def refine_top_scores(
    scores: np.ndarray, grid: np.ndarray, exact: Exact, sample: np.ndarray, full: np.ndarray
) -> np.ndarray:
    """Coarse to fine: grid scores (K, G) from a sample of ``sample[k]`` of node k's ``full[k]`` landmarks,
    with each node's best directions by the sample rescored on all its landmarks by
    ``exact(k, directions (m, 3)) -> (m,)`` visible fractions.

    Node k rescores its m_k = ⌈G · sample[k] / full[k]⌉ best directions (as much work again as scoring the
    sample on the whole grid), so the choice among near-equal directions, which a sample's noise decides
    at random, is made on exact counts; nodes whose sample is all their landmarks keep their scores. Its
    other directions keep their sample score, but no more than the lowest rescored one: the sample ranked
    them lower.
    """
    K, G = scores.shape
    out = scores.copy()
    for k in range(K):
        if full[k] <= sample[k] or full[k] == 0:
            continue
        m = min(G, max(1, math.ceil(G * sample[k] / full[k])))
        top = np.argpartition(-scores[k], m - 1)[:m] if m < G else np.arange(G)
        ex = np.asarray(exact(k, grid[top]), dtype=np.float64)
        np.minimum(out[k], ex.min(initial=np.inf), out=out[k])
        out[k, top] = ex
    return out


def step_limited_directions(
    bearings: np.ndarray,
    weights: np.ndarray,
    alpha: float,
    nodes: np.ndarray,
    n: int,
    max_step: float,
    *,
    resolution_deg: float = 12.0,
    anchor: np.ndarray | None = None,
    exact: Exact | None = None,
    full_sizes: np.ndarray | None = None,
) -> np.ndarray:
    """Initialisation (n, 3) for a hard step limit ``max_step`` [rad]: the node directions with the largest
    total visible fraction whose consecutive node directions are at most s × max_step apart (s: the
    smallest node span), exactly over a grid of resolution clamp(s × max_step / 2, 2°, ``resolution_deg``)
    (:func:`pivotd.pivot.brute.best_grid_chain`), slerped in between, so every step is ≤ max_step.

    With an anchor, node 0 stays within max_step + the grid's resolution of it. bearings (K, L, 3),
    weights (K, L) as in :func:`initial_directions`. When they are a sample of each node's landmarks,
    ``exact(k, directions (m, 3)) -> (m,)`` (the visible fraction of all of node k's landmarks) and
    ``full_sizes`` (K,) (how many landmarks each node has) refine the sample's scores
    (:func:`refine_top_scores`).
    """
    nodes = np.asarray(nodes, dtype=np.intp)
    span = int(np.diff(nodes).min()) if nodes.size > 1 else 1
    res = float(np.clip(np.degrees(span * max_step) / 2, 2.0, max(resolution_deg, 2.0)))
    grid = sphere_grid(res)
    scores = grid_scores(bearings, weights, grid, alpha).astype(np.float64)
    if exact is not None and full_sizes is not None:
        sample = np.count_nonzero(weights > 0, axis=1)
        scores = refine_top_scores(scores, grid, exact, sample, np.asarray(full_sizes))
    if anchor is not None:
        far = grid @ anchor < np.cos(min(np.pi, max_step + np.radians(res)))
        scores[0, far] = -np.inf
    choice = best_grid_chain(scores, grid, np.degrees(span * max_step))
    return slerp_fill(n, nodes, grid[choice])
