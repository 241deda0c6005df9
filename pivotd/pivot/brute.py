"""Brute-force reference: the best hard visible count over a grid of directions on the viewing sphere.

Grid: :func:`pivotd.pivot.lattice.sphere_grid`, rings of constant elevation every ``resolution`` with
neighbouring directions at most ``resolution`` apart (≈ 10 300 directions at 2°).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pivotd.geometry import tangent_basis
from pivotd.pivot._checks import feature_weights, finite_array, half_angle
from pivotd.pivot.lattice import grid_covering_radius, sphere_grid
from pivotd.pivot.view import boundary_axes

__all__ = ["RefinedView", "best_grid_chain", "brute_force_trajectory", "brute_force_view", "exact_view",
           "grid_neighbours", "grid_visibility", "refined_view"]

_POLAR = math.sqrt(1.0 - 0.3**2)  # the refinement's tangents turn to c × e_x where |c × e_z| < 0.3


def brute_force_view(
    bearings: np.ndarray,
    weights: np.ndarray | None,
    alpha: float,
    resolution_deg: float = 2.0,
    *,
    chunk: int = 1024,
    grid: np.ndarray | None = None,
) -> tuple[np.ndarray, float]:
    """Best grid direction (3,) and its hard visible weight (count when ``weights`` is None).

    ``grid`` (G, 3): ``sphere_grid(resolution_deg)`` computed once by callers scoring many poses (None: here).

    Evaluates Σ_j s_j [θ_j ≤ α] for every direction of :func:`sphere_grid` with float32 matrix
    products over ``chunk`` directions at a time: (chunk, 3) @ (3, n) cosines, compared with cos α in
    place (1.0 inside) and summed by one matrix-vector product with the weights; ties go to the first
    grid direction.
    """
    alpha = half_angle(alpha)
    B = finite_array("bearings", bearings)
    w = feature_weights(weights, B.shape[0])
    grid = sphere_grid(resolution_deg) if grid is None else grid
    if B.shape[0] == 0:
        return grid[0].copy(), 0.0
    BT = np.ascontiguousarray(B.T, dtype=np.float32)
    w32 = w.astype(np.float32)
    cos_a = np.float32(np.cos(alpha))
    g32 = grid.astype(np.float32)
    buf = np.empty((min(chunk, grid.shape[0]), B.shape[0]), np.float32)
    best_val, best_dir = -1.0, grid[0]
    for s in range(0, grid.shape[0], chunk):
        D = g32[s : s + chunk]
        inside = np.matmul(D, BT, out=buf[: D.shape[0]])
        np.greater_equal(inside, cos_a, out=inside)
        vals = inside @ w32
        i = int(np.argmax(vals))
        if vals[i] > best_val:
            best_val, best_dir = float(vals[i]), grid[s + i]
    return best_dir.copy(), best_val


def grid_neighbours(grid: np.ndarray, max_angle: float, *, chunk: int = 1024) -> np.ndarray:
    """Indices (G, L) of the grid directions within ``max_angle`` [rad] of each direction of ``grid``
    (G, 3), itself included; rows with fewer than L neighbours are padded with their own index."""
    g32 = grid.astype(np.float32)
    cos_m = np.float32(np.cos(max_angle) - 1e-6)
    rows: list[np.ndarray] = []
    for s in range(0, grid.shape[0], chunk):
        near = (g32[s : s + chunk] @ g32.T) >= cos_m
        rows.extend(np.flatnonzero(r) for r in near)
    width = max(r.size for r in rows)
    out = np.empty((grid.shape[0], width), dtype=np.intp)
    for k, r in enumerate(rows):
        out[k, : r.size] = r
        out[k, r.size :] = k
    return out


def grid_visibility(
    points: np.ndarray, waypoints: np.ndarray, alpha: float, grid: np.ndarray, weights: np.ndarray | None = None
) -> np.ndarray:
    """Hard visible weight (N, G) of ``points`` (M, 3) from each of ``waypoints`` (N, 3) [m] for every
    direction of ``grid`` (G, 3), half-angle α [rad]; a landmark at a waypoint never counts there."""
    alpha = half_angle(alpha)
    P = finite_array("points", points)
    T = finite_array("waypoints", waypoints)
    w32 = feature_weights(weights, P.shape[0]).astype(np.float32)
    gT = np.asarray(grid, dtype=np.float32).T
    cos_a = np.float32(np.cos(alpha))
    V = np.zeros((T.shape[0], gT.shape[1]), dtype=np.float32)
    for i in range(T.shape[0]):
        d = P - T[i]
        n = np.linalg.norm(d, axis=1)
        ok = n > 1e-12
        b = (d[ok] / n[ok, None]).astype(np.float32)
        inside = b @ gT  # (m, G) cosines, compared in place (1.0 inside)
        V[i] = w32[ok] @ np.greater_equal(inside, cos_a, out=inside)
    return V


def best_grid_chain(V: np.ndarray, grid: np.ndarray, max_step_deg: float | None) -> np.ndarray:
    """Grid index per waypoint (N,) maximising Σ_i V[i, k_i] with consecutive grid directions at most
    ``max_step_deg`` apart (exact: Viterbi); None: each waypoint's best index. V (N, G), grid (G, 3)."""
    N, G = V.shape
    if max_step_deg is None or N == 0:
        return np.argmax(V, axis=1)
    nb = grid_neighbours(grid, np.radians(max_step_deg))
    rows = np.arange(G)
    back = np.empty((N, G), dtype=np.int32)
    score = V[0].astype(np.float64)
    for i in range(1, N):
        cand = score[nb]  # (G, L): the best plans ending at each neighbour
        k = np.argmax(cand, axis=1)
        back[i] = nb[rows, k]
        score = cand[rows, k] + V[i]
    path = np.empty(N, dtype=np.intp)
    path[-1] = int(np.argmax(score))
    for i in range(N - 1, 0, -1):
        path[i - 1] = back[i, path[i]]
    return path


