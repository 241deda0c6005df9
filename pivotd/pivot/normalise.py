"""Per-waypoint normalisation of the trajectory objective's visible term.

The trajectory objective (:mod:`pivotd.pivot.trajectory`) sums F_i / W_i over the waypoints and adds the
smoothness term λκ Σ c_{i+1}·c_i. With W_i the waypoint's *total* retained weight, a term can reach 1 only
when one cone holds every retained landmark; a cone of half-angle α usually holds a small share of them, and
that share shrinks with α, so the same λ means a different trade-off for every FoV and map. With W_i the
*attainable* weight — the most weight a single cone of half-angle α holds at that waypoint — each term
measures the view against what the waypoint could see (≤ 1 up to the soft cone's edge), whatever the FoV.

:func:`attainable_weights` estimates that best single-cone weight: candidate axes from the heaviest cells of a
cube-map binning of the bearings (cells about α wide), each moved twice to the weighted mean bearing inside
its cone (mean shift), scored by the hard visible weight at every step; the best score wins. It is a lower
bound of the true optimum (every score is a real cone's weight) and close to it wherever the landmarks of
the best cone gather around a dense cell. Pure numpy; cost O(R log R) for R retained pairs (only the
retained landmarks are read); the result depends on each waypoint's set of landmarks, not their order (up to
floating-point rounding of sums).
"""

from __future__ import annotations

import math

import numpy as np

from pivotd.compat import StrEnum
from pivotd.pivot._ascent import Geometry
from pivotd.pivot.cone_kernel import cell_keys

__all__ = ["Normalisation", "attainable_counts", "attainable_weights", "cells_for"]


class Normalisation(StrEnum):
    """What a waypoint's visible weight is divided by in the trajectory objective."""

    TOTAL = "total"  # all its retained weight (the paper's normalisation)
    ATTAINABLE = "attainable"  # the most weight one cone of the FoV holds there (:func:`attainable_weights`)

    @classmethod
    def parse(cls, value: object) -> Normalisation:
        """The member named ``value``; ValueError naming the choices otherwise."""
        try:
            return cls(value)
        except ValueError:
            choices = " | ".join(m.value for m in cls)
            raise ValueError(f"normalise must be one of {choices}, got {value!r}") from None


def cells_for(alpha: float) -> int:
    """Cube-map cells per face whose cells are about α [rad] wide at a face centre (1 … 128)."""
    return int(min(128, max(1, round((0.5 * math.pi) / alpha))))


def _bearings(geom: Geometry) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearings (N, L, 3) float32 and weights (N, L) float32 of every row (0 for padding and landmarks at
    the sensor)."""
    W = np.array(geom.weight_rows(), dtype=np.float32)
    if geom.inv_dist is None:
        B = np.broadcast_to(geom.points, (geom.rows, *geom.points.shape)) if geom.shared else geom.points
        return B, W
    inv = geom.inv_dist
    W[inv <= 0] = 0.0
    B = (geom.points[None, :, :] if geom.shared else geom.points) - geom.origins[:, None, :]
    B *= inv[:, :, None]
    return B, W


def _candidates(B: np.ndarray, W: np.ndarray, m: int, k: int) -> tuple[np.ndarray, np.ndarray]:
    """Weighted mean bearings (N, k, 3) of each row's k heaviest cube-map cells (m cells per face) and whether
    each exists (N, k) bool. Ties in weight go to the lower cell key, so the choice does not depend on the
    landmarks' order."""
    N, L, _ = B.shape
    w = W.reshape(-1)
    live = np.flatnonzero(w > 0)  # padding and landmarks at the sensor have no bearing
    flat = B.reshape(-1, 3)[live]
    w = w[live].astype(np.float64)
    keys = cell_keys(np.ascontiguousarray(flat.T), m).astype(np.int64) + (live // L) * (m**3)
    dense = N * m**3 <= 4 * max(live.size, 1024)
    if dense:  # few cells (wide cones): histogram over every cell
        inverse, size = keys, N * m**3
    else:  # many cells (narrow cones): only the occupied ones
        cells, inverse = np.unique(keys, return_inverse=True)
        size = cells.size
    mass = np.bincount(inverse, weights=w, minlength=size)
    sums = np.stack([np.bincount(inverse, weights=w * flat[:, j], minlength=size) for j in range(3)], axis=1)
    if dense:
        cells = np.flatnonzero(mass > 0)
        mass, sums = mass[cells], sums[cells]
    row = cells // (m**3)
    order = np.lexsort((cells, -mass, row))  # by row, heaviest first, ties by key
    row_sorted = row[order]
    first = np.searchsorted(row_sorted, np.arange(N))
    rank = np.arange(order.size) - first[row_sorted]
    top = rank < k
    C = np.zeros((N, k, 3))
    C[:, :, 2] = 1.0
    have = np.zeros((N, k), dtype=bool)
    r, q, o = row_sorted[top], rank[top], order[top]
    norms = np.linalg.norm(sums[o], axis=1)
    ok = norms > 1e-12  # opposite bearings cancelling in one cell: no axis from it
    C[r[ok], q[ok]] = sums[o[ok]] / norms[ok, None]
    have[r[ok], q[ok]] = True
    return C, have


def attainable_weights(geom: Geometry, alpha: float, *, candidates: int = 6, shifts: int = 2) -> np.ndarray:
    """Estimated best single-cone weight (N,) float64 of every row of ``geom`` for half-angle α [rad].

    ``candidates`` heaviest cells per row (cells about α wide, :func:`cells_for`) seed the axes; each is moved
    ``shifts`` times to the weighted mean bearing inside its cone. Every axis visited is scored by its hard
    visible weight (cos θ ≥ cos α, the weights of ``geom``) and each row keeps its best score. Rows without
    weight give 0. All rows and candidates are handled together: ``shifts`` + 1 passes over the (N, L,
    candidates) cosines.
    """
    B, W = _bearings(geom)
    N = B.shape[0]
    if N == 0 or B.shape[1] == 0:
        return np.zeros(N)
    C, have = _candidates(B, W, cells_for(alpha), candidates)
    cos_a = np.float32(math.cos(alpha))
    BW = B * W[:, :, None]  # weighted bearings: the mean-shift sums are one product per pass
    best = np.zeros(N)
    for step in range(shifts + 1):
        inside = (np.matmul(B, C.astype(np.float32).transpose(0, 2, 1)) >= cos_a).astype(np.float32)  # (N, L, k)
        weight = np.matmul(W[:, None, :], inside)[:, 0, :].astype(np.float64)  # (N, k)
        best = np.maximum(best, np.where(have, weight, 0.0).max(axis=1))
        if step == shifts:
            break
        sums = np.matmul(inside.transpose(0, 2, 1), BW).astype(np.float64)  # (N, k, 3)
        n = np.linalg.norm(sums, axis=2, keepdims=True)
        C = np.where(n > 1e-12, sums / np.maximum(n, 1e-300), C)
    return best


def attainable_counts(bearings: np.ndarray, weights: np.ndarray, alpha: float) -> np.ndarray:
    """:func:`attainable_weights` (N,) of unit ``bearings`` (N, L, 3) float32 with ``weights`` (N, L) (0: padding)."""
    B = np.ascontiguousarray(bearings, dtype=np.float32)
    geom = Geometry(B, np.zeros((B.shape[0], 3), np.float32), None, np.asarray(weights, np.float32),
                    lambda r, c, C: np.zeros(0))
    return attainable_weights(geom, alpha)
