"""The seeds of a trajectory problem: the starting plans :meth:`TrajectoryProblem.solve` is run from.

Each seed is produced where it applies and judged like every other (the objective, :func:`best_of`):

- ``chain``: dynamic programming over a grid of directions on S² (:mod:`pivotd.pivot.chain`), the global start
  of every cold plan;
- ``narrow``: cones narrower than ``ViewOptions.narrow_deg``: the node waypoints' single-view optima
  (:func:`pivotd.pivot.view.optimize_view`), slerped between (the chain's grid cannot find a cone a few degrees
  wide);
- ``step_limited``: under a hard step limit, the best plan within it on a grid (the λ plan may take another
  route than the limit allows);
- ``fixed`` (derived from a plan that stays within α of one direction): the best single direction for node
  waypoints — on flat landscapes (a sensor inside a cloud or a ring) the cold solve can settle in a worse basin.

The caller adds its own: the previous plan and the commanded direction (the daemon's warm seeds), the rescue of
blind waypoints (:mod:`pivotd.pivot.rescue`).
"""

from __future__ import annotations

import math

import numpy as np

from pivotd.pivot import _ascent, chain
from pivotd.pivot.pairs import path_directions
from pivotd.pivot.steps import limit_steps
from pivotd.pivot.trajectory import (
    Seed,
    SeedKind,
    TrajectoryProblem,
    TrajectoryResult,
    _independent_views,
    _view_kernel,
)
from pivotd.pivot.view import ViewOptions, optimize_view

__all__ = ["chain_seed", "cold_seeds", "derived_seeds", "fixed_seed", "narrow_seed", "step_limited_seed"]


def _linked(problem: TrajectoryProblem) -> bool:
    """Whether consecutive waypoints are coupled (smoothness or a step limit)."""
    return problem.smooth > 0 or problem.max_step is not None


def chain_seed(problem: TrajectoryProblem) -> Seed | None:
    """The chain DP over node waypoints (every waypoint when nothing couples them); None without landmarks."""
    geom, opts = problem.geom, problem.opts
    if geom is None:
        return None
    N, lengths = problem.n, problem.lengths
    nodes = chain.node_indices(N, opts.chain_nodes) if _linked(problem) else np.arange(N)
    sub = _ascent.subsample(geom.take_rows(nodes), lengths[nodes], opts.active_cap)
    if problem.smooth > 0:
        scores, score_nodes = sub, nodes
    else:
        scores, score_nodes = _ascent.subsample(geom, lengths, opts.active_cap), np.arange(N)
    C = chain.initial_directions(
        scores.points, scores.weights, problem.alpha, problem.smooth * problem.chain_smooth_ratio, score_nodes, N,
        resolution_deg=opts.chain_resolution_deg, anchor=problem.anchor, knee=problem.knee,
    )
    return Seed("chain", C, SeedKind.GRID)


def narrow_seed(problem: TrajectoryProblem) -> Seed | None:
    """Single-view optima of node waypoints slerped between, for cones narrower than ``ViewOptions.narrow_deg``
    (None otherwise, or without smoothness or landmarks)."""
    opts = problem.opts
    if (problem.geom is None or problem.smooth <= 0 or opts.narrow_seed_nodes <= 0
            or problem.alpha >= math.radians(ViewOptions.narrow_deg)):
        return None
    nodes = chain.node_indices(problem.n, opts.narrow_seed_nodes)
    peaks = _independent_views(lambda k: problem.views(int(nodes[k])), problem.T[nodes], problem.alpha, None,
                               opts.distance_weights).directions
    return Seed("narrow", chain.slerp_fill(problem.n, nodes, peaks), SeedKind.POINT)


