"""Step-limited polish of a trajectory: dynamic programming on the discrete objective the plan is judged by.

The gradient ascent maximises a smoothed visibility (sigmoid of width ~3°), whose optimum can sit a
fraction of a degree off the optimum of the hard count. For a plan with a largest step S,
:func:`step_limited_polish` takes at every waypoint the axis and the directions on two rings around it as
candidates, and dynamic programming picks the sequence of candidates with the largest total hard visible
weight (or Φ_hard = Σ_i V_i(c_i)/W_i + λκ Σ_i v(c_{i+1}·c_i)) whose consecutive directions (and the step from
the anchor) stay within S: exact over the candidates, so whole runs of waypoints move together, and the
current plan is one of the sequences, so the score never drops and no step exceeds S.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from pivotd.geometry import tangent_basis
from pivotd.pivot import _ascent
from pivotd.pivot.smoothness import pair_value

__all__ = ["Reachable", "ring_offsets", "step_limited_polish"]

Reachable = Callable[[np.ndarray, np.ndarray], np.ndarray]


def ring_offsets(radius: float, tol: float) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """cos r, sin r, cos φ, sin φ (each (K, 1)) for 8 directions φ on each ring r = radius, radius/2, … ≥ tol."""
    radii = [radius]
    while radii[-1] * 0.5 >= tol:
        radii.append(radii[-1] * 0.5)
    ang = np.arange(8) * (np.pi / 4)
    r = np.repeat(radii, 8)[:, None]
    return np.cos(r), np.sin(r), np.tile(np.cos(ang), len(radii))[:, None], np.tile(np.sin(ang), len(radii))[:, None]


def _ring_candidates(C: np.ndarray, radius: float) -> np.ndarray:
    """Candidates (N, 17, 3) per unit axis C (N, 3): the axis, then 8 directions at ``radius`` and 8 at radius/2.

    Each candidate is a fixed combination of the axis and its two tangents, so all of them come from one
    (17, 3) @ (3, 3N) product."""
    cos_r, sin_r, ca, sa = ring_offsets(radius, 0.5 * radius)
    coef = np.vstack([[1.0, 0.0, 0.0], np.hstack([cos_r, sin_r * ca, sin_r * sa])])  # (17, 3): c, t1, t2
    t1, t2 = tangent_basis(C)
    basis = np.stack([C, t1, t2])  # (3, N, 3)
    N = C.shape[0]
    return (coef @ basis.reshape(3, 3 * N)).reshape(-1, N, 3).transpose(1, 0, 2)


def _best_sequence(val: np.ndarray, pen: np.ndarray) -> np.ndarray:
    """Candidate index per waypoint (N,) maximising Σ_i val[i, k_i] + Σ_i pen[i − 1, k_i, k_{i−1}] (Viterbi).

    val (N, K) candidate values, pen (N − 1, K to, K from) transition values (−inf: forbidden). Ties go
    to the lowest index (candidate 0, the current axis). The forward pass is three numpy calls per waypoint
    into preallocated buffers (the sum, its argmax per row, and the row maxima gathered through the flat
    index of the argmax); the backtrack walks the argmax table as a list.
    """
    N, K = val.shape
    back = np.empty((N, K), dtype=np.intp)
    tot = np.empty((K, K))
    flat = tot.reshape(-1)
    row_start = np.arange(K) * K
    idx = np.empty(K, dtype=np.intp)
    score = np.array(val[0], dtype=float)
    add, take = np.add, flat.take
    for i in range(1, N):
        add(pen[i - 1], score, out=tot)  # (to, from)
        b = back[i]
        tot.argmax(axis=1, out=b)
        add(row_start, b, out=idx)
        add(take(idx), val[i], out=score)
    k = int(score.argmax())
    pick = [k]
    rows = back.tolist()
    for i in range(N - 1, 0, -1):
        k = rows[i][k]
        pick.append(k)
    return np.array(pick[::-1], dtype=np.intp)


def _within(x: np.ndarray, alpha: float, reach: float) -> np.ndarray:
    """Mask (N, L) of the cosines x (N, L) to the axes whose angle is within α ± reach [rad]."""
    mask = x >= np.float32(np.cos(min(np.pi, alpha + reach)))
    if alpha > reach:
        mask &= x <= np.float32(np.cos(alpha - reach))
    return mask


def _take(B: np.ndarray, Wa: np.ndarray, mask: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The band entries (B (N, L, 3) float32, Wa (N, L)) under ``mask`` (N, L), packed to the left of
    (N, L', 3) and (N, L') with L' the largest row count (at least 1); padding has weight 0."""
    N = mask.shape[0]
    counts = np.count_nonzero(mask, axis=1)
    Lk = max(int(counts.max(initial=0)), 1)
    flat = np.flatnonzero(mask)
    starts = np.cumsum(counts) - counts
    dest = np.arange(flat.size) + np.repeat(np.arange(N) * Lk - starts, counts)
    Bk = np.zeros((N * Lk, 3), np.float32)
    Wk = np.zeros(N * Lk, np.float32)
    Bk.view(_ascent._ROW3).ravel()[dest] = np.ascontiguousarray(B).reshape(-1, 3).view(_ascent._ROW3).ravel().take(flat)
    Wk[dest] = Wa.reshape(-1).take(flat)
    return Bk.reshape(N, Lk, 3), Wk.reshape(N, Lk)


