"""Batched on-manifold gradient ascent shared by the single-pose and trajectory optimizers.

Rows are independent optical axes (waypoints of a trajectory, or multi-start candidates of one pose),
all updated in lock-step with padded numpy arrays: R_k ← exp((h_k Ĵ_k)^) R_k (paper eqs. 8, 13, 20).
Landmark geometry is held once (float32, centred) and each stage works on the landmarks near the
current cone only ("active set"), rebuilt when an axis drifts away from where the set was built.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from functools import cached_property

import numpy as np

from pivotd.geometry import tangent_basis
from pivotd.pivot.smoothness import pair_slope
from pivotd.pivot.visibility import ks_from_width

__all__ = ["AscentSettings", "Geometry", "Projector", "ascend", "evaluate", "subsample"]

Projector = Callable[[np.ndarray], np.ndarray]

#: one float32 (x, y, z) row as a single 12-byte item, for fast gathers and scatters of whole rows
_ROW3 = np.dtype((np.void, 12))


@dataclass
class Geometry:
    """Landmarks seen from K rows.

    points: (M, 3) shared by every row, or (K, L, 3) per row (padded), float32, minus ``centre``;
    origins: (K, 3) float32 sensor positions minus ``centre``; inv_dist: (K, L) float32 1/‖p − t‖
    (0 for padding / landmarks at the sensor), or None when points are already unit bearings seen
    from the origin; weights: (K, L) or (L,) float32 feature weights (0 for padding);
    exact: callable (rows, cols, C) -> float64 cos θ for the given pairs (to settle hard counts).
    """

    points: np.ndarray
    origins: np.ndarray
    inv_dist: np.ndarray | None
    weights: np.ndarray
    exact: Callable[[np.ndarray, np.ndarray, np.ndarray], np.ndarray]
    valid_all: bool = False  # True when no landmark sits at a sensor (inv_dist > 0 wherever weights exist)
    valid: np.ndarray | None = None  # (K, L) bool for per-row unit bearings (inv_dist None): False for padding

    @property
    def rows(self) -> int:
        return int(self.origins.shape[0])

    @property
    def shared(self) -> bool:
        return self.points.ndim == 2

    def cos_all(self, C: np.ndarray) -> np.ndarray:
        """cos θ (K, L) float32 between every row's axis C (K, 3) and each of its landmarks."""
        C32 = C.astype(np.float32)
        raw = C32 @ self.points.T if self.shared else np.matmul(self.points, C32[:, :, None])[..., 0]
        if self.inv_dist is None:
            return raw
        raw -= np.sum(self.origins * C32, axis=1)[:, None]
        raw *= self.inv_dist
        return raw

    def weight_rows(self) -> np.ndarray:
        """Weights broadcast to (K, L)."""
        return np.broadcast_to(self.weights, (self.rows, self.weights.shape[-1]))

    @cached_property
    def row_totals(self) -> np.ndarray:
        """Σ_j weights of every row (K,) float64 (computed once: the weights never change)."""
        return np.sum(self.weight_rows(), axis=1, dtype=np.float64)

    def take_rows(self, rows: np.ndarray) -> Geometry:
        """The geometry of a subset of rows."""
        return Geometry(
            self.points if self.shared else self.points[rows],
            self.origins[rows],
            None if self.inv_dist is None else self.inv_dist[rows],
            self.weights if self.weights.ndim == 1 else self.weights[rows],
            self.exact,
        )


@dataclass
class AscentSettings:
    """Numbers steering :func:`ascend` (angles in radians)."""

    alpha: float  # the FoV half-angle α
    width: float  # angular transition width of the sigmoid
    iterations: int  # iteration budget
    step_init: float  # first step bound
    step_max: float  # largest step bound
    tol: float  # converged when every step bound is below this
    cap: int  # at most this many landmarks per row in the active set
    drift: float  # rebuild the active set when an axis moved more than this since it was built
    settle_frac: float = 0.0  # converged when at most this fraction of rows still takes steps ≥ tol


