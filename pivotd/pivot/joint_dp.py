"""Exact dynamic programme over a pan/tilt joint grid: the best camera path a speed-limited gimbal can follow.

A :class:`JointGrid` samples the joint ranges evenly; :func:`cell_counts` scores every cell of one frame by the
landmarks in its viewing cone; :func:`best_joint_path` finds the sequence of cells with the largest total score
whose per-step moves stay within per-axis limits (a rectangle of cells around the previous cell, wrapping in pan
on a continuous-pan gimbal). The recursion V[k+1](c) = s[k+1](c) + max over the rectangle around c of V[k] is
evaluated with separable sliding maxima, O(N·P·T), and the path is recovered by exact backtracking.

Cell (i, j) is pan ``pans[i]``, tilt ``tilts[j]``; flat index i·T + j. Directions follow
:func:`pivotd.geometry.pan_tilt_to_direction` in the gimbal base frame, as :func:`pivotd.gimbal.kinematics.
joints_to_world_direction` does.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.ndimage import maximum_filter1d

from pivotd.geometry import pan_tilt_to_direction

__all__ = ["JointGrid", "JointPath", "best_joint_path", "best_smooth_joint_path", "cell_counts"]

_EPS = 1e-9  # slack on cell-count divisions and reach tests


def _even(lo: float, hi: float, step: float) -> np.ndarray:
    """Evenly spaced values from lo to hi, both included, spacing ≤ step."""
    if hi - lo <= _EPS:
        return np.array([0.5 * (lo + hi)])
    n = math.ceil((hi - lo) / step - _EPS) + 1
    return np.linspace(lo, hi, n)


@dataclass(frozen=True, eq=False)
class JointGrid:
    """Pan values ``pans`` (P,) and tilt values ``tilts`` (T,) [rad], each evenly spaced.

    With ``continuous_pan`` the pans cover the full circle with spacing 2π/P and no duplicate end, and pan
    distances wrap.
    """

    pans: np.ndarray
    tilts: np.ndarray
    continuous_pan: bool = False

    def __post_init__(self) -> None:
        for name in ("pans", "tilts"):
            a = np.array(getattr(self, name), dtype=float).reshape(-1)
            if a.size == 0 or not np.isfinite(a).all() or np.any(np.diff(a) <= 0):
                raise ValueError(f"JointGrid.{name} must be a non-empty increasing finite array")
            a.setflags(write=False)
            object.__setattr__(self, name, a)

    @classmethod
    def inside(cls, pan_min: float, pan_max: float, tilt_min: float, tilt_max: float,
               step: float = math.radians(2.0), continuous_pan: bool = False) -> JointGrid:
        """Grid inside the joint limits [rad] with spacing ≤ ``step`` [rad], both ends of each range included.

        With ``continuous_pan`` the pan limits are ignored: P = ceil(2π/step) pans from ``pan_min`` (−π when
        not finite) around the circle.
        """
        if not step > 0 or not math.isfinite(step):
            raise ValueError(f"grid step must be a positive finite angle, got {step!r}")
        if not tilt_min <= tilt_max or (not continuous_pan and not pan_min <= pan_max):
            raise ValueError(f"bad joint limits: pan [{pan_min}, {pan_max}], tilt [{tilt_min}, {tilt_max}]")
        tilts = _even(float(tilt_min), float(tilt_max), step)
        if continuous_pan:
            origin = float(pan_min) if math.isfinite(pan_min) else -math.pi
            n = max(math.ceil(2.0 * math.pi / step - _EPS), 1)
            pans = origin + 2.0 * math.pi * np.arange(n) / n
        else:
            pans = _even(float(pan_min), float(pan_max), step)
        return cls(pans, tilts, continuous_pan)

    @property
    def shape(self) -> tuple[int, int]:
        """(P, T)."""
        return (self.pans.size, self.tilts.size)

    @property
    def pan_step(self) -> float:
        """Pan spacing [rad] (2π/P when continuous; 0 for a single pan)."""
        if self.continuous_pan:
            return 2.0 * math.pi / self.pans.size
        return float(self.pans[1] - self.pans[0]) if self.pans.size > 1 else 0.0

    @property
    def tilt_step(self) -> float:
        """Tilt spacing [rad] (0 for a single tilt)."""
        return float(self.tilts[1] - self.tilts[0]) if self.tilts.size > 1 else 0.0

    def pan_cells(self, limit: float) -> int:
        """Largest pan move [cells] within ``limit`` [rad]: floor(limit/step + 1e-9), capped to the grid."""
        return _cells(limit, self.pan_step, self.pans.size)

    def tilt_cells(self, limit: float) -> int:
        """Largest tilt move [cells] within ``limit`` [rad]: floor(limit/step + 1e-9), capped to the grid."""
        return _cells(limit, self.tilt_step, self.tilts.size)

    def base_directions(self) -> np.ndarray:
        """Unit optical axes (P·T, 3) of every cell in the gimbal base frame, flat index i·T + j."""
        pan, tilt = np.meshgrid(self.pans, self.tilts, indexing="ij")
        return pan_tilt_to_direction(pan, tilt).reshape(-1, 3)

    def directions(self, base_from_world: np.ndarray) -> np.ndarray:
        """World unit directions (P·T, 3) of every cell for a base orientation ``base_from_world`` (3, 3)
        (:func:`pivotd.gimbal.kinematics.base_from_world`: world → base)."""
        R = np.asarray(base_from_world, dtype=float)
        if R.shape != (3, 3):
            raise ValueError(f"base_from_world must be (3, 3), got {R.shape}")
        return self.base_directions() @ R  # row form of Rᵀ d

    def joints(self, cells: np.ndarray) -> np.ndarray:
        """Joint angles (N, 2) [rad] of cell indices (N, 2)."""
        c = np.asarray(cells, dtype=int).reshape(-1, 2)
        return np.stack([self.pans[c[:, 0]], self.tilts[c[:, 1]]], axis=1)

    def nearest(self, pan: float, tilt: float) -> tuple[int, int]:
        """Cell (i, j) nearest to the joint angles [rad] (pan distance wraps when continuous)."""
        return int(np.argmin(self._pan_distance(pan))), int(np.argmin(np.abs(self.tilts - tilt)))

    def _pan_distance(self, pan: float) -> np.ndarray:
        d = np.abs(self.pans - pan)
        if self.continuous_pan:
            d = np.abs(np.remainder(self.pans - pan + math.pi, 2.0 * math.pi) - math.pi)
        return d


def _cells(limit: float, step: float, n: int) -> int:
    if not limit >= 0:
        raise ValueError(f"a per-step joint limit must be ≥ 0, got {limit!r}")
    if n <= 1 or step <= 0:
        return 0
    if not math.isfinite(limit):
        return n - 1
    return int(min(math.floor(limit / step + _EPS), n - 1))


def cell_counts(rel: np.ndarray, weights: np.ndarray | None, grid: JointGrid, base_from_world: np.ndarray,
                alpha: float) -> np.ndarray:
    """Hard count (or weight sum) (P, T) of landmarks within ``alpha`` [rad] of each cell's direction.

    ``rel`` (L, 3): landmark minus camera [m], world frame (landmarks at the camera are ignored); ``weights``
    (L,) or None (count). Range filtering is the caller's job.

    Exact and O(L·T + P·T): the angle between a cell (p, t) and a landmark at base angles (p_l, t_l) is within
    alpha iff cos t cos t_l cos(p − p_l) + sin t sin t_l ≥ cos alpha, so on every tilt row the landmark covers
    one pan interval around p_l (around p_l + π where cos t < 0), added as a difference array and summed.
    """
    rel = np.asarray(rel, dtype=float).reshape(-1, 3)
    w = np.ones(rel.shape[0]) if weights is None else np.asarray(weights, dtype=float).reshape(-1)
    if w.shape[0] != rel.shape[0]:
        raise ValueError(f"weights must have shape ({rel.shape[0]},), got {w.shape}")
    R = np.asarray(base_from_world, dtype=float)
    if R.shape != (3, 3):
        raise ValueError(f"base_from_world must be (3, 3), got {R.shape}")
    P, T = grid.shape
    norm = np.linalg.norm(rel, axis=1)
    keep = norm > 1e-9
    if not keep.any():
        return np.zeros((P, T))
    b = rel[keep] @ R.T  # base frame (L, 3)
    w = w[keep]
    pl = np.arctan2(b[:, 1], b[:, 0])
    tl = np.arctan2(-b[:, 2], np.hypot(b[:, 0], b[:, 1]))
    ct, st = np.cos(grid.tilts), np.sin(grid.tilts)
    A = ct[None, :] * np.cos(tl)[:, None]  # (L, T)
    B = math.cos(alpha) - st[None, :] * np.sin(tl)[:, None]
    flat = np.abs(A) <= 1e-12  # the cell or the landmark at a pole: pan does not matter
    with np.errstate(divide="ignore", invalid="ignore"):
        c = np.where(flat, np.where(B <= 0, -np.inf, np.inf), B / np.abs(A))
    centre = pl[:, None] + np.where(A < 0, math.pi, 0.0)
    half = np.arccos(np.clip(c, -1.0, 1.0))  # (L, T) half-width of the pan interval [rad]
    some = c <= 1.0
    full = some & (c <= -1.0 + 1e-12)
    part = some & ~full
    rows = np.broadcast_to(np.arange(T), c.shape)
    ww = np.broadcast_to(w[:, None], c.shape)
    out = np.zeros((T, P))
    if full.any():
        out += np.bincount(rows[full], ww[full], minlength=T)[:, None]
    if part.any():
        out += _pan_intervals(grid, centre[part], half[part], rows[part], ww[part])
    return out.T.copy()


def _pan_intervals(grid: JointGrid, centre: np.ndarray, half: np.ndarray, rows: np.ndarray,
                   w: np.ndarray) -> np.ndarray:
    """(T, P) sums of ``w`` (K,) over the pans within ``half`` (K,) of ``centre`` (K,) [rad] on tilt row ``rows``
    (K,) (pan angles compared modulo 2π; half < π)."""
    P, T = grid.shape
    p0 = float(grid.pans[0])
    step = grid.pan_step if P > 1 else 1.0
    diff = np.zeros((T, 2 * P + 1) if grid.continuous_pan else (T, P + 1))
    lo_a, hi_a = centre - half, centre + half
    if grid.continuous_pan:
        lo = np.ceil((lo_a - p0) / step - _EPS).astype(np.int64)
        hi = np.floor((hi_a - p0) / step + _EPS).astype(np.int64)
        n = np.minimum(hi - lo + 1, P)
        ok = n > 0
        start = np.remainder(lo[ok], P)
        _scatter(diff, rows[ok], start, start + n[ok], w[ok])
        run = np.cumsum(diff, axis=1)
        return run[:, :P] + run[:, P:2 * P]
    two_pi = 2.0 * math.pi
    shift = p0 + np.remainder(centre - p0, two_pi) - centre  # centres into [p0, p0 + 2π)
    lo_a, hi_a = lo_a + shift, hi_a + shift
    for k in range(-1, math.ceil((float(grid.pans[-1]) - p0) / two_pi) + 1):
        lo = np.ceil((lo_a + two_pi * k - p0) / step - _EPS).astype(np.int64)
        hi = np.floor((hi_a + two_pi * k - p0) / step + _EPS).astype(np.int64)
        lo, hi = np.maximum(lo, 0), np.minimum(hi, P - 1)
        ok = lo <= hi
        if ok.any():
            _scatter(diff, rows[ok], lo[ok], hi[ok] + 1, w[ok])
    return np.cumsum(diff, axis=1)[:, :P]


def _scatter(diff: np.ndarray, rows: np.ndarray, start: np.ndarray, stop: np.ndarray, w: np.ndarray) -> None:
    """diff[rows, start] += w and diff[rows, stop] -= w (repeated indices accumulate)."""
    width = diff.shape[1]
    idx = np.concatenate([rows * width + start, rows * width + stop])
    diff += np.bincount(idx, np.concatenate([w, -w]), minlength=diff.size).reshape(diff.shape)


@dataclass(frozen=True)
class JointPath:
    """The optimum of :func:`best_joint_path`: cell indices (N, 2) (pan index, tilt index) and its total score."""

    cells: np.ndarray
    total: float

    def joints(self, grid: JointGrid) -> np.ndarray:
        """Joint angles (N, 2) [rad] of the path's cells."""
        return grid.joints(self.cells)


