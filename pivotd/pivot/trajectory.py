"""Trajectory PIVOT (paper §IV-B): one viewing direction per waypoint, visibility plus smoothness.

Maximises Σ_i F_i(R_i)/W_i + λ Σ_i c_{i+1}·c_i (+ λ a·c_0 with an anchor direction a), where
F_i = Σ_j s_ij v(θ_ij) (eq. 6) over waypoint i's retained landmarks, s_ij = feature weight × distance
weight (eq. 15) and W_i = Σ_j s_ij normalises each waypoint by its local feature weight (the paper's
ε = 1/(nπ)). All waypoints are updated together with padded arrays: R_i ← exp((h_i Ĵ_i)^) R_i with
J_i = J_vis,i/W_i + λ c_i × (c_{i−1} + c_{i+1}) (eqs. 12, 18–20; one neighbour at the ends).
With ``TrajectoryOptions.smooth_knee_deg`` > 0 each pair enters as v(c_{i+1}·c_i) instead
(:mod:`pivotd.pivot.smoothness`: a step beyond the knee costs in proportion to its size, not its square), and
its gradient term is weighted by v' at the current step. With ``TrajectoryOptions.normalise`` = attainable, W_i
is instead the most weight one cone of the FoV holds at that waypoint (:mod:`pivotd.pivot.normalise`), so each
visible term is a share of what the waypoint could see.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import numpy as np

from pivotd.geometry import optical_frame_from_direction
from pivotd.pivot import _ascent, chain, polish
from pivotd.pivot._checks import feature_weights, finite_array, half_angle, unit_vector
from pivotd.pivot.cone_kernel import cone_kernel
from pivotd.pivot.constraints import PanTiltConstraint
from pivotd.pivot.morton import morton_keys
from pivotd.pivot.normalise import Normalisation, attainable_weights
from pivotd.pivot.smoothness import pair_value, path_value
from pivotd.pivot.steps import limit_steps, step_angles
from pivotd.pivot.view import ViewOptions, optimize_view, schedule


@dataclass
class TrajectoryOptions:
    """Tuning of :func:`optimize_trajectory` (angles in degrees)."""

    fov_start_deg: float = 90.0  # cold start: FoV schedule from this half-angle down to α
    warm_fov_start_deg: float | None = None  # warm start (init_directions given): None = no widening
    stages: int = 4  # schedule stages including the final one at α
    width_deg: float = 3.0  # sigmoid transition width at α (k_s from ks_from_width)
    wide_width_ratio: float = 0.25  # widened stages use width max(width, ratio · α_q)
    stage_iters: int = 6
    max_iterations: int = 60  # iteration budget at α (cold start)
    warm_iterations: int = 20  # iteration budget at α (warm start)
    step_init_deg: float = 8.0
    warm_step_init_deg: float = 1.0
    step_max_deg: float = 20.0
    tol_deg: float = 0.1
    distance_weights: bool = True  # eq. 15 distance weights s_ij
    active_cap: int = 128  # widened stages: landmarks per waypoint (strided subsample)
    final_cap: int = 256  # final stage: landmarks per waypoint near the cone boundary
    drift_deg: float = 12.0  # cold start: rebuild a waypoint's active set after its axis moved this far
    warm_drift_deg: float = 5.0  # warm start: the same (tighter: warm bands are crowded, thinning hurts)
    settle_frac: float = 0.03  # stop once at most 3 % of the waypoints still move by ≥ tol per step
    rest_settled: bool = False  # cold start at α: a waypoint whose step bound fell below tol rests until a
    # neighbour moves (only the others are evaluated): 7–10 % faster on FIF, but off by default because where the
    # ascent runs out of budget (the blob path) the waypoints still creeping below tol matter
    lam_boost: float = 1.0  # widened stages use λ × boost (geometric decay to λ at α): a smoothness homotopy
    smooth_scale: float = 25.0  # κ: the smoothness term is λκ Σ c_{i+1}·c_i against per-waypoint visible fractions
    smooth_knee_deg: float = 0.0  # > 0: a step beyond about this angle costs in proportion to its size, not its
    # square (pseudo-Huber of the chord, pivotd.pivot.smoothness); 0: the paper's 1 − cos per step
    chain_init: bool = True  # cold start: dynamic programming over a direction grid (pivotd.pivot.chain)
    chain_resolution_deg: float = 12.0
    chain_nodes: int = 64
    polish_deg: float = 0.0  # hard-count polish (pivotd.pivot.polish): largest ring radius (0: off)
    polish_tol_deg: float = 0.25  # ... smallest ring radius
    polish_sweeps: int = 4  # ... at most this many red-black sweeps
    polish_cap: int = 2048  # ... landmarks per waypoint in its band (strided beyond)
    warm_polish: bool = False  # also polish warm starts (receding-horizon replans)
    step_polish_deg: float = 4.0  # step-limited DP polish of the visible count (pivotd.pivot.polish): radius (0: off)
    seed_cap: int = 512  # landmarks per node waypoint scoring the step-limited grid chain (a second candidate; 0: off)
    normalise: Normalisation = Normalisation.TOTAL  # W_i: total retained weight, or the attainable one (normalise.py)
    fixed_nodes: int = 16  # cold start of a plan staying within α of one direction: the best single direction for
    # this many node waypoints (0: off) is a candidate, solved when it already sees more or scores higher than the
    # plan; the higher objective is kept
    fixed_cap: int = 8192  # ... scored on at most this many strided landmarks per node waypoint
    narrow_seed_nodes: int = 16  # cold start, α below ViewOptions.narrow_deg: a candidate through this many node
    # waypoints' single-view optima (optimize_view), kept when its objective is higher (0: off)


@dataclass
class TrajectoryResult:
    """directions (N, 3) unit; rotations (N, 3, 3) with rotations[i] @ e3 == directions[i];
    visible (N,) int hard counts (angle ≤ α); iterations: gradient steps; objective: the normalised
    trajectory objective (module docstring) at α."""

    directions: np.ndarray
    rotations: np.ndarray
    visible: np.ndarray
    iterations: int
    objective: float


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


def _dense_geometry(points: np.ndarray, waypoints: np.ndarray, fw: np.ndarray, dist_w: bool):
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
    W = _weights(d, valid, fw.astype(np.float32)[None, :], dist_w)

    def exact(r: np.ndarray, c: np.ndarray, C: np.ndarray) -> np.ndarray:
        v = points[c] - waypoints[r]
        return np.einsum("ij,ij->i", v, C[r]) / np.maximum(np.linalg.norm(v, axis=1), 1e-300)

    return _ascent.Geometry(P, T, inv, W, exact, valid_all), W.sum(axis=1, dtype=np.float64)


def _ragged_geometry(pairs: _Pairs, waypoints: np.ndarray, dist_w: bool):
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
    W = _weights(d, valid, pairs.weights.astype(np.float32), dist_w)

    def exact(r: np.ndarray, c: np.ndarray, C: np.ndarray) -> np.ndarray:
        v = P[r, c].astype(float) - waypoints[r]
        return np.einsum("ij,ij->i", v, C[r]) / np.maximum(np.linalg.norm(v, axis=1), 1e-300)

    geom = _ascent.Geometry(U, np.zeros((N, 3), np.float32), None, W, exact, valid=valid)
    return geom, W.sum(axis=1, dtype=np.float64)


def _weights(d: np.ndarray, valid: np.ndarray | None, fw: np.ndarray, dist_w: bool) -> np.ndarray:
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
class _Pairs:
    """The retained (waypoint, landmark) pairs, padded per waypoint: points (N, L, 3) in the map's dtype
    (padding repeats a retained landmark), weights (N, L) float32 or float64 (0 for padding), lengths (N,)."""

    points: np.ndarray
    weights: np.ndarray
    lengths: np.ndarray

    def waypoint(self, i: int) -> tuple[np.ndarray, np.ndarray]:
        """Landmarks (n, 3) and weights (n,) of waypoint i."""
        n = int(self.lengths[i])
        return self.points[i, :n], self.weights[i, :n]


def _gather_pairs(
    points: np.ndarray, weights: np.ndarray | None, retained: Sequence[np.ndarray], N: int,
    pair_weights: Sequence[np.ndarray] | None = None,
) -> _Pairs:
    """The retained pairs only, gathered once from the map in retained order (:class:`_Pairs`).

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
        return _Pairs(np.zeros((N, L, 3)), np.zeros((N, L)), lens)
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
    if pair_weights is not None:  # per-waypoint factors aligned with retained (e.g. pivotd.pivot.weights)
        if len(pair_weights) != N:
            raise ValueError(f"pair_weights must have one array per waypoint ({N}), got {len(pair_weights)}")
        fw = fw.astype(np.float64)
        for i, pw in enumerate(pair_weights):
            pw = np.asarray(pw, dtype=float).ravel()
            if pw.shape != (lens[i],) or not (np.isfinite(pw).all() and (pw >= 0).all()):
                raise ValueError(f"pair_weights[{i}] must hold {lens[i]} finite weights ≥ 0")
            fw[i, : lens[i]] *= pw
    fw[np.arange(L)[None, :] >= lens[:, None]] = 0.0
    return _Pairs(P.reshape(N, L, 3), fw, lens)