def step_limited_seed(problem: TrajectoryProblem) -> Seed | None:
    """Under a hard step limit: the node directions with the largest visible total whose steps stay within it,
    on a grid (:func:`pivotd.pivot.chain.step_limited_directions`); None without a limit or landmarks."""
    geom, opts = problem.geom, problem.opts
    if geom is None or problem.max_step is None or opts.seed_cap <= 0 or opts.step_polish_deg <= 0:
        return None
    nodes = chain.node_indices(problem.n, opts.chain_nodes)
    sub = _ascent.subsample(geom.take_rows(nodes), problem.lengths[nodes], opts.seed_cap)
    C = chain.step_limited_directions(
        sub.points, sub.weights, problem.alpha, nodes, problem.n, problem.max_step,
        resolution_deg=opts.chain_resolution_deg, anchor=problem.anchor,
        exact=lambda k, D: _visible_fraction(geom, int(nodes[k]), D, problem.alpha),
        full_sizes=problem.lengths[nodes],
    )
    if problem.constraint is not None:
        C = problem.constraint.project(C)
    C = limit_steps(C, problem.max_step, anchor=problem.anchor, constraint=problem.constraint)
    return Seed("step_limited", C, SeedKind.LIMITED)


def cold_seeds(problem: TrajectoryProblem) -> list[Seed]:
    """The seeds of a plan made without a previous one: chain, narrow, step_limited (those that apply)."""
    out = [chain_seed(problem), narrow_seed(problem), step_limited_seed(problem)]
    found = [s for s in out if s is not None]
    return found or [Seed("path", path_directions(problem.T), SeedKind.GRID)]


def fixed_seed(problem: TrajectoryProblem, plan: TrajectoryResult) -> Seed | None:
    """The best single direction over node waypoints, when ``plan`` stays within α of one direction (None
    otherwise, or without smoothness or landmarks)."""
    geom, opts = problem.geom, problem.opts
    if geom is None or problem.smooth <= 0 or opts.fixed_nodes <= 0 or _spread(plan.directions) > problem.alpha:
        return None
    nodes = chain.node_indices(problem.n, opts.fixed_nodes)
    d = _fixed_direction(geom.take_rows(nodes), problem.lengths[nodes], problem.norm[nodes], problem.alpha,
                         opts.fixed_cap)
    return Seed("fixed", np.tile(d, (problem.n, 1)), SeedKind.POINT)


def derived_seeds(problem: TrajectoryProblem, plan: TrajectoryResult) -> list[Seed]:
    """Seeds that depend on the best plan of the cold seeds: ``fixed`` where it applies."""
    s = fixed_seed(problem, plan)
    return [] if s is None else [s]


def _spread(C: np.ndarray) -> float:
    """Largest angle [rad] between the axes C (N, 3) and their mean direction (π when they cancel out)."""
    m = C.sum(axis=0)
    norm = float(np.linalg.norm(m))
    if norm < 1e-9:
        return math.pi
    return float(np.arccos(np.clip((C @ m).min() / norm, -1.0, 1.0)))



def _fixed_direction(geom: _ascent.Geometry, lengths: np.ndarray, norm: np.ndarray, alpha: float,
                     cap: int) -> np.ndarray:
    """The single direction (3,) seeing the most of the rows' landmarks together, each row's weights divided
    by its W_i (``norm`` (K,)) as in the objective: :func:`optimize_view` on at most ``cap`` strided bearings
    per row."""
    sub = _ascent.subsample(geom, lengths, cap)
    w = sub.weights / np.maximum(norm, 1e-12)[:, None].astype(np.float32)
    keep = w > 0
    B = sub.points[keep].astype(np.float64)
    if B.shape[0] == 0:
        return np.array([1.0, 0.0, 0.0])
    return optimize_view(B, w[keep].astype(np.float64), alpha, kernel=_view_kernel(alpha, B.shape[0])).direction



def _visible_fraction(geom: _ascent.Geometry, row: int, D: np.ndarray, alpha: float) -> np.ndarray:
    """Hard visible fraction of the weight of all of waypoint ``row``'s landmarks (m,) for axes D (m, 3)."""
    D32 = D.astype(np.float32)
    W = geom.weights[row] if geom.weights.ndim == 2 else geom.weights
    if geom.shared:
        x = D32 @ geom.points.T
        if geom.inv_dist is not None:
            x -= (D32 @ geom.origins[row])[:, None]
            x *= geom.inv_dist[row][None, :]
    else:
        x = D32 @ geom.points[row].T
    np.greater_equal(x, np.float32(np.cos(alpha)), out=x, casting="unsafe")
    total = float(np.sum(W, dtype=np.float64))
    return (x @ W).astype(float) / (total if total > 0 else 1.0)


