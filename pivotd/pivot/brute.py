"""Brute-force reference: the best hard visible count over a grid of directions on the viewing sphere.

Grid (``sphere_grid``): rings of constant elevation every ``resolution`` from −90° to +90°
(both poles included); on a ring at elevation e the azimuth step is resolution / cos e (rounded so the
ring closes), so neighbouring grid directions are at most ``resolution`` apart. At 2° this is
≈ 10 300 directions, the equal-area count 4π/(2°)².
"""

from __future__ import annotations

import numpy as np

from pivotd.pivot._checks import feature_weights, finite_array, half_angle


def sphere_grid(resolution_deg: float = 2.0) -> np.ndarray:
    """Unit directions (G, 3) covering S² at the given angular resolution [deg] (see module docstring)."""
    if not (np.isfinite(resolution_deg) and 0 < resolution_deg <= 90):
        raise ValueError(f"resolution_deg must be in (0, 90], got {resolution_deg}")
    res = np.radians(resolution_deg)
    n_rings = round(np.pi / res)
    out = []
    for el in np.linspace(-np.pi / 2, np.pi / 2, n_rings + 1):
        ce = np.cos(el)
        n_az = max(1, int(np.ceil(2 * np.pi * ce / res - 1e-9))) if ce > 1e-9 else 1
        az = np.arange(n_az) * (2 * np.pi / n_az)
        out.append(np.stack([ce * np.cos(az), ce * np.sin(az), np.full(n_az, np.sin(el))], axis=1))
    return np.concatenate(out)


def brute_force_view(
    bearings: np.ndarray,
    weights: np.ndarray | None,
    alpha: float,
    resolution_deg: float = 2.0,
    *,
    chunk: int = 1024,
) -> tuple[np.ndarray, float]:
    """Best grid direction (3,) and its hard visible weight (count when ``weights`` is None).

    Evaluates Σ_j s_j [θ_j ≤ α] for every direction of :func:`sphere_grid` with float32 matrix
    products over ``chunk`` directions at a time; ties go to the first grid direction.
    """
    alpha = half_angle(alpha)
    B = finite_array("bearings", bearings)
    w = feature_weights(weights, B.shape[0])
    grid = sphere_grid(resolution_deg)
    if B.shape[0] == 0:
        return grid[0].copy(), 0.0
    B32 = B.astype(np.float32)
    w32 = w.astype(np.float32)
    uniform = weights is None
    cos_a = np.float32(np.cos(alpha))
    best_val, best_dir = -1.0, grid[0]
    for s in range(0, grid.shape[0], chunk):
        D = grid[s : s + chunk].astype(np.float32)
        inside = cos_a <= (B32 @ D.T)
        vals = np.count_nonzero(inside, axis=0) if uniform else w32 @ inside
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
        V[i] = w32[ok] @ ((b @ gT) >= cos_a)
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