def _independent_views(
    landmarks: Callable[[int], tuple[np.ndarray, np.ndarray]],
    T: np.ndarray,
    alpha: float,
    init: np.ndarray | None,
    dist_w: bool,
) -> TrajectoryResult:
    """λ = 0 without joint limits: every waypoint is its own single-pose problem, solved by
    :func:`pivotd.pivot.view.optimize_view` (init[i] joins its multi-start set); objective Σ F_i/W_i.
    ``landmarks(i)`` returns waypoint i's landmarks (n, 3) [m] and weights (n,)."""
    N = T.shape[0]
    dirs, rots, visible = np.empty((N, 3)), np.empty((N, 3, 3)), np.zeros(N, dtype=int)
    obj, iters = 0.0, 0
    kernel = None  # the cone kernel of α, built once when a waypoint first needs it
    for i in range(N):
        Pi, wi = landmarks(i)
        d = Pi - T[i]
        n = np.sqrt(np.square(d) @ np.ones(3))
        scale = max(float(n.max(initial=0.0)), float(np.abs(T).max()), 1.0)
        ok = n > 1e-9 * scale  # a landmark at the sensor has no bearing
        B, w, n = d[ok] / n[ok, None], wi[ok], n[ok]
        if dist_w and n.size:
            w = np.maximum(_weights(n[None].astype(np.float32), None, w[None], True)[0].astype(float), 0.0)
        uniform = w.size == 0 or bool(np.all(w == w[0]))
        if kernel is None:
            kernel = _view_kernel(alpha, B.shape[0])
        r = optimize_view(B, None if uniform else w, alpha, init=None if init is None else init[i], kernel=kernel)
        dirs[i], rots[i], visible[i] = r.direction, r.rotation, r.visible
        # F_i / W_i: with uniform weights optimize_view counted each landmark as 1
        obj += r.objective / max(float(w.size) if uniform else float(w.sum()), 1e-12)
        iters = max(iters, r.iterations)
    return TrajectoryResult(dirs, rots, visible, iters, obj)