def brute_force_trajectory(
    points: np.ndarray,
    waypoints: np.ndarray,
    alpha: float,
    max_step_deg: float | None,
    resolution_deg: float = 2.0,
    *,
    weights: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray]:
    """The plan on the direction grid with the largest total hard visible weight whose consecutive
    directions are at most ``max_step_deg`` apart (exact over the grid); None: no step limit (each
    waypoint's best grid direction). Returns directions (N, 3) and visible weights (N,).

    The reference for trajectory plans: up to the grid's resolution it bounds what any plan with that
    largest step can see. ``points`` (M, 3), ``waypoints`` (N, 3) [m]. Cost: N·M·G comparisons
    (G ≈ 10 300 at 2°) plus N·G·L for the steps (L: grid directions within one step).
    """
    grid = sphere_grid(resolution_deg)
    V = grid_visibility(points, waypoints, alpha, grid, weights)
    path = best_grid_chain(V, grid, max_step_deg)
    return grid[path], V[np.arange(V.shape[0]), path].astype(float)


@dataclass(frozen=True)
class RefinedView:
    """The refined reference of one pose: ``direction`` (3,) unit, ``value`` its hard visible weight (a
    lower bound on the optimum), ``bound`` an upper bound on the hard visible weight of any direction,
    ``exact`` False when the cell cap cut the search (``bound`` then covers only the cells kept)."""

    direction: np.ndarray
    value: float
    bound: float
    exact: bool


