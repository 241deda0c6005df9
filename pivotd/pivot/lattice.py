"""Direction lattices on the unit sphere S²: the near-uniform Fibonacci lattice, the rings-of-elevation grid of the
brute-force references (with its measured covering radius), the azimuth × elevation grid of the teleport policy and
the sunflower spirals over a cap of the local searches."""

from __future__ import annotations

import math

import numpy as np

from pivotd.geometry import pan_tilt_to_direction

__all__ = ["GOLDEN_ANGLE", "azimuth_elevation_grid", "fibonacci_sphere", "grid_covering_radius", "sphere_grid",
           "spiral_caps"]

GOLDEN_ANGLE = math.pi * (3.0 - math.sqrt(5.0))  # [rad] azimuth step of the Fibonacci lattice and the spirals


def fibonacci_sphere(n: int) -> np.ndarray:
    """n near-uniform unit directions (n, 3) (Fibonacci lattice; neighbours ≈ √(4π/n) rad apart)."""
    i = np.arange(0.5, n, dtype=np.float64)
    out = np.empty((n, 3))
    z = out[:, 2]
    np.multiply(i, 2.0, out=z)
    z /= n
    np.subtract(1.0, z, out=z)
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    phi = i * GOLDEN_ANGLE
    np.multiply(r, np.cos(phi), out=out[:, 0])
    np.multiply(r, np.sin(phi), out=out[:, 1])
    return out


def sphere_grid(resolution_deg: float = 2.0) -> np.ndarray:
    """Unit directions (G, 3) covering S² at the angular resolution ``resolution_deg`` [deg]: rings of constant
    elevation every ``resolution`` from −90° to +90° (both poles included); on a ring at elevation e the azimuth
    step is resolution / cos e (rounded so the ring closes), so neighbouring grid directions are at most
    ``resolution`` apart. At 2° this is ≈ 10 300 directions, the equal-area count 4π/(2°)². Raises ValueError
    outside (0, 90]."""
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


def grid_covering_radius(resolution_deg: float = 2.0) -> float:
    """Covering radius [rad] of :func:`sphere_grid`: every unit direction lies within it of a grid direction.

    Measured, not assumed: the largest distance to the nearest grid direction over a dense sample
    (40 elevations per ring gap × azimuths at 1/40 of the coarser ring's step) between every pair of
    neighbouring rings, the nearest candidates taken on both rings, plus 2 % (the sample's spacing).
    """
    grid = sphere_grid(resolution_deg)
    el = np.arcsin(np.clip(grid[:, 2], -1.0, 1.0))
    rings = np.unique(np.round(el, 12))
    counts = np.array([np.count_nonzero(np.abs(el - r) < 1e-9) for r in rings])
    worst = 0.0
    for k in range(rings.size - 1):
        e = np.linspace(rings[k], rings[k + 1], 41)
        step = 2 * np.pi / min(counts[k], counts[k + 1])
        az = np.arange(0.0, step + 1e-12, step / 40)
        E, A = np.meshgrid(e, az, indexing="ij")
        best = np.full(E.shape, np.pi)
        for r, n in ((rings[k], counts[k]), (rings[k + 1], counts[k + 1])):
            d_az = 2 * np.pi / n
            node = np.round(A / d_az) * d_az
            for off in (-d_az, 0.0, d_az):
                cosd = np.sin(E) * np.sin(r) + np.cos(E) * np.cos(r) * np.cos(A - node - off)
                best = np.minimum(best, np.arccos(np.clip(cosd, -1.0, 1.0)))
        worst = max(worst, float(best.max()))
    return 1.02 * worst


def azimuth_elevation_grid(step_deg: float) -> np.ndarray:
    """Unit directions (G, 3) on an azimuth × elevation grid of ``step_deg`` [deg] (poles excluded), azimuth-major:
    azimuths from −180°, elevations from −90° + step (the pan/tilt convention of :mod:`pivotd.geometry`)."""
    step = math.radians(step_deg)
    az = np.arange(-math.pi, math.pi - 1e-9, step)
    el = np.arange(-math.pi / 2 + step, math.pi / 2 - 1e-9, step)
    a, e = np.meshgrid(az, el, indexing="ij")
    return pan_tilt_to_direction(a.ravel(), -e.ravel())


def spiral_caps(radii: list[float], points: list[int]) -> list[np.ndarray]:
    """For each radius r_k [rad] of ``radii``, the local coordinates (1 + P_k, 3) of a sunflower spiral over a cap:
    row 0 the cap's centre (1, 0, 0), then ``points[k]`` directions spread evenly (equal area per direction) over
    the cap of radius r_k around it (spacing ≈ r_k · √(π / P_k)), as (cos ρ, sin ρ cos φ, sin ρ sin φ) for polar
    radius ρ = r_k √((i + ½) / P_k) and azimuth φ = (i + ½) · GOLDEN_ANGLE. Map a level onto the sphere with a
    frame (3, 3) whose rows are the cap's axis and two tangents. All levels in one set of array calls."""
    sizes = [int(p) + 1 for p in points]  # each level: its centre, then its spiral
    starts = [sum(sizes[:k]) for k in range(len(sizes))]
    i = np.arange(sum(sizes), dtype=float) - np.repeat(np.array(starts, float) + 0.5, sizes)
    np.maximum(i, 0.0, out=i)  # i + 0.5 along each spiral, 0 at the centres
    r = np.sqrt(i)
    r *= np.repeat([rk / math.sqrt(p) for rk, p in zip(radii, points, strict=True)], sizes)  # r_k √(i / P_k)
    i *= GOLDEN_ANGLE  # azimuth
    flat = np.empty((r.size, 3))
    np.cos(r, out=flat[:, 0])
    np.sin(r, out=r)
    np.multiply(r, np.cos(i), out=flat[:, 1])
    np.multiply(r, np.sin(i), out=flat[:, 2])
    return [flat[s : s + p] for s, p in zip(starts, sizes, strict=True)]