def _view_kernel(alpha: float, n: int):
    """The cone kernel :func:`optimize_view` uses for ``n`` bearings at half-angle α [rad] (its histogram stage:
    more than ``ViewOptions.sample`` bearings, a cone not narrow), or None when it takes another path."""
    return cone_kernel(alpha) if n > ViewOptions.sample and alpha >= math.radians(ViewOptions.narrow_deg) else None


def _judge(
    geom: _ascent.Geometry | None, C: np.ndarray, norm: np.ndarray, alpha: float, width: float, smooth: float,
    anchor: np.ndarray | None, knee: float = 0.0,
) -> tuple[np.ndarray, float]:
    """Hard visible counts (N,) int and the trajectory objective (module docstring) of the axes C (N, 3)."""
    N = C.shape[0]
    if geom is None:
        return np.zeros(N, dtype=int), 0.0
    visible, F = _ascent.evaluate(geom, C, alpha, width)
    obj = float(np.sum(F / np.maximum(norm, 1e-12)))
    if smooth > 0:
        obj += smooth * path_value(C, knee)
        if anchor is not None:
            obj += smooth * float(pair_value(float(anchor @ C[0]), knee))
    return visible.astype(int), obj


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


def _band(geom: _ascent.Geometry, C: np.ndarray, alpha: float, reach: float, cap: int):
    """Bearings (N, L, 3) and weights (N, L) of the landmarks within α ± reach of each axis C (N, 3):
    the only ones whose state a search moving the axes by at most ``reach`` [rad] can change."""
    cos_lo = float(np.cos(min(np.pi, alpha + reach)))
    cos_hi = float(np.cos(alpha - reach)) if alpha > reach else 2.0
    return _ascent._active(geom, C, cos_lo, cos_hi, cap)