def refined_view(
    bearings: np.ndarray,
    weights: np.ndarray | None,
    alpha: float,
    resolution_deg: float = 2.0,
    fine_deg: float = 0.25,
    *,
    max_expansions: int = 16384,
) -> RefinedView:
    """The reference single-pose optimum: the ``resolution_deg`` grid, then best-first branch and bound.

    Every grid direction g stands for the cell of directions within ρ (the grid's covering radius) of it;
    no direction of that cell sees more than the weight within α + ρ of g (the cell's bound). The cells
    with the highest bounds above the best hard weight found so far are split, 128 at a time, into 3 × 3
    children (a tangent-plane lattice at spacing ρ/√2 mapped onto S², each child a cell of radius ρ/2),
    which are scored the same way; cells spaced at most ``fine_deg`` apart are not split further (2° →
    1.02° → 0.51° → 0.26° → 0.13° from the 2° grid). The search ends when no cell's bound exceeds the
    best weight (``exact``: the optimum at that resolution is found and ``bound`` is the largest bound of
    the finest cells) or after ``max_expansions`` splits (``bound`` is then the largest open bound).
    Only landmarks in the band α ± 3ρ of a parent can change state among its children: the rest are
    counted once per parent. Hard weights in float32, as :func:`brute_force_view`.
    """
    alpha = half_angle(alpha)
    B = finite_array("bearings", bearings)
    w = feature_weights(weights, B.shape[0])
    nrm = np.linalg.norm(B, axis=1)
    keep = nrm > 1e-12  # a landmark at the sensor has no bearing
    B, w = B[keep] / nrm[keep, None], w[keep]
    grid = sphere_grid(resolution_deg)
    if B.shape[0] == 0:
        return RefinedView(grid[0].copy(), 0.0, 0.0, True)
    rho0 = grid_covering_radius(resolution_deg)
    B32, w32 = B.astype(np.float32), w.astype(np.float32)
    uniform = weights is None

    def weigh(mask: np.ndarray, wc: np.ndarray) -> np.ndarray:  # hard weight per row of a (k, m) mask
        return np.count_nonzero(mask, axis=1).astype(np.float64) if uniform else (mask @ wc).astype(np.float64)

    cos_a = np.float32(np.cos(alpha))
    vals, bounds = [], []
    cos_rho = np.float32(np.cos(min(np.pi, alpha + rho0)))
    for s in range(0, grid.shape[0], 1024):
        cos = grid[s : s + 1024].astype(np.float32) @ B32.T
        vals.append(weigh(cos >= cos_a, w32))
        bounds.append(weigh(cos >= cos_rho, w32))
    val, ub = np.concatenate(vals), np.concatenate(bounds)
    i = int(np.argmax(val))
    best_dir, best = grid[i].copy(), float(val[i])
    # the open cells: direction, bound, covering radius, lattice spacing
    live = ub > best
    dirs, cell_ub = grid[live], ub[live]
    rho = np.full(dirs.shape[0], rho0)
    spacing = np.full(dirs.shape[0], np.radians(resolution_deg))
    fine = np.radians(fine_deg) * 1.0001
    off = np.array([(a, b) for a in (-1, 0, 1) for b in (-1, 0, 1)], dtype=float)  # (9, 2) lattice offsets
    expansions = 0
    while True:
        open_ = np.flatnonzero((cell_ub > best) & (spacing > fine))
        if open_.size == 0 or expansions >= max_expansions:
            break
        take = open_[np.argsort(-cell_ub[open_], kind="stable")[: min(128, max_expansions - expansions)]]
        expansions += take.size
        P, r = dirs[take], rho[take][:, None]
        step = r / np.sqrt(2.0)
        child_rho = 0.5 * r * 1.01  # 1 %: the tangent-plane lattice mapped onto S² (distortion ~ρ²/6)
        t1, t2 = tangent_basis(P, polar=_POLAR)
        v = step[:, :, None] * (off[None, :, 0:1] * t1[:, None, :] + off[None, :, 1:2] * t2[:, None, :])
        ang = np.linalg.norm(v, axis=2, keepdims=True)
        kids = np.cos(ang) * P[:, None, :] + np.sinc(ang / np.pi) * v  # exp map: sin|v|/|v| · v  (p, 9, 3)
        kids = (kids / np.linalg.norm(kids, axis=2, keepdims=True)).reshape(-1, 3)
        reach = r + child_rho  # a child's cell lies within this of its parent
        cos_in = np.cos(np.maximum(0.0, alpha - reach)).astype(np.float32)
        cos_out = np.cos(np.minimum(np.pi, alpha + reach + child_rho)).astype(np.float32)
        cos_ub = np.repeat(np.cos(np.minimum(np.pi, alpha + child_rho)).astype(np.float32), 9, axis=0)
        cp = P.astype(np.float32) @ B32.T  # (p, n)
        base = np.repeat(weigh(cp >= cos_in, w32), 9)  # inside every child's cone and bound
        band = (cp >= cos_out) & (cp < cos_in)
        cols = np.flatnonzero(band.any(axis=0))
        wc = w32.take(cols)
        in_band = np.repeat(band[:, cols], 9, axis=0)  # (9p, m): only each parent's own band counts
        c = kids.astype(np.float32) @ B32.take(cols, axis=0).T  # (9p, m)
        kid_v = base + weigh((c >= cos_a) & in_band, wc)
        kid_u = base + weigh((c >= cos_ub) & in_band, wc)
        k = int(np.argmax(kid_v))
        if kid_v[k] > best:
            best, best_dir = float(kid_v[k]), kids[k].copy()
        rest = np.ones(dirs.shape[0], dtype=bool)
        rest[take] = False
        rest &= cell_ub > best
        new = kid_u > best
        dirs = np.concatenate([dirs[rest], kids[new]])
        cell_ub = np.concatenate([cell_ub[rest], kid_u[new]])
        rho = np.concatenate([rho[rest], np.repeat(child_rho[:, 0], 9)[new]])
        spacing = np.concatenate([spacing[rest], np.repeat(step[:, 0], 9)[new]])
    still_open = bool(np.any((cell_ub > best) & (spacing > fine)))
    bound = max(best, float(cell_ub.max(initial=best)))
    return RefinedView(best_dir, best, bound, not still_open)