def _score(cand: np.ndarray, B: np.ndarray, Wa: np.ndarray, cos_a: np.float32) -> np.ndarray:
    """Hard visible weight (N, K) float64 of candidate axes cand (N, K, 3) over the band B (N, L, 3), Wa (N, L)."""
    x = np.matmul(cand.astype(np.float32), B.transpose(0, 2, 1))  # (N, K, L) cosines
    np.greater_equal(x, cos_a, out=x, casting="unsafe")  # 1.0 inside, 0.0 outside, in place
    return np.matmul(x, Wa[:, :, None])[..., 0].astype(float)


def step_limited_polish(
    band: Callable[[np.ndarray, float], tuple[np.ndarray, np.ndarray]],
    C: np.ndarray,
    alpha: float,
    max_step: float,
    radius: float,
    tol: float,
    *,
    anchor: np.ndarray | None = None,
    reachable: Reachable | None = None,
    smooth: float = 0.0,
    norm: np.ndarray | None = None,
    knee: float = 0.0,
) -> np.ndarray:
    """Step-limited dynamic-programming polish (module docstring); returns the new unit axes (N, 3).

    ``band(C, reach)`` returns float32 unit bearings (N, L, 3) and weights (N, L) of the landmarks
    within α ± reach [rad] of each axis C (N, 3): the only ones whose state a move of at most ``reach``
    can change (the others add the same to every candidate of their waypoint). C (N, 3): unit axes whose
    steps are ≤ ``max_step`` [rad]; one DP per radius r = radius, radius/2, … ≥ tol [rad] over the
    rings r and r/2, recentred on each result. ``band`` is called once, with the reach 2.02 × radius of
    all levels together (the axes move by < 2 × radius in all); each level narrows the previous level's
    band to α ± 2.02 r around its axes (it held α ± 4.04 r around axes that have moved ≤ 2 r since) and
    scores all waypoints × candidates in one batched product on the part within α ± 1.01 r (the landmarks
    whose state a move of ≤ r can change). ``reachable(rows, directions (n, K, 3)) -> (n, K) bool``
    (optional) restricts the candidates to the reachable ones. With ``smooth`` = λκ > 0 it maximises Φ_hard
    (visible weight / ``norm`` (N,) plus λκ Σ c_{i+1}·c_i) within the limit instead of the visible weight alone.
    """
    C = np.array(C, dtype=float)
    N = C.shape[0]
    if N == 0 or radius < tol:
        return C
    cos_a = np.float32(np.cos(alpha) - 1e-7)
    cos_s = float(np.cos(max_step)) - 1e-12
    inv = 1.0 / np.maximum(norm, 1e-12) if smooth > 0 else None
    B, Wa = band(C, 2.02 * radius)
    r = radius
    while r >= tol:
        if B.shape[1] == 0:
            break
        x = np.matmul(B, C.astype(np.float32)[:, :, None])[..., 0]  # (N, L) cosines to the axes, once per level
        # only landmarks within α ± r of the axes can change state under a move of ≤ r; the others add the same
        # to every candidate of their waypoint, which leaves the best sequence unchanged
        Bs, Ws = _take(B, Wa, _within(x, alpha, 1.01 * r))
        if r < radius and 0.5 * r >= tol:  # the next level's band: the axes move by ≤ r in this level
            B, Wa = _take(B, Wa, _within(x, alpha, 2.02 * r))
        cand = _ring_candidates(C, r)  # (N, K, 3)
        val = _score(cand, Bs, Ws, cos_a)  # (N, K)
        if inv is not None:
            val *= inv[:, None]
        if reachable is not None:
            val[:, 1:][~reachable(np.arange(N), cand[:, 1:])] = -np.inf
        if anchor is not None:
            far = cand[0] @ anchor < cos_s
            far[0] = False  # the current axis stays a choice whatever the rounding
            val[0, far] = -np.inf
        pen = np.matmul(cand[1:], cand[:-1].transpose(0, 2, 1))  # (N − 1, K to, K from) cosines
        too_far = pen < cos_s
        too_far[:, 0, 0] = False  # the current plan is always feasible
        if smooth > 0:
            if knee > 0:
                pen[...] = pair_value(pen, knee)
            pen *= smooth
        else:
            pen[...] = 0.0
        pen[too_far] = -np.inf  # in place: np.where over the (N − 1, K, K) array took 4× as long
        if smooth > 0 and anchor is not None:
            val[0] += smooth * pair_value(cand[0] @ anchor, knee)
        C = cand[np.arange(N), _best_sequence(val, pen)]
        C /= np.linalg.norm(C, axis=1, keepdims=True)
        r *= 0.5
    return C