def _window_max(V: np.ndarray, rp: int, rt: int, wrap: bool) -> np.ndarray:
    """Max of V (P, T) over the rectangle |Δi| ≤ rp (circular when ``wrap``), |Δj| ≤ rt around every cell."""
    P, _T = V.shape
    M = V
    if rp > 0:
        if wrap and 2 * rp + 1 >= P:
            M = np.broadcast_to(M.max(axis=0, keepdims=True), M.shape)
        else:
            M = maximum_filter1d(M, 2 * rp + 1, axis=0, mode="wrap" if wrap else "constant", cval=-np.inf)
    if rt > 0:
        M = maximum_filter1d(M, 2 * rt + 1, axis=1, mode="constant", cval=-np.inf)
    return np.asarray(M)


def _scores(scores: np.ndarray, grid: JointGrid) -> np.ndarray:
    """``scores`` as a float (N, P, T) array for ``grid``; ValueError on another shape or NaN."""
    S = np.asarray(scores, dtype=float)
    if S.ndim != 3 or S.shape[1:] != grid.shape or S.shape[0] == 0:
        raise ValueError(f"scores must have shape (N, {grid.shape[0]}, {grid.shape[1]}), got {S.shape}")
    if np.isnan(S).any():
        raise ValueError("scores contain NaN")
    return S