def exact_view(
    bearings: np.ndarray, weights: np.ndarray | None, alpha: float, *, max_centres: int = 4_000_000
) -> tuple[np.ndarray, float]:
    """The exact single-pose optimum for half-angle α < 90° [rad]: a direction (3,) and its hard visible
    weight (closed cone, cos θ ≥ cos α − 1e-12, float64).

    A cone holding a set S of bearings can be moved, keeping S inside, until one of them is on its edge and
    then turned about that one until a second is (for α < 90° the cones of radius α whose edge passes
    through p meet only in p, so if none does, S is that single bearing). The optimum is therefore
    centred on a bearing or on one of the two axes at angle α from a pair of bearings at most 2α apart:
    every such axis is scored on all bearings, O(P n) for P such pairs. Meant for small instances; raises
    ValueError when the axes would exceed ``max_centres``.
    """
    alpha = half_angle(alpha)
    if alpha >= np.pi / 2:
        raise ValueError(f"exact_view needs a half-angle below 90°, got {np.degrees(alpha):.3g}°")
    B = finite_array("bearings", bearings)
    w = feature_weights(weights, B.shape[0])
    nrm = np.linalg.norm(B, axis=1)
    keep = nrm > 1e-12
    B, w = B[keep] / nrm[keep, None], w[keep]
    if B.shape[0] == 0:
        return np.array([1.0, 0.0, 0.0]), 0.0
    ca = np.cos(alpha)
    C = np.concatenate([B, boundary_axes(B, alpha)])
    if C.shape[0] > max_centres:
        raise ValueError(f"exact_view: {C.shape[0]} candidate axes exceed max_centres={max_centres}")
    best, best_dir = -1.0, B[0]
    for s in range(0, C.shape[0], 2048):
        cos_cb = C[s : s + 2048] @ B.T
        vals = (cos_cb >= ca - 1e-12) @ w
        k = int(np.argmax(vals))
        if vals[k] > best:
            best, best_dir = float(vals[k]), C[s + k]
    return best_dir / np.linalg.norm(best_dir), best
