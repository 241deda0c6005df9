"""Approximate cone counts on a cube-map binning of the viewing sphere, for one FoV half-angle.

A direction u is binned by the surface voxel of an m × m × m cube that u / max|u_i| falls in: key
ix·m² + iy·m + iz with each index ⌊(q + 1) m / 2⌋ (clipped to m − 1) of the scaled coordinate q ∈ [−1, 1].
Inside a face these are the cells of a cube map with m × m cells per face; edge and corner voxels merge the
face cells they join. One ``bincount`` of the keys gives the histogram of the bearings (exact integer
counts with unit weights, so independent of the landmarks' order), and one sparse product with the
cells × cells cone-overlap matrix gives the approximate visible weight of a cone centred on every cell.

The matrix depends only on α and m: build it once (:func:`cone_kernel`) and pass it to every call that
uses the same half-angle (``optimize_view(…, kernel=…)``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pivotd.pivot._checks import half_angle
from pivotd.pivot.lattice import fibonacci_sphere

__all__ = ["ConeKernel", "cell_keys", "cells_per_face", "cone_kernel"]


def cells_per_face(alpha: float) -> int:
    """Default cube-map resolution m for half-angle α [rad]: cells ≈ α / 2.7 wide at a face centre (m = 16 at
    α = 15°), clamped to 4 … 24."""
    return int(min(24, max(4, round(math.radians(90.0) * 2.7 / alpha))))


def cell_keys(BT: np.ndarray, m: int) -> np.ndarray:
    """Surface-voxel key (n,) intp of every unit direction of BT (3, n) float32 (see the module docstring).

    The scaled coordinates are shrunk by 2⁻¹⁵ towards the cube's centre, so that their float32 rounding
    (≈ 10⁻⁶ m) never takes one outside 0 … m − 1 and no clipping pass is needed (a direction within 2⁻¹⁵ of
    a cell boundary may fall in the neighbouring cell)."""
    A = np.abs(BT)
    s = A.max(axis=0)
    np.divide(np.float32(0.5 * m * (1.0 - 2.0**-15)), s, out=s)  # (m / 2)(1 − 2⁻¹⁵) / max|u_i|
    Q = np.multiply(BT, s, out=A)
    Q += np.float32(0.5 * m)
    np.floor(Q, out=Q)
    return (np.array([m * m, m, 1], np.float32) @ Q).astype(np.intp)  # exact: keys < 2²⁴


def _disc_fraction(t: np.ndarray) -> np.ndarray:
    """Fraction of a disc on the inner side of a straight edge at signed distance t (in radii) from its centre."""
    t = np.clip(t, -1.0, 1.0)
    return 0.5 + (t * np.sqrt(1.0 - t * t) + np.arcsin(t)) / math.pi


@dataclass(frozen=True)
class ConeKernel:
    """The cone-overlap matrix of the cube-map cells for half-angle ``alpha`` [rad] and ``m`` cells per face.

    keys (C,) the surface voxels (C = m³ − (m − 2)³); centres (C, 3) float32 unit mean direction of each;
    radius (C,) angular radius [rad] of a disc of the same area; the matrix in CSR form over those cells:
    row i (``indptr[i]:indptr[i + 1]``) lists the voxel keys ``indices`` whose cell overlaps the cone of
    half-angle α around centre i and ``overlap`` (float32) the estimated fraction of that cell inside it
    (the cell as a disc of its area cut by the cone's edge, at most the cone's area over the cell's).
    ``soft_lo``/``soft_span`` (C,) float32: the same fraction for any axis, linear in the cosine between the
    axis and the cell's centre (:meth:`soft_weights`). ``centres_t`` (3, C): the centres' contiguous transpose
    ((K, 3) @ (3, C) products on a transposed view take several times as long); ``centres1`` (C, 4): the
    centres with a column of ones (one product gives a weighted sum of centres and the total weight).
    """

    alpha: float
    m: int
    keys: np.ndarray
    centres: np.ndarray
    radius: np.ndarray
    indptr: np.ndarray
    indices: np.ndarray
    overlap: np.ndarray
    soft_lo: np.ndarray
    soft_span: np.ndarray
    soft_cap: np.ndarray | None
    centres_t: np.ndarray
    centres1: np.ndarray

    @property
    def size(self) -> int:
        """Number of histogram bins a :func:`cell_keys` key can fall in (m³)."""
        return self.m**3

    def counts(self, hist: np.ndarray) -> np.ndarray:
        """Approximate visible weight (C,) of the cone centred on every cell, from ``hist`` (m³,) (bincount of keys)."""
        v = hist.take(self.indices) * self.overlap
        return np.add.reduceat(v, self.indptr[:-1])

    def soft_weights(self, cos_c: np.ndarray) -> np.ndarray:
        """Estimated fraction (K, C) float32 of each cell inside the cones of K axes, from their cosines
        ``cos_c`` (K, C) float32 to the cell centres (overwritten)."""
        cos_c -= self.soft_lo
        cos_c *= self.soft_span
        np.maximum(cos_c, np.float32(0.0), out=cos_c)  # two ufuncs: np.clip's wrapper costs more than both
        np.minimum(cos_c, np.float32(1.0), out=cos_c)
        if self.soft_cap is not None:
            cos_c *= self.soft_cap
        return cos_c


def cone_kernel(alpha: float, m: int | None = None, *, samples_per_cell: int = 48) -> ConeKernel:
    """Build the :class:`ConeKernel` for half-angle α [rad] and m cells per face (None: :func:`cells_per_face`).

    The cells' centres and areas come from binning a Fibonacci lattice of ``samples_per_cell`` directions per
    cell. Cost ≈ 10 ms at m = 16 (C = 1352 cells; 25–55 ms on a loaded host): build once per α and reuse.
    """
    alpha = half_angle(alpha)
    m = cells_per_face(alpha) if m is None else int(m)
    if m < 2:
        raise ValueError(f"cells per face must be >= 2, got {m}")
    n_s = samples_per_cell * 6 * m * m
    S = fibonacci_sphere(n_s).astype(np.float32)
    ST = np.ascontiguousarray(S.T)
    k = cell_keys(ST, m)
    cnt = np.bincount(k, minlength=m**3)
    sums = np.stack([np.bincount(k, weights=c, minlength=m**3) for c in ST], axis=1)
    keys = np.flatnonzero(cnt > 0)
    centres = sums[keys] / np.linalg.norm(sums[keys], axis=1, keepdims=True)
    area = 4.0 * math.pi * cnt[keys] / n_s
    radius = np.arccos(np.clip(1.0 - area / (2.0 * math.pi), -1.0, 1.0))  # spherical cap of the same area
    cone_area = 2.0 * math.pi * (1.0 - math.cos(alpha))
    cap = np.minimum(1.0, cone_area / area)  # a cone smaller than the cell holds at most this fraction
    reach = float(np.cos(min(math.pi, alpha + float(radius.max()))))
    c32 = centres.astype(np.float32)
    C = keys.size
    cos = c32 @ c32.T  # (C, C)
    flat = np.flatnonzero(cos >= np.float32(reach))  # row-major: grouped by row
    r, j = np.divmod(flat, C)
    d = np.arccos(np.clip(cos.ravel().take(flat).astype(float), -1.0, 1.0))
    f = np.minimum(_disc_fraction((alpha - d) / radius[j]), cap[j])
    f[r == j] = np.maximum(f[r == j], 1e-6)  # every row holds its own cell (no empty CSR rows)
    keep = f > 0
    r, j, f = r[keep], j[keep], f[keep]
    indptr = np.concatenate([[0], np.cumsum(np.bincount(r, minlength=C))])
    lo = np.cos(np.minimum(math.pi, alpha + radius))
    hi = np.cos(np.maximum(0.0, alpha - radius))
    return ConeKernel(
        alpha=alpha,
        m=m,
        keys=keys,
        centres=c32,
        radius=radius,
        indptr=indptr.astype(np.intp),
        indices=keys[j].astype(np.intp),
        overlap=f.astype(np.float32),
        soft_lo=lo.astype(np.float32),
        soft_span=(1.0 / np.maximum(hi - lo, 1e-12)).astype(np.float32),
        soft_cap=cap.astype(np.float32) if bool((cap < 1.0).any()) else None,
        centres_t=np.ascontiguousarray(c32.T),
        centres1=np.ascontiguousarray(np.hstack([c32, np.ones((C, 1), np.float32)])),
    )