def _reachable_fn(constraint: PanTiltConstraint | None) -> polish.Reachable | None:
    """``reachable(rows, directions (n, K, 3)) -> (n, K) bool`` for the polish, or None without limits."""
    if constraint is None:
        return None

    def reachable(rows: np.ndarray, d: np.ndarray) -> np.ndarray:
        n, K, _ = d.shape
        sub = PanTiltConstraint(
            np.repeat(constraint.base_from_world[rows], K, axis=0),
            constraint.pan_min, constraint.pan_max, constraint.tilt_min, constraint.tilt_max,
        )
        return sub.reachable(d.reshape(-1, 3)).reshape(n, K)

    return reachable


def _polish(
    geom: _ascent.Geometry,
    C: np.ndarray,
    norm: np.ndarray,
    alpha: float,
    smooth: float,
    anchor: np.ndarray | None,
    constraint: PanTiltConstraint | None,
    opts: TrajectoryOptions,
) -> np.ndarray:
    """Hard-count polish of Φ_hard (pivotd.pivot.polish.polish_trajectory) of the axes C (N, 3)."""
    radius, tol = np.radians(opts.polish_deg), np.radians(opts.polish_tol_deg)
    B, Wa = _band(geom, C, alpha, (opts.polish_sweeps + 1) * radius, opts.polish_cap)
    C_new, _ = polish.polish_trajectory(
        B, Wa, C, norm, alpha, smooth, radius, tol, sweeps=opts.polish_sweeps, anchor=anchor,
        reachable=_reachable_fn(constraint), knee=float(np.radians(opts.smooth_knee_deg)),
    )
    return C_new


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


def _hard_total(geom: _ascent.Geometry, C: np.ndarray, alpha: float) -> float:
    """Σ_i of the hard visible weight of waypoint i's landmarks for axes C (N, 3) (float32 cosines)."""
    inside = geom.cos_all(C) >= np.float32(np.cos(alpha))
    if geom.inv_dist is not None and not geom.valid_all:
        inside &= geom.inv_dist > 0
    return float(np.sum(inside * geom.weight_rows(), dtype=np.float64))


def _step_polish(
    geom: _ascent.Geometry,
    C: np.ndarray,
    alpha: float,
    max_step: float,
    anchor: np.ndarray | None,
    constraint: PanTiltConstraint | None,
    opts: TrajectoryOptions,
    smooth: float = 0.0,
    norm: np.ndarray | None = None,
) -> np.ndarray:
    """Step-limited polish of the visible weight (pivotd.pivot.polish.step_limited_polish) of the axes C (N, 3)."""
    radius, tol = np.radians(opts.step_polish_deg), np.radians(opts.polish_tol_deg)
    return polish.step_limited_polish(
        lambda C_, reach: _band(geom, C_, alpha, reach, opts.polish_cap),
        C, alpha, max_step, radius, tol, anchor=anchor, reachable=_reachable_fn(constraint),
        smooth=smooth, norm=norm, knee=float(np.radians(opts.smooth_knee_deg)),
    )