def _nonzero2d(mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Row and column indices of a 2-D mask in row-major order (much faster than np.nonzero in 2-D)."""
    flat = np.flatnonzero(mask)
    return np.divmod(flat, mask.shape[1])


def _active(
    geom: Geometry, C: np.ndarray, cos_lo: float, cos_hi: float, cap: int
) -> tuple[np.ndarray, np.ndarray]:
    """Padded active bearings (K, L, 3) and weights (K, L): landmarks with cos_lo ≤ cos θ ≤ cos_hi.

    Rows with more than ``cap`` such landmarks keep an evenly strided subset (a column stride of
    ⌊count / cap⌋, so up to 2 cap − 1 are kept) whose weights are scaled up by count / kept. With
    cos_lo ≤ −1 ≤ 1 ≤ cos_hi and unit bearings (inv_dist None) within the cap, the stored arrays are
    returned as they are.
    """
    everything = cos_lo <= -1.0 and cos_hi >= 1.0
    if everything and geom.inv_dist is None and geom.points.shape[-2] <= cap:
        if geom.shared:
            return geom.points[None], geom.weights[None]
        return geom.points, geom.weight_rows()
    W = geom.weight_rows()
    if everything:
        mask = W > 0
    else:  # zero-weight landmarks may slip in: they add nothing to the gradient
        cos = geom.cos_all(C)
        mask = cos >= cos_lo
        if cos_hi < 1.0:
            mask &= cos <= cos_hi
    K, Lfull = mask.shape
    counts = np.count_nonzero(mask, axis=1)
    scale = None
    if counts.size and counts.max() > cap:  # thin crowded rows with a column stride before extracting
        stride = np.maximum(1, counts // cap)
        crowded = np.flatnonzero(stride > 1)
        for st in np.unique(stride[crowded]):  # rows sharing a stride are thinned together
            rows_st = crowded[stride[crowded] == st]
            keep = np.zeros(Lfull, dtype=bool)
            keep[:: int(st)] = True
            mask[rows_st] &= keep
        kept = np.count_nonzero(mask, axis=1)
        scale = (counts / np.maximum(kept, 1)).astype(np.float32)
        counts = kept
    flat = np.flatnonzero(mask)
    L = max(int(counts.max()) if counts.size else 0, 1)
    B = np.zeros((K * L, 3), dtype=np.float32)
    Wa = np.zeros(K * L, dtype=np.float32)
    if flat.size:
        starts = np.cumsum(counts) - counts
        # entry j of row k goes to k·L + (j − starts[k]); it came from k·Lfull + its column
        dest = np.arange(flat.size) + np.repeat(np.arange(K) * L - starts, counts)
        need_rows = scale is not None or geom.inv_dist is not None or geom.shared or geom.weights.ndim == 1
        rows = np.repeat(np.arange(K), counts) if need_rows else None
        cols = flat - rows * Lfull if rows is not None else None
        if geom.inv_dist is None and not geom.shared and geom.points.flags.c_contiguous:
            # unit bearings per row: move whole 12-byte rows (much faster than indexing (n, 3) arrays)
            B.view(_ROW3).ravel()[dest] = geom.points.reshape(-1, 3).view(_ROW3).ravel().take(flat)
        else:
            p = geom.points.take(cols, axis=0) if geom.shared else geom.points.reshape(-1, 3).take(flat, axis=0)
            if geom.inv_dist is not None:
                p -= geom.origins.take(rows, axis=0)
                p *= geom.inv_dist.reshape(-1).take(flat)[:, None]
            B.view(_ROW3).ravel()[dest] = np.ascontiguousarray(p, dtype=np.float32).view(_ROW3).ravel()
        w = geom.weights.take(cols) if geom.weights.ndim == 1 else geom.weights.reshape(-1).take(flat)
        Wa[dest] = w if scale is None else w * scale[rows]
    return B.reshape(K, L, 3), Wa.reshape(K, L)


def _refresh_rows(
    geom: Geometry,
    C: np.ndarray,
    rows: np.ndarray,
    B: np.ndarray,
    Wa: np.ndarray,
    cos_lo: float,
    cos_hi: float,
    cap: int,
) -> tuple[np.ndarray, np.ndarray]:
    """Rebuild the active set of the given rows only, widening the padded arrays when needed."""
    if rows.size > geom.rows // 2:
        return _active(geom, C, cos_lo, cos_hi, cap)
    Br, Wr = _active(geom.take_rows(rows), C[rows], cos_lo, cos_hi, cap)
    L, Lr = B.shape[1], Br.shape[1]
    if Lr > L:
        B = np.concatenate([B, np.zeros((B.shape[0], Lr - L, 3), np.float32)], axis=1)
        Wa = np.concatenate([Wa, np.zeros((Wa.shape[0], Lr - L), np.float32)], axis=1)
    else:
        B = B.copy() if not B.flags.writeable else B
        Wa = Wa.copy() if not Wa.flags.writeable else Wa
    B[rows] = 0.0
    Wa[rows] = 0.0
    B[rows, :Lr] = Br
    Wa[rows, :Lr] = Wr
    return B, Wa


def subsample(geom: Geometry, lengths: np.ndarray, cap: int) -> Geometry:
    """At most ``cap`` evenly strided landmarks of each row as unit bearings, weights scaled to the row totals.

    ``lengths`` (K,): how many leading columns of each row are real (the rest is padding).
    """
    K = geom.rows
    k = np.arange(cap)
    lengths = np.asarray(lengths, dtype=np.intp)
    cols = np.where(lengths[:, None] > cap, (k[None, :] * lengths[:, None]) // cap, k[None, :])
    real = k[None, :] < np.minimum(lengths, cap)[:, None]
    cols = np.where(real, cols, 0)
    rows = np.broadcast_to(np.arange(K)[:, None], cols.shape)
    p = geom.points[cols] if geom.shared else geom.points[rows, cols]
    w = geom.weights[cols] if geom.weights.ndim == 1 else geom.weights[rows, cols]
    if geom.inv_dist is not None:
        p = (p - geom.origins[:, None, :]) * geom.inv_dist[rows, cols][..., None]
    w = np.where(real, w, 0.0)
    total = geom.weight_rows().sum(axis=1, dtype=np.float64)
    sub = w.sum(axis=1, dtype=np.float64)
    w = w * (total / np.where(sub > 0, sub, 1.0))[:, None]
    return Geometry(p.astype(np.float32), np.zeros((K, 3), np.float32), None, w.astype(np.float32), geom.exact)


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b for (K, 3) arrays (cheaper than np.cross for small K)."""
    out = np.empty(np.broadcast_shapes(a.shape, b.shape))
    out[:, 0] = a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1]
    out[:, 1] = a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2]
    out[:, 2] = a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]
    return out