def _steps(limit: np.ndarray | float, n: int, name: str) -> np.ndarray:
    a = np.broadcast_to(np.asarray(limit, dtype=float), (max(n - 1, 0),))
    if np.isnan(a).any() or (a < 0).any():
        raise ValueError(f"{name} must be ≥ 0 for each of the {n - 1} steps")
    return a


def best_joint_path(scores: np.ndarray, max_dpan: np.ndarray | float, max_dtilt: np.ndarray | float,
                    grid: JointGrid, start: tuple[float, float] | None = None,
                    start_reach: tuple[float, float] | None = None) -> JointPath:
    """Cell path (N, 2) maximising Σ scores[k, i_k, j_k] with |Δpan| ≤ max_dpan[k], |Δtilt| ≤ max_dtilt[k] [rad]
    between steps k and k + 1 (in cells: floor(limit/step + 1e-9); pan wraps on a continuous-pan grid).

    ``scores`` (N, P, T) (−inf marks a forbidden cell); ``max_dpan``, ``max_dtilt`` (N − 1,) or scalars [rad].
    ``start`` (pan, tilt) [rad] restricts the first cell to those within ``start_reach`` (dpan, dtilt) [rad]
    of it (default (0, 0)); the cell nearest ``start`` is always allowed. Ties go to the smallest move
    (|Δi| + |Δj| in cells, backwards from the last step), then the lowest flat index.
    Raises ValueError when no path is feasible.
    """
    S = _scores(scores, grid)
    N, _P, T = S.shape
    rp = [grid.pan_cells(v) for v in _steps(max_dpan, N, "max_dpan")]
    rt = [grid.tilt_cells(v) for v in _steps(max_dtilt, N, "max_dtilt")]
    wrap = grid.continuous_pan

    V = np.empty_like(S)
    V[0] = S[0]
    if start is not None:
        V[0] = np.where(_start_mask(grid, start, start_reach), S[0], -np.inf)
    elif start_reach is not None:
        raise ValueError("start_reach needs a start pose")
    for k in range(N - 1):
        V[k + 1] = S[k + 1] + _window_max(V[k], rp[k], rt[k], wrap)

    last = V[-1].ravel()
    flat = int(np.argmax(last))  # first (lowest) index among equal maxima
    if not np.isfinite(last[flat]):
        raise ValueError("no feasible joint path (every path crosses a forbidden cell)")
    cells = np.empty((N, 2), dtype=int)
    cells[-1] = divmod(flat, T)
    for k in range(N - 2, -1, -1):
        cells[k] = _predecessor(V[k], cells[k + 1], rp[k], rt[k], wrap)
    return JointPath(cells, float(last[flat]))