def optimize_trajectory(
    points: np.ndarray,
    waypoints: np.ndarray,
    alpha: float,
    lam: float,
    *,
    weights: np.ndarray | None = None,
    retained: Sequence[np.ndarray] | None = None,
    init_directions: np.ndarray | None = None,
    anchor: np.ndarray | None = None,
    constraint: PanTiltConstraint | None = None,
    max_step: float | None = None,
    options: TrajectoryOptions | None = None,
    pair_weights: Sequence[np.ndarray] | None = None,
) -> TrajectoryResult:
    """Optimise viewing directions for landmarks ``points`` (M, 3) [m] along ``waypoints`` (N, 3) [m].

    α: FoV half-angle [rad]; λ ≥ 0: smoothness weight; ``weights`` (M,) feature weights (None: 1);
    ``retained``: per-waypoint index arrays into ``points`` (None: every landmark everywhere) — only
    those landmarks are read, so the cost does not depend on the map's size; ``init_directions``
    (N, 3): warm start (no multi-start, no FoV widening unless configured) — None starts from the
    chain initialisation; ``anchor`` (3,): a fixed direction just before waypoint 0 (adds λ anchor·c_0);
    ``pair_weights``: with ``retained``, one array (n_i,) ≥ 0 per waypoint multiplying the feature weights of
    its retained landmarks (pivotd.pivot.weights); ``constraint``: pan/tilt limits enforced at every step;
    ``max_step`` [rad]: a hard limit on the angle between consecutive directions (and from the anchor),
    guaranteed (pivotd.pivot.steps).
    λ = 0 (or a single waypoint without ``anchor``) without ``constraint`` and ``max_step`` solves each
    waypoint with :func:`pivotd.pivot.view.optimize_view`. Landmarks coinciding with a waypoint are ignored there.
    Raises ValueError on NaN/inf or bad shapes.
    """
    opts = options or TrajectoryOptions()
    normalise = Normalisation.parse(opts.normalise)
    alpha = half_angle(alpha)
    lam = float(lam)
    if not (np.isfinite(lam) and lam >= 0):
        raise ValueError(f"lambda must be a finite number ≥ 0, got {lam}")
    if max_step is not None:
        max_step = float(max_step)
        if not (np.isfinite(max_step) and 0.0 < max_step <= np.pi):
            raise ValueError(f"max_step must be an angle in (0, pi] rad, got {max_step}")
    T = finite_array("waypoints", waypoints)
    N = T.shape[0]
    if N == 0:
        raise ValueError("waypoints is empty")
    if retained is None:
        if pair_weights is not None:
            raise ValueError("pair_weights needs retained (one weight per retained landmark)")
        P = finite_array("points", points)
        fw = feature_weights(weights, P.shape[0])
        if P.shape[0] > 1:  # every landmark is used: lay them out along a space-filling curve (spatial_order)
            order = spatial_order(P, [np.arange(P.shape[0])])[0]
            P, fw = P[order], fw[order]
        pairs = None
    else:
        pairs = _gather_pairs(points, weights, retained, N, pair_weights)
    if constraint is not None and len(constraint) != N:
        raise ValueError(f"constraint has {len(constraint)} waypoints, the path has {N}")
    a_vec = None if anchor is None else unit_vector("anchor", anchor)
    warm = init_directions is not None
    if warm:
        C0 = finite_array("init_directions", init_directions)
        if C0.shape[0] != N:
            raise ValueError(f"init_directions must have shape ({N}, 3), got {C0.shape}")
        n0 = np.linalg.norm(C0, axis=1)
        if np.any(n0 < 1e-12):
            raise ValueError(f"init_directions row {int(np.argmin(n0))} is zero")
        C0 = C0 / n0[:, None]
    else:
        C0 = path_directions(T)
    # λ = 0, or a single waypoint without an anchor (no pair for the smoothness term): independent poses
    if (lam == 0.0 or (N == 1 and a_vec is None)) and constraint is None and max_step is None:
        views = (lambda i: (P, fw)) if pairs is None else pairs.waypoint
        return _independent_views(views, T, alpha, C0 if warm else None, opts.distance_weights)
    R0 = optical_frame_from_direction(C0)

    lengths = np.full(N, P.shape[0]) if pairs is None else pairs.lengths
    if not lengths.any():
        geom, norm = None, np.zeros(N)
    elif pairs is None:
        geom, norm = _dense_geometry(P, T, fw, opts.distance_weights)
    else:
        geom, norm = _ragged_geometry(pairs, T, opts.distance_weights)
    chain_smooth_ratio = 1.0
    if normalise is Normalisation.ATTAINABLE and geom is not None:
        total, norm = norm, attainable_weights(geom, alpha)
        has = total > 0  # the chain scores fractions of the total: scale its smoothness by the typical A_i / W_i
        chain_smooth_ratio = float(np.median(norm[has] / total[has])) if has.any() else 1.0

    rad = np.radians
    if warm:
        start = alpha if opts.warm_fov_start_deg is None else rad(opts.warm_fov_start_deg)
        stages, budget, h0 = schedule(alpha, start, opts.stages), opts.warm_iterations, rad(opts.warm_step_init_deg)
    else:
        stages, budget, h0 = schedule(alpha, rad(opts.fov_start_deg), opts.stages), opts.max_iterations, rad(
            opts.step_init_deg
        )
    settings = _ascent.AscentSettings(
        stages=stages,
        width=rad(opts.width_deg),
        wide_width_ratio=opts.wide_width_ratio,
        stage_iters=opts.stage_iters,
        final_iters=budget,
        step_init=h0,
        step_max=rad(opts.step_max_deg),
        tol=rad(opts.tol_deg),
        active_cap=opts.active_cap,
        final_cap=opts.final_cap,
        drift=rad(opts.warm_drift_deg if warm else opts.drift_deg),
        lam_boost=opts.lam_boost,
        settle_frac=opts.settle_frac,
        freeze_settled=opts.rest_settled and not warm,
    )
    project = None if constraint is None else constraint.project
    if geom is None:
        empty = _ascent.Geometry(
            np.zeros((0, 3), np.float32), np.zeros((N, 3), np.float32), None, np.zeros(0, np.float32),
            lambda r, c, C: np.zeros(0),
        )
        geom_run = empty
    else:
        geom_run = geom
    coarse = None
    seed = None  # node waypoints of the chain initialisation, for the step-limited seed
    smooth = lam * opts.smooth_scale
    knee = rad(opts.smooth_knee_deg)
    if geom is not None and (len(stages) > 1 or (opts.chain_init and not warm)):
        if opts.chain_init and not warm:  # the chain scores its node waypoints only
            linked = smooth > 0 or max_step is not None
            nodes = chain.node_indices(N, opts.chain_nodes) if linked else np.arange(N)
            sub = _ascent.subsample(geom.take_rows(nodes), lengths[nodes], opts.active_cap)
            seed = nodes if linked else None
            node_scores = sub if smooth > 0 or not linked else _ascent.subsample(geom, lengths, opts.active_cap)
            C_init = chain.initial_directions(
                node_scores.points, node_scores.weights, alpha, smooth * chain_smooth_ratio,
                nodes if smooth > 0 else np.arange(N), N,
                resolution_deg=opts.chain_resolution_deg, anchor=a_vec, knee=knee,
            )
            R0 = optical_frame_from_direction(C_init)
            settings.stages = [alpha]
            settings.step_init = rad(opts.chain_resolution_deg) / 2
        else:
            coarse = _ascent.subsample(geom, lengths, opts.active_cap)
    R, iters = _ascent.ascend(geom_run, R0, norm, settings, lam=smooth, anchor=a_vec, project=project, coarse=coarse,
                              knee=knee)
    C = R[:, :, 2].copy()
    cold_or_allowed = opts.warm_polish or not warm
    if geom is not None and opts.polish_deg > 0 and cold_or_allowed:
        C = _polish(geom, C, norm, alpha, smooth, a_vec, constraint, opts)
    if max_step is not None:  # the hard limit: project, then polish the count within it
        C = limit_steps(C, max_step, anchor=a_vec, constraint=constraint)
        limit = max_step
    else:  # Pareto polish: more visible landmarks at the plan's own largest step
        limit = float(step_angles(C, a_vec).max(initial=0.0)) if (N > 1 or a_vec is not None) else None
    if geom is not None and opts.step_polish_deg > 0 and cold_or_allowed and limit is not None and limit > 0:
        # at the plan's own largest step the polish keeps the λ trade-off (Φ_hard within the step); under a
        # hard limit the limit is the smoothness asked for, and the polish maximises the visible weight
        keep_smooth = smooth if max_step is None else 0.0
        C = _step_polish(geom, C, alpha, limit, a_vec, constraint, opts, keep_smooth, norm)
        if seed is not None and opts.seed_cap > 0 and max_step is not None:
            # under a hard limit, the best plan within it on a grid, polished, is a second candidate, kept when
            # it sees more (both stay within the limit): the λ plan may take another route than the limit allows
            nodes = seed
            sub = _ascent.subsample(geom.take_rows(nodes), lengths[nodes], opts.seed_cap)
            C_alt = chain.step_limited_directions(
                sub.points, sub.weights, alpha, nodes, N, limit, resolution_deg=opts.chain_resolution_deg,
                anchor=a_vec, exact=lambda k, D: _visible_fraction(geom, int(nodes[k]), D, alpha),
                full_sizes=lengths[nodes],
            )
            if constraint is not None:
                C_alt = constraint.project(C_alt)
            C_alt = _step_polish(geom, limit_steps(C_alt, limit, anchor=a_vec, constraint=constraint), alpha, limit,
                                 a_vec, constraint, opts, keep_smooth, norm)
            if _hard_total(geom, C_alt, alpha) > _hard_total(geom, C, alpha):
                C = C_alt
        if max_step is not None:
            C = limit_steps(C, max_step, anchor=a_vec, constraint=constraint)  # a no-op: the guarantee
    R = _ascent._turn_to(R, C)
    C = R[:, :, 2].copy()
    visible, obj = _judge(geom, C, norm, alpha, rad(opts.width_deg), smooth, a_vec, knee)
    result = TrajectoryResult(C, R, visible, iters, obj)

    def solve_from(init: np.ndarray) -> TrajectoryResult:
        """A second cold-start candidate: the same problem warm-started from ``init`` with the cold budget and
        the polishes."""
        return optimize_trajectory(
            points, waypoints, alpha, lam, weights=weights, retained=retained, init_directions=init,
            anchor=anchor, constraint=constraint, max_step=max_step, pair_weights=pair_weights,
            options=replace(opts, warm_polish=True, warm_iterations=opts.max_iterations),
        )

    def adopted(alt: TrajectoryResult) -> TrajectoryResult:
        return TrajectoryResult(alt.directions, alt.rotations, alt.visible, iters + alt.iterations, alt.objective)
    if not warm and geom is not None and smooth > 0 and opts.fixed_nodes > 0 and _spread(C) <= alpha:
        # A plan that stays within one cone's half-angle of a single direction is, in effect, a fixed view; on
        # flat landscapes (a sensor inside a cloud or a ring, where every view sees about as much) the cold solve
        # can settle in a worse basin than the best fixed direction. That direction over node waypoints is a
        # candidate, solved only when it already sees more or scores higher than the plan.
        nodes = chain.node_indices(N, opts.fixed_nodes)
        C_fix = np.tile(_fixed_direction(geom.take_rows(nodes), lengths[nodes], norm[nodes], alpha, opts.fixed_cap),
                        (N, 1))
        if constraint is not None:
            C_fix = constraint.project(C_fix)
        vis_fix, obj_fix = _judge(geom, C_fix, norm, alpha, rad(opts.width_deg), smooth, a_vec, knee)
        if obj_fix > result.objective or vis_fix.sum() > result.visible.sum():
            alt = solve_from(C_fix)
            # under a hard step limit the plan maximises what it sees (as the step-limited seed above is judged)
            better = (alt.objective > result.objective if max_step is None
                      else int(alt.visible.sum()) > int(result.visible.sum()))
            if better:
                result = adopted(alt)
    if (not warm and geom is not None and smooth > 0 and opts.narrow_seed_nodes > 0
            and alpha < math.radians(ViewOptions.narrow_deg)):
        # a narrow cone sees a few degrees: the chain's grid and the widened stages of a cold start cannot find
        # its basins, while the single-view search can. Seed a second solve through those optima and keep the
        # plan with the higher objective (both are judged by the same function).
        nodes = chain.node_indices(N, opts.narrow_seed_nodes)
        views = (lambda i: (P, fw)) if pairs is None else pairs.waypoint
        peaks = _independent_views(lambda k: views(int(nodes[k])), T[nodes], alpha, None,
                                   opts.distance_weights).directions
        alt = solve_from(chain.slerp_fill(N, nodes, peaks))
        if alt.objective > result.objective:
            result = adopted(alt)
    return result
