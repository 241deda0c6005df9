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