def _start_mask(grid: JointGrid, start: tuple[float, float], reach: tuple[float, float] | None) -> np.ndarray:
    dpan, dtilt = (0.0, 0.0) if reach is None else (float(reach[0]), float(reach[1]))
    if not (dpan >= 0 and dtilt >= 0):
        raise ValueError(f"start_reach must be ≥ 0, got {reach!r}")
    pan, tilt = float(start[0]), float(start[1])
    ok_p = grid._pan_distance(pan) <= dpan + _EPS
    ok_t = np.abs(grid.tilts - tilt) <= dtilt + _EPS
    mask = ok_p[:, None] & ok_t[None, :]
    mask[grid.nearest(pan, tilt)] = True
    return mask


def _predecessor(V: np.ndarray, cell: np.ndarray, rp: int, rt: int, wrap: bool) -> tuple[int, int]:
    """The cell of V within the move rectangle around ``cell`` holding its maximum; ties: smallest move, then
    lowest flat index."""
    P, T = V.shape
    i0, j0 = int(cell[0]), int(cell[1])
    if not wrap:  # the rectangle is a slice of V
        i_lo, j_lo = max(i0 - rp, 0), max(j0 - rt, 0)
        block = V[i_lo:min(i0 + rp, P - 1) + 1, j_lo:min(j0 + rt, T - 1) + 1]
        hits = np.flatnonzero(block == block.max())
        hit_i, hit_j = np.divmod(hits, block.shape[1])
        if hits.size > 1:  # ties: the smallest move, then the lowest flat index (row-major: the first hit)
            move = np.abs(hit_i + (i_lo - i0)) + np.abs(hit_j + (j_lo - j0))
            k = int(np.argmin(move))
            hit_i, hit_j = hit_i[k:], hit_j[k:]
        return i_lo + int(hit_i[0]), j_lo + int(hit_j[0])
    di = np.arange(-rp, rp + 1) if 2 * rp + 1 < P else np.arange(P) - i0
    ii = np.remainder(i0 + di, P)
    di = np.abs(np.remainder(ii - i0 + P // 2, P) - P // 2) if 2 * rp + 1 >= P else np.abs(di)
    jj = np.arange(max(j0 - rt, 0), min(j0 + rt, T - 1) + 1)
    block = V[np.ix_(ii, jj)]
    best = block.max()
    hit_i, hit_j = np.nonzero(block == best)
    move = di[hit_i] + np.abs(jj[hit_j] - j0)
    flat = ii[hit_i] * T + jj[hit_j]
    pick = np.lexsort((flat, move))[0]
    return int(ii[hit_i[pick]]), int(jj[hit_j[pick]])


def best_smooth_joint_path(scores: np.ndarray, max_dpan: np.ndarray | float, max_dtilt: np.ndarray | float,
                           max_ddpan: np.ndarray | float, max_ddtilt: np.ndarray | float, grid: JointGrid,
                           centre: np.ndarray, radius: tuple[int, int]) -> JointPath:
    """Cell path (N, 2) maximising Σ scores[k, c_k] under a first- and a second-order limit on the moves
    m_k = c_{k+1} − c_k (cells; pan wraps on a continuous-pan grid), inside a corridor around ``centre``.

    * |m_k| ≤ max_dpan[k], max_dtilt[k] [rad] (as :func:`best_joint_path`; in cells floor(limit/step + 1e-9));
    * |m_k − m_{k−1}| ≤ max_ddpan[k], max_ddtilt[k] [rad] with m_{−1} = 0: the path starts at rest and its move
      changes by at most the limit per step (``a·dt²`` for an acceleration limit a at frame interval dt; inf:
      no limit at that step);
    * c_0 = centre[0] and |c_k − centre[k]| ≤ ``radius`` (pan, tilt) [cells] per axis (pan distance wrapping).

    On a continuous-pan grid moves and distances go the short way round, a pan move at most (P − 1)//2 cells.

    ``scores`` (N, P, T) (−inf marks a forbidden cell); ``max_dpan``, ``max_dtilt``, ``max_ddpan``,
    ``max_ddtilt`` (N − 1,) or scalars; ``centre`` (N, 2) cell indices. Exact: a dynamic programme over the lifted
    state (cell offset in the corridor, last move), O(N · corridor cells · moves · (Δpan + Δtilt changes)). Ties go
    to the smallest change of move on each axis (tilt first, backwards from the last step), then the lowest flat
    state index.
    Raises ValueError when no path is feasible.
    """
    S = _scores(scores, grid)
    N, P, T = S.shape
    C = np.asarray(centre, dtype=np.int64)
    if C.shape != (N, 2) or np.any(C < 0) or np.any(C[:, 0] >= P) or np.any(C[:, 1] >= T):
        raise ValueError(f"centre must be (N, 2) cell indices inside the ({P}, {T}) grid, got shape {C.shape}")
    rp, rt = (int(r) for r in radius)
    if rp < 0 or rt < 0:
        raise ValueError(f"radius must be ≥ 0 cells, got {radius!r}")
    wrap = grid.continuous_pan
    vp = np.array([grid.pan_cells(v) for v in _steps(max_dpan, N, "max_dpan")], dtype=np.int64)
    vt = np.array([grid.tilt_cells(v) for v in _steps(max_dtilt, N, "max_dtilt")], dtype=np.int64)
    ap = np.array([grid.pan_cells(v) for v in _steps(max_ddpan, N, "max_ddpan")], dtype=np.int64)
    at = np.array([grid.tilt_cells(v) for v in _steps(max_ddtilt, N, "max_ddtilt")], dtype=np.int64)
    if wrap:  # moves and corridor offsets the short way round: a move is at most (P − 1)//2 cells
        vp = np.minimum(vp, (P - 1) // 2)
        rp = min(rp, P // 2)
    Mp = int(vp.max()) if vp.size else 0
    Mt = int(vt.max()) if vt.size else 0
    ap, at = np.minimum(ap, 2 * Mp), np.minimum(at, 2 * Mt)

    # corridor scores (N, Op, Ot): offset index u ↔ cell centre_k + u − radius
    op = np.arange(-rp, rp + 1) if not (wrap and 2 * rp + 1 > P) else np.arange(-rp, P - rp)
    ot = np.arange(-rt, rt + 1)
    ci = C[:, :1] + op[None, :]
    cj = C[:, 1:] + ot[None, :]
    ok_i = np.ones(ci.shape, bool) if wrap else (ci >= 0) & (ci < P)
    ok_j = (cj >= 0) & (cj < T)
    ci = np.remainder(ci, P) if wrap else np.clip(ci, 0, P - 1)
    cj = np.clip(cj, 0, T - 1)
    Sc = S[np.arange(N)[:, None, None], ci[:, :, None], cj[:, None, :]]
    Sc = np.where(ok_i[:, :, None] & ok_j[:, None, :], Sc, -np.inf)
    d = np.diff(C, axis=0)  # centre moves (N − 1, 2)
    if wrap:
        d[:, 0] = np.remainder(d[:, 0] + P // 2, P) - P // 2

    Op, Ot = op.size, ot.size
    mp = np.arange(-Mp, Mp + 1)
    mt = np.arange(-Mt, Mt + 1)
    V = np.full((Op, Ot, mp.size, mt.size), -np.inf)
    V[rp, rt, Mp, Mt] = Sc[0, rp, rt]  # at the centre, at rest
    back = np.zeros((max(N - 1, 0), Op, Ot, mp.size, mt.size), dtype=np.int32)  # chosen change per state
    for k in range(N - 1):
        # W[u, m'] = max over previous moves m with |m' − m| ≤ a_k (per axis) of V[u, m]: tilt, then pan
        Wt, jt = _move_window(V, int(at[k]), axis=3)
        W, ip = _move_window(Wt, int(ap[k]), axis=2)
        jsel = np.take_along_axis(jt, np.clip(np.arange(mp.size)[None, None, :, None] + ip, 0, mp.size - 1), axis=2)
        arg = ((ip + 2 * Mp) * (4 * Mt + 1) + jsel + 2 * Mt).astype(np.int32)  # (Δpan, Δtilt) of the move
        W[:, :, np.abs(mp) > vp[k], :] = -np.inf
        W[:, :, :, np.abs(mt) > vt[k]] = -np.inf
        # V'[u', m'] = S[u'] + W[u' − m' + d_k, m']
        su = np.arange(Op)[:, None] - mp[None, :] + d[k, 0]  # (Op, Mp)
        if wrap:  # the source cell's offset from the previous centre, the short way round
            su = np.remainder(su - rp + P // 2, P) - P // 2 + rp
        sv = np.arange(Ot)[:, None] - mt[None, :] + d[k, 1]  # (Ot, Mt)
        okp = (su >= 0) & (su < Op)
        okt = (sv >= 0) & (sv < Ot)
        su, sv = np.clip(su, 0, Op - 1), np.clip(sv, 0, Ot - 1)
        ix = (su[:, None, :, None], sv[None, :, None, :], np.arange(mp.size)[None, None, :, None],
              np.arange(mt.size)[None, None, None, :])
        G = np.where(okp[:, None, :, None] & okt[None, :, None, :], W[ix], -np.inf)
        back[k] = arg[ix]
        V = Sc[k + 1][:, :, None, None] + G

    flat = int(np.argmax(V))
    if not np.isfinite(V.ravel()[flat]):
        raise ValueError("no feasible joint path (every path crosses a forbidden cell)")
    total = float(V.ravel()[flat])
    u, v, a, b = np.unravel_index(flat, V.shape)
    offs = np.empty((N, 2), dtype=np.int64)
    offs[-1] = (u, v)
    for k in range(N - 2, -1, -1):
        i, j = divmod(int(back[k, u, v, a, b]), 4 * Mt + 1)
        i, j = i - 2 * Mp, j - 2 * Mt
        u, v = u - mp[a] + d[k, 0], v - mt[b] + d[k, 1]
        if wrap:
            u = (u - rp + P // 2) % P - P // 2 + rp
        a, b = a + i, b + j
        offs[k] = (u, v)
    cells = C + offs - np.array([rp, rt])
    if wrap:
        cells[:, 0] = np.remainder(cells[:, 0], P)
    return JointPath(cells, total)


def _move_window(V: np.ndarray, a: int, axis: int) -> tuple[np.ndarray, np.ndarray]:
    """Max of V over index offsets δ ∈ [−a, a] along ``axis`` (outside: −inf) and the δ holding it (ties: the
    smallest |δ|, then the negative one)."""
    n = V.shape[axis]
    best = V.copy()
    arg = np.zeros(V.shape, dtype=np.int64)
    for mag in range(1, min(a, n - 1) + 1):
        for delta in (-mag, mag):
            cand = np.full(V.shape, -np.inf)
            dst = [slice(None)] * V.ndim
            src = [slice(None)] * V.ndim
            dst[axis] = slice(max(-delta, 0), n - max(delta, 0))
            src[axis] = slice(max(delta, 0), n - max(-delta, 0))
            cand[tuple(dst)] = V[tuple(src)]
            better = cand > best
            best = np.where(better, cand, best)
            arg[better] = delta
    return best, arg