def _exp(w: np.ndarray) -> np.ndarray:
    """exp(ω^) (K, 3, 3) for rotation vectors (K, 3) (Rodrigues; same as geometry.so3_exp, less overhead)."""
    th = np.sqrt(np.einsum("ij,ij->i", w, w))
    small = th < 1e-8
    safe = np.where(small, 1.0, th)
    a = np.where(small, 1.0, np.sin(safe) / safe)
    b = np.where(small, 0.5, (1.0 - np.cos(safe)) / safe**2)
    K = np.zeros((w.shape[0], 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -w[:, 2], w[:, 1], -w[:, 0]
    K[:, 1, 0], K[:, 2, 0], K[:, 2, 1] = w[:, 2], -w[:, 1], w[:, 0]
    out = np.matmul(K, K) * b[:, None, None] + K * a[:, None, None]
    out[:, 0, 0] += 1.0
    out[:, 1, 1] += 1.0
    out[:, 2, 2] += 1.0
    return out


def _turn_to(R: np.ndarray, target: np.ndarray) -> np.ndarray:
    """Left-multiply each R (K, 3, 3) by the smallest rotation taking R e3 to the unit ``target`` (K, 3)."""
    c = R[:, :, 2]
    axis = _cross(c, target)
    s = np.sqrt(np.einsum("ij,ij->i", axis, axis))
    ang = np.arctan2(s, np.sum(c * target, axis=1))
    moved = ang > 1e-12
    if not np.any(moved):
        return R
    w = np.zeros_like(axis)
    w[moved] = axis[moved] / np.maximum(s[moved], 1e-300)[:, None] * ang[moved, None]
    antipodal = moved & (s < 1e-12)
    if np.any(antipodal):  # turn by π about any axis ⟂ c
        w[antipodal] = tangent_basis(c[antipodal])[0] * np.pi
    return _exp(w) @ R


def ascend(
    geom: Geometry,
    R: np.ndarray,
    norm: np.ndarray,
    settings: AscentSettings,
    lam: float = 0.0,
    anchor: np.ndarray | None = None,
    project: Projector | None = None,
    knee: float = 0.0,
) -> tuple[np.ndarray, int]:
    """Maximise Σ_k F_k(R_k)/norm_k + λ Σ_k v(c_{k+1}·c_k) (+ λ v(anchor·c_0)) over rotations R (K, 3, 3), with
    the pair value v of :mod:`pivotd.pivot.smoothness` at ``knee`` [rad] (0: v(x) = x, the paper's term).

    With λ = 0 the rows are independent. Step control: the step direction is the combined gradient
    (eqs. 12, 18, 19) normalised by each row's feature weight ``norm`` (K,); its length is clipped to a
    per-row bound h_k that grows ×1.2 while successive gradients agree and halves when they reverse
    (overshoot; the step after a reversal keeps its bound, as in iRprop), between ``tol`` and
    ``step_max``. It ends when at most ``settle_frac`` of the rows still step by ≥ tol.
    ``project`` (optional) maps axes onto the reachable set after every step (projected gradient
    ascent). Returns the rotations and the iteration count.

    Only the axes are tracked: a step exp((h û)^) with û ⟂ c moves the axis to c cos h + (û × c) sin h,
    and the roll about the axis does not enter the objective. The returned rotations are the inputs
    turned by the smallest rotation onto the final axes.
    """
    R = np.array(R, dtype=float)
    K = R.shape[0]
    inv_norm = 1.0 / np.maximum(norm, 1e-12)
    C = R[:, :, 2].copy()
    if project is not None:
        C = project(C)
    total = 0
    coupled = (lam > 0 and K > 1) or (lam > 0 and anchor is not None)
    a_q, width = settings.alpha, settings.width
    ks = ks_from_width(a_q, width)
    w_eff = min(width, a_q, np.pi - a_q)
    margin = 2.0 * w_eff + settings.drift
    cos_lo = float(np.cos(min(np.pi, a_q + margin)))
    cos_hi = float(np.cos(max(0.0, a_q - margin))) if a_q - margin > 0 else 1.0
    cap = settings.cap
    cos_a = np.float32(np.cos(a_q))
    half_ks = np.float32(0.5 * ks)
    quarter_ks = np.float32(0.25 * ks)
    h = np.full(K, min(settings.step_init, max(a_q, settings.tol), 0.5 * settings.drift))
    J_prev = np.zeros((K, 3))
    B, Wa = _active(geom, C, cos_lo, cos_hi, cap)
    C_ref = C.copy()
    cos_drift = np.cos(settings.drift)
    cos_pairs = np.ones(K)  # cosines of consecutive axes (K − 1,), then of the anchor and the first axis
    s_scale = (float(quarter_ks) * inv_norm)[:, None]  # the visible gradient's factor k_s/4 / W_k (K, 1)
    flat_w = np.full(K - 1, lam)  # the pair weights without a knee
    for _ in range(settings.iterations):
        total += 1
        t = np.matmul(B, C.astype(np.float32)[:, :, None])[..., 0]  # cos θ (K, L)
        t -= cos_a
        t *= half_ks
        np.tanh(t, out=t)
        t *= t
        g = np.subtract(np.float32(1.0), t, out=t)
        g *= Wa  # ∝ s_j v (1 − v): the k_s/4 factor is applied to the (K, 3) sum
        S = np.matmul(g[:, None, :], B)[:, 0, :].astype(float)
        S *= s_scale
        if coupled:  # J = c × (S_vis / W + Σ_neighbours w · c_nb): one cross product for both terms
            # w = λ × the pair value's slope at the current step (λ itself without a knee)
            if knee > 0:  # the slopes of the K − 1 pairs and of the anchor's pair, in one pass
                cos_pairs[:-1] = np.einsum("ij,ij->i", C[1:], C[:-1])
                if anchor is not None:
                    cos_pairs[-1] = anchor @ C[0]
                slopes = lam * pair_slope(cos_pairs, knee)
                pair_w, anchor_w = slopes[:-1], float(slopes[-1])
            else:
                pair_w, anchor_w = flat_w, lam
            S[1:] += pair_w[:, None] * C[:-1]
            S[:-1] += pair_w[:, None] * C[1:]
            if anchor is not None:
                S[0] += anchor_w * anchor
        J = _cross(C, S)
        nJ = np.sqrt(np.einsum("ij,ij->i", J, J))
        agree = np.einsum("ij,ij->i", J, J_prev)
        h = np.where(agree < 0, 0.5 * h, np.where(agree > 0, np.minimum(1.2 * h, settings.step_max), h))
        J_prev = np.where((agree < 0)[:, None], 0.0, J)  # after a reversal the next step neither grows nor shrinks
        live = nJ > 1e-12
        moving = live & (h >= settings.tol)
        if np.count_nonzero(moving) <= settings.settle_frac * K:  # rows at rest have bounds below tol
            break
        hs = np.where(live, h, 0.0)
        u = J / np.where(live, nJ, 1.0)[:, None]
        C = C * np.cos(hs)[:, None] + _cross(u, C) * np.sin(hs)[:, None]
        if project is None:
            C /= np.sqrt(np.einsum("ij,ij->i", C, C))[:, None]
        else:
            C = project(C)  # returns unit rows (rows at rest are reachable already and stay as they are)
        if cos_lo > -1.0:
            moved = np.flatnonzero(np.einsum("ij,ij->i", C, C_ref) < cos_drift)
            if moved.size:
                B, Wa = _refresh_rows(geom, C, moved, B, Wa, cos_lo, cos_hi, cap)
                C_ref[moved] = C[moved]
    return _turn_to(R, C), total


def evaluate(geom: Geometry, C: np.ndarray, alpha: float, width: float) -> tuple[np.ndarray, np.ndarray]:
    """Hard visible counts (K,) int and smooth objectives F_k = Σ_j s_kj v(θ_kj) (K,) at α, from one cos pass.

    Counts include landmarks of any weight; padding and landmarks at the sensor (inv_dist 0) never
    count. Pairs within 2e-4 of cos α are settled in float64.
    """
    x = geom.cos_all(C)
    ca = np.cos(alpha)
    x -= np.float32(ca)  # x = cos θ − cos α
    inside = x >= 0
    if geom.inv_dist is not None and geom.weights.ndim == 2 and not geom.valid_all:
        inside &= geom.inv_dist > 0
    elif geom.valid is not None:
        inside &= geom.valid
    rows, cols = _nonzero2d(np.abs(x) < np.float32(2e-4))
    if rows.size:
        if geom.inv_dist is not None:
            ok = geom.inv_dist[rows, cols] > 0
        else:
            ok = geom.valid[rows, cols] if geom.valid is not None else np.ones(rows.size, bool)
        inside[rows[ok], cols[ok]] = geom.exact(rows[ok], cols[ok], C) >= ca - 1e-12
    counts = np.count_nonzero(inside, axis=1)
    x *= np.float32(0.5 * ks_from_width(alpha, width))
    np.tanh(x, out=x)  # v = (1 + tanh) / 2
    W = geom.weight_rows()
    F = 0.5 * (geom.row_totals + np.einsum("ij,ij->i", W, x).astype(np.float64))
    return counts, F
