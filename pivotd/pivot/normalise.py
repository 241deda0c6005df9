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
from enum import StrEnum

import numpy as np

from pivotd.pivot._ascent import Geometry
from pivotd.pivot.cone_kernel import cell_keys


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


def _row_bearings(geom: Geometry, row: int) -> tuple[np.ndarray, np.ndarray]:
    """Unit bearings (n, 3) float32 and weights (n,) float64 of one row's landmarks with weight > 0."""
    w = geom.weights[row] if geom.weights.ndim == 2 else geom.weights
    if geom.inv_dist is None:
        B = geom.points[row] if not geom.shared else geom.points
    else:
        inv = geom.inv_dist[row]
        w = np.where(inv > 0, w, 0)
        B = (geom.points - geom.origins[row]) * inv[:, None]
    keep = np.flatnonzero(w > 0)
    return B[keep].astype(np.float32, copy=False), w[keep].astype(np.float64)


def _row_candidates(B: np.ndarray, w: np.ndarray, m: int, k: int) -> np.ndarray:
    """Weighted mean bearings (≤ k, 3) of the k heaviest cube-map cells (m cells per face) of B (n, 3)."""
    keys = cell_keys(np.ascontiguousarray(B.T), m)
    cells, inverse = np.unique(keys, return_inverse=True)
    mass = np.bincount(inverse, weights=w, minlength=cells.size)
    top = np.lexsort((cells, -mass))[:k]  # heaviest first, ties by cell key: independent of landmark order
    sums = np.stack([np.bincount(inverse, weights=w * B[:, j], minlength=cells.size)[top] for j in range(3)], axis=1)
    norms = np.linalg.norm(sums, axis=1, keepdims=True)
    return np.where(norms > 1e-12, sums / np.maximum(norms, 1e-300), B[0])  # opposite bearings cancelling: any axis


def _weighted_inside(geom: Geometry, C: np.ndarray, cos_a: np.float32) -> tuple[np.ndarray, np.ndarray]:
    """Hard visible weight (N,) float64 of axes C (N, 3) and each row's weighted sum of the bearings inside (N, 3)."""
    cos = geom.cos_all(C)
    W = geom.weight_rows()
    inside = cos >= cos_a
    if geom.inv_dist is not None:
        inside &= geom.inv_dist > 0
    coeff = np.where(inside, W, np.float32(0.0))
    weight = coeff.sum(axis=1, dtype=np.float64)
    if geom.inv_dist is None:
        sums = coeff @ geom.points if geom.shared else np.einsum("nl,nlk->nk", coeff, geom.points)
    else:  # bearing = (p − t) / ‖p − t‖
        coeff = coeff * geom.inv_dist
        sums = coeff @ geom.points if geom.shared else np.einsum("nl,nlk->nk", coeff, geom.points)
        sums = sums - coeff.sum(axis=1)[:, None] * geom.origins
    return weight, sums.astype(np.float64)


def attainable_weights(geom: Geometry, alpha: float, *, candidates: int = 8, shifts: int = 3) -> np.ndarray:
    """Estimated best single-cone weight (N,) float64 of every row of ``geom`` for half-angle α [rad].

    ``candidates`` heaviest cells per row (cells about α wide, :func:`cells_for`) seed the axes; each is moved
    ``shifts`` times to the weighted mean bearing inside its cone. Every axis visited is scored by its hard
    visible weight (cos θ ≥ cos α, the weights of ``geom``) and each row keeps its best score. Rows without
    weight give 0.
    """
    N = geom.rows
    m = cells_for(alpha)
    cos_a = np.float32(math.cos(alpha))
    seeds = np.zeros((candidates, N, 3))
    seeds[:, :, 2] = 1.0
    have = np.zeros((candidates, N), dtype=bool)
    for i in range(N):
        B, w = _row_bearings(geom, i)
        if w.size == 0:
            continue
        c = _row_candidates(B, w, m, candidates)
        seeds[: c.shape[0], i] = c
        have[: c.shape[0], i] = True
    best = np.zeros(N)
    for j in range(candidates):
        rows = have[j]
        if not rows.any():
            break
        C = seeds[j]
        for step in range(shifts + 1):
            weight, sums = _weighted_inside(geom, C, cos_a)
            best = np.where(rows, np.maximum(best, weight), best)
            if step == shifts:
                break
            n = np.linalg.norm(sums, axis=1, keepdims=True)
            C = np.where(n > 1e-12, sums / np.maximum(n, 1e-300), C)
    return best
