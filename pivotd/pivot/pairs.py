"""The retained (waypoint, landmark) pairs of a trajectory problem and their geometry.

Only the retained rows of the map are read (cost O(N × longest retained set)); each pair becomes a float32 unit
bearing (or, when every waypoint sees every landmark, one shared float32 cloud with inverse distances) and a weight
s_ij = feature weight × (optionally) the distance weight of eq. 15.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from pivotd.pivot import _ascent
from pivotd.pivot._checks import feature_weights, finite_array
from pivotd.pivot.morton import morton_keys

__all__ = ["Pairs", "dense_geometry", "gather_pairs", "landmark_weights", "path_directions", "ragged_geometry",
           "spatial_order"]

def path_directions(waypoints: np.ndarray) -> np.ndarray:
    """Unit local path directions (N, 3): central differences, one-sided at the ends; +x where the path stalls."""
    N = waypoints.shape[0]
    d = np.zeros((N, 3))
    if N > 1:
        d[1:-1] = waypoints[2:] - waypoints[:-2]
        d[0] = waypoints[1] - waypoints[0]
        d[-1] = waypoints[-1] - waypoints[-2]
    n = np.linalg.norm(d, axis=1)
    good = n > 1e-9
    if not good.any():
        return np.tile([1.0, 0.0, 0.0], (N, 1))
    d[good] /= n[good, None]
    idx = np.where(good, np.arange(N), -1)
    idx = np.maximum.accumulate(idx)  # carry the last good direction forward ...
    first = int(np.argmax(good))
    idx[idx < 0] = first  # ... and the first one backward
    return d[idx]


def dense_geometry(points: np.ndarray, waypoints: np.ndarray, fw: np.ndarray, dist_w: bool):
    """Geometry where every waypoint retains every landmark; returns (geometry, W_i totals).

    Distances come from ‖p‖² + ‖t‖² − 2 t·p in float32 around the waypoints' centroid (one matrix
    product); pairs closer than 1 % of the scene scale are recomputed in float64.
    """
    centre = waypoints.mean(axis=0)
    P = (points - centre).astype(np.float32)
    T = (waypoints - centre).astype(np.float32)
    pp = np.einsum("ij,ij->i", P, P)
    tt = np.einsum("ij,ij->i", T, T)
    d = (T * np.float32(-2.0)) @ P.T
    d += pp[None, :]
    d += tt[:, None]
    scale2 = float(max(np.max(pp, initial=0.0), np.max(tt)))
    close = np.float32(1e-4 * max(scale2, 1e-12))
    d2_min = float(d.min(initial=np.inf))
    if d2_min < close:  # float32 cancellation: recompute close pairs in float64
        rows, cols = _ascent._nonzero2d(d < close)
        d[rows, cols] = np.sum((points[cols] - waypoints[rows]) ** 2, axis=1)
        np.maximum(d, 0.0, out=d)
        d2_min = float(d.min(initial=np.inf))
    np.sqrt(d, out=d)
    eps = np.float32(1e-9 * max(1.0, np.sqrt(scale2)))
    valid_all = bool(np.sqrt(max(d2_min, 0.0)) > eps)
    valid = None if valid_all else d > eps
    if valid_all:
        inv = np.divide(np.float32(1.0), d)
    else:
        inv = np.zeros_like(d)
        np.divide(np.float32(1.0), d, out=inv, where=valid)
    W = landmark_weights(d, valid, fw.astype(np.float32)[None, :], dist_w)

    def exact(r: np.ndarray, c: np.ndarray, C: np.ndarray) -> np.ndarray:
        v = points[c] - waypoints[r]
        return np.einsum("ij,ij->i", v, C[r]) / np.maximum(np.linalg.norm(v, axis=1), 1e-300)

    return _ascent.Geometry(P, T, inv, W, exact, valid_all), W.sum(axis=1, dtype=np.float64)


def ragged_geometry(pairs: Pairs, waypoints: np.ndarray, dist_w: bool):
    """Geometry of the retained pairs (padded per waypoint); returns (geometry, W_i totals).

    Each pair's offset is formed without cancellation however far the scene is from the origin (in float64
    for a float64 map; for a float32 map in float32 against the float32-rounded waypoint, then corrected by
    the rounding residual) and stored as a float32 unit bearing: later passes are plain dot products.
    """
    P, lens = pairs.points, pairs.lengths
    N, L = P.shape[0], P.shape[1]
    pad = np.arange(L)[None, :] < lens[:, None]  # (N, L): real entries
    # one float32 plane per coordinate (3, N, L): element-wise work then runs along L instead of over a
    # trailing axis of length 3 (several times faster)
    D = np.empty((3, N, L), np.float32)
    if P.dtype == np.float32:  # landmark − float32(waypoint) − the waypoint's rounding residual: two correctly
        T32 = waypoints.astype(np.float32)  # rounded float32 operations on exact inputs, no float64 pass
        rest = (waypoints - T32).astype(np.float32)
        for k in range(3):
            np.subtract(P[:, :, k], T32[:, k, None], out=D[k])
            D[k] -= rest[:, k, None]
    else:
        for k in range(3):
            np.subtract(P[:, :, k], waypoints[:, k, None], out=D[k], casting="same_kind")
    d = np.sqrt(D[0] * D[0] + D[1] * D[1] + D[2] * D[2])
    scale = float(max(d.max(initial=0.0), np.abs(waypoints).max(), 1.0))
    valid = pad & (d > np.float32(1e-9 * scale))  # a landmark at the sensor has no bearing: weight 0, never counts
    inv = np.zeros_like(d)
    np.divide(np.float32(1.0), d, out=inv, where=valid)
    U = np.empty((N, L, 3), np.float32)
    for k in range(3):
        np.multiply(D[k], inv, out=U[:, :, k])
    W = landmark_weights(d, valid, pairs.weights.astype(np.float32), dist_w)

    def exact(r: np.ndarray, c: np.ndarray, C: np.ndarray) -> np.ndarray:
        v = P[r, c].astype(float) - waypoints[r]
        return np.einsum("ij,ij->i", v, C[r]) / np.maximum(np.linalg.norm(v, axis=1), 1e-300)

    geom = _ascent.Geometry(U, np.zeros((N, 3), np.float32), None, W, exact, valid=valid)
    return geom, W.sum(axis=1, dtype=np.float64)


def landmark_weights(d: np.ndarray, valid: np.ndarray | None, fw: np.ndarray, dist_w: bool) -> np.ndarray:
    """s_ij (N, L) float32: feature weight × (optionally) the distance weight of eq. 15; 0 where invalid."""
    fw = fw.astype(np.float32, copy=False)
    if valid is None:  # every pair is valid
        if not dist_w:
            return np.ascontiguousarray(np.broadcast_to(fw, d.shape))
        dmin = d.min(axis=1, keepdims=True)
        dmax = d.max(axis=1, keepdims=True)
        inv_span = (np.float32(1.0) / np.maximum(np.float32(1e-6), dmax - dmin)).astype(np.float32)
        s = d * -inv_span  # s = 1 − (d − dmin)/span, in three passes
        s += (np.float32(1.0) + dmin * inv_span).astype(np.float32)
        s *= fw
        return s
    if not dist_w:
        return np.where(valid, fw, np.float32(0.0))
    dmin = d.min(axis=1, keepdims=True, where=valid, initial=np.float32(np.inf))
    dmax = d.max(axis=1, keepdims=True, where=valid, initial=np.float32(-np.inf))
    empty = ~np.isfinite(dmin)
    dmin[empty], dmax[empty] = 0.0, 1.0
    s = d - dmin
    s *= (np.float32(-1.0) / np.maximum(np.float32(1e-6), dmax - dmin)).astype(np.float32)
    s += np.float32(1.0)
    s *= fw
    s *= valid  # 0 where invalid
    return s.astype(np.float32, copy=False)


def spatial_order(points: np.ndarray, retained: Sequence[np.ndarray]) -> list[np.ndarray]:
    """Each retained index array ordered by the Morton key of its landmarks (``points`` (M, 3) [m]) in the
    box of all retained landmarks; ties (coincident landmarks) by coordinates. Cost O(R log R) for R
    retained pairs: only the retained rows of ``points`` are read.

    ``optimize_trajectory`` subsamples each waypoint's landmarks by strides in the given order, so
    retained sets in this order give answers that do not depend on the map's landmark order.
    """
    lists = [np.asarray(r, dtype=np.intp).ravel() for r in retained]
    if not lists or sum(r.size for r in lists) == 0:
        return lists
    pts = [points.take(r, axis=0) for r in lists]
    nonempty = [p for p in pts if p.size]
    # the box, one coordinate column at a time (reductions along axis 0 of an (n, 3) array are much slower)
    lo = np.array([min(float(p[:, k].min()) for p in nonempty) for k in range(3)])
    hi = np.array([max(float(p[:, k].max()) for p in nonempty) for k in range(3)])
    out = []
    for r, p in zip(lists, pts, strict=True):
        if r.size < 2:
            out.append(r)
            continue
        key = morton_keys(p, lo, hi)
        order = np.argsort(key)
        ks = key[order]
        dup = np.flatnonzero(ks[1:] == ks[:-1])
        if dup.size:  # landmarks within one key cell (~coincident): by coordinates, within their groups
            sel = np.union1d(dup, dup + 1)
            sub = order[sel]
            order[sel] = sub[np.lexsort((p[sub, 2], p[sub, 1], p[sub, 0], ks[sel]))]
        out.append(r[order])
    return out


@dataclass
class Pairs:
    """The retained (waypoint, landmark) pairs, padded per waypoint: points (N, L, 3) in the map's dtype
    (padding repeats a retained landmark), weights (N, L) float32 or float64 (0 for padding), lengths (N,)."""

    points: np.ndarray
    weights: np.ndarray
    lengths: np.ndarray

    def waypoint(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Landmarks (n, 3) and weights (n,) of waypoint i."""
        n = int(self.lengths[i])
        return self.points[i, :n], self.weights[i, :n]


def gather_pairs(
    points: np.ndarray, weights: np.ndarray | None, retained: Sequence[np.ndarray], N: int,
) -> Pairs:
    """The retained pairs only, gathered once from the map in retained order (:class:`Pairs`).

    Everything here costs O(N × longest retained set): the map itself is only indexed, never converted,
    checked or copied as a whole (NaN/inf coordinates and bad weights are reported with their row in the map).
    """
    if len(retained) != N:
        raise ValueError(f"retained must have one index array per waypoint ({N}), got {len(retained)}")
    pts = points if isinstance(points, np.ndarray) else np.asarray(points)
    if pts.ndim != 2 or pts.shape[1] != 3:
        raise ValueError(f"points must have shape (n, 3), got {pts.shape}")
    M = pts.shape[0]
    lists = [np.asarray(r).ravel() for r in retained]
    for i, r in enumerate(lists):
        if r.size and r.dtype.kind not in "iu":
            raise ValueError(f"retained[{i}] must hold integer indices, got {r.dtype}")
    lens = np.array([r.size for r in lists], dtype=np.intp)
    L = max(int(lens.max(initial=0)), 1)
    if not lens.any():  # nothing retained anywhere (possibly an empty map)
        return Pairs(np.zeros((N, L, 3)), np.zeros((N, L)), lens)
    first = next(r[0] for r in lists if r.size)
    idx = np.full((N, L), first, dtype=np.intp)  # padding repeats a retained landmark (masked out later)
    for i, r in enumerate(lists):
        idx[i, : r.size] = r
    if lens.sum() and (idx.min() < 0 or idx.max() >= M):
        bad = int(np.argmax(((idx < 0) | (idx >= M)).any(axis=1)))
        raise ValueError(f"retained[{bad}] indexes outside 0..{M - 1}")
    flat = idx.reshape(-1)
    P = pts.take(flat, axis=0)
    if P.dtype not in (np.float32, np.float64):
        P = P.astype(float)
    if not np.isfinite(P).all():
        finite_array("points", P, rows=flat)  # raises, naming the row in the map
    if weights is None:
        fw = np.ones((N, L))
    else:
        w = weights if isinstance(weights, np.ndarray) else np.asarray(weights)
        if w.shape != (M,):
            raise ValueError(f"weights must have shape ({M},), got {w.shape}")
        fw = w.take(flat)
        if fw.dtype not in (np.float32, np.float64):
            fw = fw.astype(float)
        if not (np.isfinite(fw).all() and (fw >= 0).all()):
            feature_weights(fw, flat.size, rows=flat)  # raises, naming the row in the map
        fw = fw.reshape(N, L)
    fw[np.arange(L)[None, :] >= lens[:, None]] = 0.0
    return Pairs(P.reshape(N, L, 3), fw, lens)


