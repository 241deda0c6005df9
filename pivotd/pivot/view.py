"""Single-pose PIVOT: the viewing direction that keeps the most (weighted) landmarks in a conical FoV.

Practical enhancements of the paper (§IV-C). Global stage, O(n + cells): the bearings are binned on a
cube map with one ``bincount`` (exact integer counts, independent of the landmarks' order) and one
sparse product with a precomputed cone-overlap matrix (:mod:`pivotd.pivot.cone_kernel`, built once per
half-angle) gives the approximate visible weight of a cone on every cell; its best distinct peaks (plus
the weighted centroid) take a mean-shift step on the histogram. (Up to ``sample`` landmarks the seeds are
axes, the centroid, landmarks and a coarse lattice, shifted on the landmarks themselves.) The survivors
are ranked by their hard visible weight on all landmarks; the best one and the rivals whose widened-cone
bound could still beat it are refined by gradient ascent on the smooth objective; a coarse-to-fine
hard-count search on spirals of directions (:func:`local_search`: a wide cap for flat landscapes with
many shallow maxima close together, then finer ones) finishes. Steps are normalised, clipped and
adaptively scaled (as in :func:`pivotd.pivot._ascent.ascend`). Narrow cones (α < ``narrow_deg``) take another
path, whatever the number of landmarks: a branch and bound over a 3-D hash of the bearings in cubes of the
cone's chord, with exact local searches on the landmarks of the cone's edge (:func:`_narrow_view`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pivotd.geometry import optical_frame_from_direction, tangent_basis
from pivotd.pivot._checks import feature_weights, finite_array, half_angle, unit_vector
from pivotd.pivot.cone_kernel import ConeKernel, cell_keys, cone_kernel
from pivotd.pivot.lattice import fibonacci_sphere, spiral_caps
from pivotd.pivot.visibility import ks_from_width

__all__ = ["ViewOptions", "ViewResult", "boundary_axes", "local_search", "optimize_view"]


@dataclass
class ViewOptions:
    """Tuning of :func:`optimize_view` (angles in degrees): the optimizer's own, no config key sets any of it (the
    daemon solves its single views with these defaults), so every field keeps its default."""

    width_deg: float = 2.0  # sigmoid transition width at α (k_s from ks_from_width) ...
    width_ratio: float = 0.1  # ... but at least this fraction of α (wide cones need softer edges)
    max_iterations: int = 40  # iteration budget at α
    step_init_deg: float = 4.0
    step_max_deg: float = 15.0
    tol_deg: float = 0.5  # refinement stops below this step (the hard-count searches go finer)
    sample: int = 1024  # above this many landmarks the candidates come from a histogram of the bearings ...
    cells: int | None = None  # ... on a cube map with cells × cells per face (None: from α, cone_kernel.cells_per_face)
    hist_shift: int = 1  # mean-shift steps of the peaks (and the weighted centroid) on the histogram
    peaks: int = 12  # distinct histogram peaks (cones centred on cells, by approximate weight) seeding the candidates
    seeds: int = 32  # landmark-seeded candidates
    mean_shift: int = 2  # mean-shift steps applied to every candidate before ranking
    coarse_ratio: float = 1.0  # global seed: a direction lattice spaced ≈ ratio · α scored on the subsample
    coarse_peaks: int = 4  # its best directions (non-maximum suppressed) join the multi-start set (0: off)
    refine: int = 6  # distinct candidates kept after the subsample ranking
    distinct_ratio: float = 0.5  # candidates closer than ratio · α count as duplicates
    full_shift: int = 1  # ≤ sample landmarks: mean-shift steps on all of them, each scored by full hard count
    reach_ratio: float = 0.25  # a candidate is refined when its weight within α(1 + ratio) can beat the best
    final_candidates: int = 2  # at most this many go on to the refinement at α
    keep_ratio: float = 0.5  # drop candidates whose subsample score is < ratio · best
    drift_deg: float = 5.0
    cap_ratio: float = 0.5  # hard-count search (local_search): first a spiral of directions within ratio · α ...
    cap_points: int = 32  # ... of the best with this many directions (flat landscapes: the best peak nearby; 0: off)
    polish_deg: float = 1.5  # then spirals of polish_points directions of radius polish_deg (0: off), at least
    # 0.6 × the cap's spacing cap_ratio · α · √(π / cap_points) so that every point of the cap is within reach ...
    polish_ratio: float = 1.0 / 3.0  # ... shrinking by this factor ...
    polish_tol_deg: float = 0.1  # ... while the radius stays ≥ this (at most 0.05 α)
    polish_points: int = 24
    narrow_deg: float = 6.0  # below this half-angle the global stage is the cap hash (_cap_candidates) ...
    narrow_searches: int = 32  # ... and at most this many of its candidates (by cube bound) get a hard-count search,
    narrow_empty_cubes: int = 1024  # ... (with the empty cubes next to the occupied ones while these are fewer) ...
    narrow_cap_ratio: float = 1.75  # ... over a cap of radius ratio · α around a cube's centre (covers the cube) ...
    narrow_cap_points: int = 64  # ... with this many directions, then an exact search (boundary_axes) within
    narrow_exact_ratio: float = 1.0  # ... this fraction of α of the result (halved until its edge band holds ...
    narrow_exact_band: int = 80  # ... at most this many landmarks) around each of the ...
    narrow_exact: int = 3  # ... this many best distinct results of the hard-count search


@dataclass
class ViewResult:
    """direction (3,) unit; rotation (3, 3) camera-to-world with rotation @ e3 == direction;
    visible: hard count (angle ≤ α); objective: F at α (eq. 6); iterations: gradient steps taken."""

    direction: np.ndarray
    rotation: np.ndarray
    visible: int
    objective: float
    iterations: int


def _spread(n: int, k: int) -> np.ndarray:
    """k indices (k,) spread evenly over range(n), first and last included: ⌊i (n − 1)/(k − 1)⌋ (exact integers)."""
    if k <= 1:
        return np.zeros(min(k, n), dtype=np.intp)
    return np.arange(k, dtype=np.intp) * (n - 1) // (k - 1)


_AXES = ((1.0, 0.0, 0.0), (0.0, 1.0, 0.0), (0.0, 0.0, 1.0), (-1.0, 0.0, 0.0), (0.0, -1.0, 0.0), (0.0, 0.0, -1.0))


def _candidates(
    B: np.ndarray,
    BT: np.ndarray,
    w: np.ndarray,
    alpha: float,
    opts: ViewOptions,
    init: np.ndarray | None,
    uniform: bool,
) -> np.ndarray:
    """Multi-start directions (K ≤ refine, 3) for few landmarks (≤ ``sample``), best score first, none closer
    than distinct_ratio · α: seeds (axes, centroid, landmarks, a coarse lattice) moved by mean shift and
    scored on the landmarks themselves. B (n, 3) unit bearings and BT (3, n) their float32 transpose.
    ``uniform``: all weights ``w`` are equal (saves a weighted product per mean-shift step).
    """
    Bs, ws = B.astype(np.float32), w.astype(np.float32)
    seeds = list(_AXES)
    centroid = ws @ Bs
    x, y, z = (float(v) for v in centroid)
    nc = math.sqrt(x * x + y * y + z * z)
    if nc > 1e-9 * max(float(ws.sum()), 1e-12):
        x, y, z = x / nc, y / nc, z / nc
        t1, t2 = tangent_basis(np.array([x, y, z]))
        (tx, ty, tz), (ux, uy, uz) = t1.tolist(), t2.tolist()
        ca, sa = math.cos(2 * alpha), math.sin(2 * alpha)
        seeds.append((x, y, z))
        for px, py, pz in ((tx, ty, tz), (-tx, -ty, -tz), (ux, uy, uz), (-ux, -uy, -uz)):
            seeds.append((ca * x + sa * px, ca * y + sa * py, ca * z + sa * pz))
    if init is not None:
        seeds.append(tuple(init))
    C = np.array(seeds, dtype=np.float32)
    k = min(opts.seeds, Bs.shape[0])
    if k:
        C = np.concatenate([C, Bs.take(_spread(Bs.shape[0], k), axis=0)])
    cos_a = np.float32(np.cos(alpha))
    BsT = np.ascontiguousarray(Bs.T)  # (3, s): (K, 3) @ (3, s) is the fast layout
    if opts.coarse_peaks > 0:
        C = np.concatenate([C, _coarse_peaks(BsT, ws, alpha, opts)])
    raw = C
    raw_score = None
    Bs1 = np.empty((Bs.shape[0], 4), np.float32)  # (s, 4): bearings and a column of ones
    Bs1[:, :3] = Bs
    Bs1[:, 3] = 1.0
    for _ in range(opts.mean_shift):  # mean shift with a flat conical kernel
        inside = C @ BsT  # (K, s)
        np.greater_equal(inside, cos_a, out=inside)  # 1.0 inside the cone
        if not uniform:
            inside *= ws
        moved = inside @ Bs1  # (K, 4): weighted sums inside each cone and the weight inside
        if raw_score is None:
            raw_score = moved[:, 3] if uniform else moved[:, 3].copy()
        moved = moved[:, :3]
        nrm = np.sqrt(np.einsum("ij,ij->i", moved, moved))
        ok = nrm > 1e-12
        C = np.where(ok[:, None], moved / np.where(ok, nrm, 1.0)[:, None], C)
    score = C @ BsT
    score = np.greater_equal(score, cos_a, out=score) @ ws
    if raw_score is not None:  # a seed can beat the mode it drifts to (wide cones): keep both
        C = np.concatenate([C, raw])
        score = np.concatenate([score, raw_score])
    order = np.argsort(-score, kind="stable")
    order = order[score[order] >= opts.keep_ratio * score[order[0]]]
    Co = C[order]
    kept = _greedy_distinct(Co, np.cos(opts.distinct_ratio * alpha), max(1, opts.refine))  # positions, best first
    return Co[kept].astype(float)


def _histogram_candidates(
    BT: np.ndarray, w: np.ndarray, alpha: float, opts: ViewOptions, init: np.ndarray | None, uniform: bool,
    kernel: ConeKernel,
) -> np.ndarray:
    """Multi-start directions (K ≤ refine, 3) for many landmarks, best approximate weight first, none closer
    than distinct_ratio · α.

    The bearings BT (3, n) float32 (weights w (n,), ``uniform``: all equal) are binned on the kernel's cube
    map with one ``bincount`` (exact integer counts for equal weights: independent of the landmarks' order);
    one sparse product gives the approximate weight of the cone centred on every cell; its ``peaks`` best
    distinct cells (plus the weighted centroid and ``init``) take one mean-shift step on the histogram
    (cells weighted by their estimated fraction inside the cone), and each keeps the better of its start and
    its shifted position by the same estimate. Cost O(n + cells).
    """
    h = np.bincount(cell_keys(BT, kernel.m), weights=None if uniform else w, minlength=kernel.size).astype(np.float32)
    A = kernel.counts(h)  # (C,) approximate weight of the cone on every cell centre
    k = min(8 * max(1, opts.peaks), A.size)
    top = np.argpartition(A, A.size - k)[A.size - k :]
    top = top.take(np.argsort(-A.take(top), kind="stable"))
    cos_d = math.cos(opts.distinct_ratio * alpha)
    D = kernel.centres.take(top, axis=0)
    picks = _greedy_distinct(D, cos_d, max(1, opts.peaks))
    seeds = [D.take(picks, axis=0)]
    hs = h.take(kernel.keys)  # (C,) weight per cell
    if opts.hist_shift:
        centroid = hs @ kernel.centres
        nc = float(np.sqrt(centroid @ centroid))
        if nc > 1e-6 * max(float(hs.sum()), 1e-12):
            seeds.append((centroid / nc)[None])
    if init is not None:
        seeds.append(init.astype(np.float32)[None])
    C = np.concatenate(seeds) if len(seeds) > 1 else seeds[0]
    score = np.empty(C.shape[0], np.float32)
    score[: len(picks)] = A.take(top.take(picks))
    for step in range(max(1, opts.hist_shift)):  # mean shift on the histogram, keeping the better of start and end
        # one product gives each axis's cells weighted by their estimated fraction inside its cone: the shifted
        # axis (weighted mean of the cell centres) and the estimate of the axis itself (the total)
        Wt = kernel.soft_weights(C @ kernel.centres_t)
        Wt *= hs
        moved = Wt @ kernel.centres1  # (K, 4)
        if step == 0:
            score[len(picks) :] = moved[len(picks) :, 3]  # the centroid's and init's estimates
        if not opts.hist_shift:
            break
        moved = moved[:, :3]
        nrm = np.sqrt(np.einsum("ij,ij->i", moved, moved))
        ok = nrm > 1e-12
        M = np.where(ok[:, None], moved / np.where(ok, nrm, 1.0)[:, None], C)
        sM = kernel.soft_weights(M @ kernel.centres_t) @ hs
        C, score = np.concatenate([M, C]), np.concatenate([sM, score])
    order = np.argsort(-score, kind="stable")
    order = order[score.take(order) >= opts.keep_ratio * score[order[0]]]
    Co = C.take(order, axis=0)
    return Co.take(_greedy_distinct(Co, cos_d, max(1, opts.refine)), axis=0).astype(float)


def _cap_candidates(
    BT: np.ndarray, w: np.ndarray, alpha: float, k: int, empty_upto: int, uniform: bool
) -> tuple[np.ndarray, np.ndarray]:
    """The k cubes with the highest bounds for a narrow cone: their centres projected on the sphere (K ≤ k, 3)
    and bounds (K,), highest first (ties in key order).

    The unit bearings BT (3, n) float32 (weights w (n,), ``uniform``: all equal) are hashed into a 3-D grid of
    cubes of side s = 2 sin(α/2), the chord of α: a cone of half-angle α whose axis lies in a cube holds only
    bearings of that cube and its 26 neighbours, so their weight bounds the weight of every such cone, whatever
    α; every direction of a cube is within 2 asin(√3 s / 2) ≈ 1.73 α of its projected centre. The cube weights
    come from one sort of the integer keys (``np.unique``: exact counts with equal weights, independent of the
    landmarks' order) and 27 ``searchsorted`` lookups of the shifted keys. The cubes are the occupied ones and,
    when there are at most ``empty_upto`` of those, also their empty neighbours (the axis of a cone can lie
    in an empty cube: a ring of bearings). Cost O(n log n), no table that grows as α shrinks.
    """
    s = 2.0 * math.sin(0.5 * alpha)
    M = math.ceil(1.0 / s) + 3  # indices of ⌊u_i / s⌋ + M (and ± 2) stay within 1 … 2M − 1
    L = 2 * M + 1
    Q = np.floor(BT * np.float32(1.0 / s)).astype(np.int64)
    Q += M
    keys = (Q[0] * L + Q[1]) * L + Q[2]
    uk, inv = np.unique(keys, return_inverse=True)
    U = uk.size
    own = np.bincount(inv, weights=None if uniform else w, minlength=U) * (float(w[0]) if uniform else 1.0)  # per cube
    offsets = np.array([(dx * L + dy) * L + dz for dx in (-1, 0, 1) for dy in (-1, 0, 1) for dz in (-1, 0, 1)])
    cubes = uk if empty_upto < U else np.unique((uk[:, None] + offsets).ravel())
    bound = np.zeros(cubes.size)
    for off in offsets:
        q = cubes + off
        pos = np.minimum(np.searchsorted(uk, q), U - 1)
        hit = np.flatnonzero(uk.take(pos) == q)
        bound[hit] += own.take(pos.take(hit))
    k = min(k, cubes.size)
    top = np.argpartition(-bound, k - 1)[:k] if k < cubes.size else np.arange(cubes.size)
    top = top[np.lexsort((cubes.take(top), -bound.take(top)))]  # by bound, then key: order-independent
    ix, rem = np.divmod(cubes.take(top), L * L)
    iy, iz = np.divmod(rem, L)
    D = (np.stack([ix, iy, iz], axis=1) - M + 0.5) * s
    return D / np.linalg.norm(D, axis=1, keepdims=True), bound.take(top)


def _narrow_view(
    B: np.ndarray, BT: np.ndarray, w: np.ndarray, w32: np.ndarray, alpha: float, opts: ViewOptions,
    init: np.ndarray | None, uniform: bool,
) -> np.ndarray:
    """Global stage and hard-count search for a narrow cone (α < narrow_deg): a branch and bound over the cubes
    of :func:`_cap_candidates`. In order of their bounds (``init`` first), while a bound exceeds the best weight
    found (at most 4 · narrow_searches cubes, narrow_searches of them searched approximately), the best axis
    within narrow_cap_ratio · α of the cube's projected centre (a disc covering the cube) is found exactly by
    :func:`_exact_local` when the disc's edge band is small (sparse data), otherwise by the coarse-to-fine
    :func:`local_search` over the disc (skipping cubes within α of one already searched so); the
    ``narrow_exact`` best distinct results of the latter then climb by exact searches within
    narrow_exact_ratio · α. Weights are counted in float64 (float32 cosines resolve only ~7 µrad at 0.5°).
    No smooth ascent: its transition width would be wider than the cone. B (n, 3) float64 and BT (3, n)
    float32 unit bearings, w / w32 (n,) weights.
    Returns the axis (3,)."""
    n_search = max(1, opts.narrow_searches)
    C, bound = _cap_candidates(BT, w, alpha, 8 * n_search, opts.narrow_empty_cubes, uniform)
    if init is not None:
        C, bound = np.vstack([init, C]), np.concatenate([[np.inf], bound])
    cover = opts.narrow_cap_ratio * alpha
    radii, points = _search_levels(alpha, opts, cover, opts.narrow_cap_points)
    cos_a = math.cos(alpha) - 1e-12

    def weight64(c: np.ndarray) -> float:
        return float(w[B @ (c / math.sqrt(float(c @ c))) >= cos_a].sum())

    found: list[tuple[float, int, np.ndarray, bool]] = []  # (hard weight, rank, axis, exact over the disc)
    searched: list[np.ndarray] = []  # centres of the cubes searched approximately
    cos_near = math.cos(alpha)
    for k in range(C.shape[0]):
        if found and bound[k] <= max(f[0] for f in found):
            break  # no cone with its axis in this cube (or a later one) sees more
        if len(searched) >= n_search or len(found) >= 4 * n_search:
            break
        if any(float(C[k] @ c) >= cos_near for c in searched):
            continue  # dense: a neighbouring cube's search already went over most of this one
        exact = _exact_local(C[k], BT, w32, alpha, cover, opts.narrow_exact_band, shrink=False)
        if exact is not None:
            found.append((weight64(exact), k, exact, True))
            continue
        searched.append(C[k])
        c = local_search(C[k], BT, w32, alpha, C[k].astype(np.float32) @ BT, radii, points) if radii else C[k]
        found.append((weight64(c), k, c, False))
    found.sort(key=lambda f: (-f[0], f[1]))
    best_s, c_best = found[0][0], found[0][2]
    done: list[np.ndarray] = []
    reach = opts.narrow_exact_ratio * alpha
    for sc, _, c, exact in found:
        if len(done) >= opts.narrow_exact or reach <= 0:
            break
        if exact or any(float(c @ d) >= math.cos(0.5 * reach) for d in done):
            continue  # settled already, or the same basin as an axis already searched exactly
        done.append(c)
        for _ in range(3):  # exact in a disc around c; repeated while it moves to a better axis
            e = _exact_local(c, BT, w32, alpha, reach, opts.narrow_exact_band)
            se = -1.0 if e is None else weight64(e)
            if e is None or se <= sc:
                break
            c, sc = e, se
        if sc > best_s:
            best_s, c_best = sc, c
    return c_best


def boundary_axes(B: np.ndarray, alpha: float) -> np.ndarray:
    """The axes (2P, 3) of the cones of half-angle α [rad] whose edge passes through two of the unit bearings
    B (m, 3) float64, for the P pairs at most 2α apart (coincident pairs skipped): c = a·m̂ ± √(1 − a²)·n̂ with
    m̂ the pair's mid-bearing, n̂ its unit normal and a = cos α / (m̂ · b). A cone holding the most weight can
    be moved onto such an axis (or onto a bearing) without losing any of it. O(m²) pairs."""
    pair_cos = B @ B.T
    i, j = np.nonzero(np.triu(pair_cos >= np.cos(2.0 * alpha), k=1))
    mid = B[i] + B[j]
    mid /= np.linalg.norm(mid, axis=1, keepdims=True)
    ax = np.cross(B[i], B[j])
    nrm = np.linalg.norm(ax, axis=1)
    ok = nrm > 1e-12
    mid, ax = mid[ok], ax[ok] / nrm[ok, None]
    a = np.minimum(1.0, np.cos(alpha) / np.einsum("ij,ij->i", mid, B[i[ok]]))
    t = np.sqrt(1.0 - a * a)[:, None]
    return np.concatenate([a[:, None] * mid + t * ax, a[:, None] * mid - t * ax])


def _exact_local(
    c: np.ndarray, BT: np.ndarray, w32: np.ndarray, alpha: float, reach: float, max_band: int, shrink: bool = True
) -> np.ndarray | None:
    """The best cone axis (3,) within r [rad] of the unit axis c (3,), exactly: every landmark within α − r
    of c is inside all those cones and every landmark beyond α + r outside, so only the edge band α ± r is
    scored. The axes keeping a given set of landmarks inside form an intersection of caps; where it meets
    the disc of radius r it has a corner that is c itself, a :func:`boundary_axes` axis of two band
    landmarks, or a point of the disc's rim at angle α from one band landmark (:func:`_edge_meets_disc`),
    so those candidates are scored. r
    starts at ``reach`` and halves until the band holds ≤ ``max_band`` landmarks (cost O(max_band³); None
    when ``shrink`` is False and the band at ``reach`` is larger).
    BT (3, n) float32 unit bearings, w32 (n,) weights."""
    cos_c = c.astype(np.float32) @ BT
    r = reach
    while True:
        lo, hi = np.cos(min(np.pi, alpha + r)) - 1e-6, np.cos(max(0.0, alpha - r)) + 1e-6
        sel = np.flatnonzero((cos_c >= lo) & (cos_c <= hi))
        if sel.size <= max_band or r < 1e-6:
            break
        if not shrink:
            return None
        r *= 0.5
    Bb = BT.take(sel, axis=1).T.astype(float)
    Bb /= np.linalg.norm(Bb, axis=1, keepdims=True)
    wb = w32.take(sel).astype(float)
    A = boundary_axes(Bb, alpha - 1e-6)  # 1 µrad inside: float32 bearings stay inside in float64
    A = np.vstack([c[None], A[A @ c >= np.cos(r)], _edge_meets_disc(Bb, alpha - 1e-6, c, r * (1 - 1e-9))])
    cos_ab = A @ Bb.T
    vals = (cos_ab >= np.cos(alpha) - 1e-12) @ wb
    return A[int(np.argmax(vals))]


def _edge_meets_disc(Bb: np.ndarray, alpha: float, c: np.ndarray, r: float) -> np.ndarray:
    """The directions (≤ 2m, 3) at angle α [rad] from one of the unit bearings Bb (m, 3) and at angle r from
    the unit axis c (3,): v = x·c + y·b ± z·(c × b) with x + y (c·b) = cos r, x (c·b) + y = cos α."""
    g = Bb @ c  # (m,)
    n = np.cross(np.broadcast_to(c, Bb.shape), Bb)
    det = 1.0 - g * g
    ok = det > 1e-15
    g, n, b, det = g[ok], n[ok], Bb[ok], det[ok]
    cr, ca = math.cos(r), math.cos(alpha)
    x = (cr - g * ca) / det
    y = (ca - g * cr) / det
    z2 = (1.0 - (x * x + y * y + 2.0 * x * y * g)) / det  # |c × b|² = 1 − g²
    hit = z2 >= 0.0
    x, y, n, b = x[hit], y[hit], n[hit], b[hit]
    base = x[:, None] * c + y[:, None] * b
    zn = np.sqrt(z2[hit])[:, None] * n
    V = np.concatenate([base + zn, base - zn])
    return V / np.linalg.norm(V, axis=1, keepdims=True) if V.size else V.reshape(0, 3)


def _greedy_distinct(D: np.ndarray, cos_min: float, k: int) -> list[int]:
    """Greedy non-maximum suppression over unit directions D (m, 3) sorted best first: the positions of at
    most k of them, each with cosine < ``cos_min`` to every one picked before it. The pairwise test is one
    product; the greedy walk runs on the rows packed as Python integers (bit j of row i: i and j are far)."""
    m = D.shape[0]
    if m == 0 or k <= 0:
        return []
    far = np.less(D @ np.ascontiguousarray(D.T), np.float32(cos_min))  # (m, m)
    nb = (m + 7) // 8
    rows = np.packbits(far, axis=1, bitorder="little").tobytes()
    free = (1 << m) - 1
    picks: list[int] = []
    while free and len(picks) < k:
        i = (free & -free).bit_length() - 1  # the best direction still free
        picks.append(i)
        free &= int.from_bytes(rows[i * nb : (i + 1) * nb], "little")
    return picks


def _coarse_peaks(BsT: np.ndarray, ws: np.ndarray, alpha: float, opts: ViewOptions) -> np.ndarray:
    """The global seed: hard visible weight of the subsample (BsT (3, s), ws (s,)) for every direction of a
    Fibonacci lattice spaced ≈ coarse_ratio · α, and its ``coarse_peaks`` best directions (k, 3) float32,
    each at least α/2 from the better ones (greedy non-maximum suppression)."""
    n_dirs = int(min(max(4.0 * math.pi / (opts.coarse_ratio * alpha) ** 2, 32), 4096))
    D = fibonacci_sphere(n_dirs).astype(np.float32)
    inside = np.greater_equal(D @ BsT, np.float32(np.cos(alpha)), out=np.empty((n_dirs, BsT.shape[1]), np.float32))
    score = inside @ ws
    order = np.argsort(-score, kind="stable")[: 8 * opts.coarse_peaks]
    Do = D[order]
    return Do[_greedy_distinct(Do, np.cos(0.5 * alpha), opts.coarse_peaks)]


def optimize_view(
    bearings: np.ndarray,
    weights: np.ndarray | None,
    alpha: float,
    *,
    init: np.ndarray | None = None,
    options: ViewOptions | None = None,
    kernel: ConeKernel | None = None,
) -> ViewResult:
    """Maximise F(R) = Σ_j s_j v(θ_j) (eq. 6) over R ∈ SO(3) for unit ``bearings`` (n, 3), half-angle α [rad].

    ``weights`` (n,) are the feature weights s_j (None: uniform); zero-length bearings (a landmark at
    the sensor) are ignored. ``init`` (3,) adds a starting direction to the multi-start set. ``kernel``:
    the :func:`pivotd.pivot.cone_kernel.cone_kernel` of α (and ``options.cells``), built once by callers that
    solve many poses with the same half-angle (None: built here when needed). Raises ValueError on NaN/inf
    input, α outside (0, π) or a kernel of another half-angle.
    """
    opts = options or ViewOptions()
    alpha = half_angle(alpha)
    init_v = None if init is None else unit_vector("init", init)
    B, BT, w = _unit_bearings(bearings, weights)
    if B.shape[0] == 0:
        d = init_v if init_v is not None else np.array([1.0, 0.0, 0.0])
        return ViewResult(d, optical_frame_from_direction(d), 0, 0.0, 0)
    w32 = w.astype(np.float32)
    uniform = weights is None or float(w.min()) == float(w.max())
    if kernel is not None and (abs(kernel.alpha - alpha) > 1e-9 * alpha
                               or (opts.cells is not None and kernel.m != opts.cells)):
        raise ValueError(f"kernel was built for alpha={kernel.alpha} with {kernel.m} cells per face, not {alpha}")
    if alpha < math.radians(opts.narrow_deg):  # the narrow path does not use the kernel
        c_best = _narrow_view(B, BT, w, w32, alpha, opts, init_v, uniform)
        return _result(c_best, B, BT, w32, alpha, opts, 0)
    if B.shape[0] > opts.sample:
        if kernel is None:
            kernel = cone_kernel(alpha, opts.cells)
        C = _histogram_candidates(BT, w, alpha, opts, init_v, uniform, kernel)
    else:
        C = _candidates(B, BT, w, alpha, opts, init_v, weights is None)
    iters = 0
    shifts = opts.full_shift if B.shape[0] <= opts.sample else 0  # above: shifted on the histogram instead
    C, cos_c, score, bound = _full_shift(C, BT, w32, alpha, shifts, opts.reach_ratio, uniform)
    cos_a32 = np.float32(np.cos(alpha))
    # refine the candidates that could still win: those whose bound (the weight within α(1 + reach_ratio),
    # more than any direction that close to them can see) reaches the best full hard weight: the best one
    # first, then by highest bound, skipping those the mean shift brought within distinct_ratio · α of one
    # already chosen (a greedy pick for the winner so far, optimistic picks for the basins it may miss)
    order = np.argsort(-bound, kind="stable")
    order = order[bound[order] >= score.max()]
    order = np.concatenate([[int(np.argmax(score))], order])
    cos_d = np.cos(opts.distinct_ratio * alpha)
    keep: list[int] = []
    for k in order:
        if len(keep) >= max(1, opts.final_candidates):
            break
        if all(float(C[k] @ C[j]) < cos_d for j in keep):
            keep.append(int(k))
    # the chosen candidates are refined together (one band, one product per step for all); a rival stops once it
    # comes within distinct_ratio · α of the axis of a better-ranked one (a basin already being climbed). Each
    # refined axis competes with its start.
    R, steps = _refine(BT, w32, C[keep], cos_c[keep], alpha, opts, uniform)
    iters += steps
    cos_r = R.astype(np.float32) @ BT
    s_r = _row_weights(cos_r >= cos_a32, w32, uniform)
    best_s, c_best, cos_best = -1.0, C[keep[0]], cos_c[keep[0]]
    for j, k in enumerate(keep):
        for c, cs, sc in ((R[j], cos_r[j], float(s_r[j])), (C[k], cos_c[k], float(score[k]))):
            if sc > best_s:
                best_s, c_best, cos_best = sc, c, cs
    radii, points = _search_levels(alpha, opts, opts.cap_ratio * alpha, opts.cap_points)
    if radii:
        c_best = local_search(c_best, BT, w32, alpha, cos_best, radii, points)
    return _result(c_best, B, BT, w32, alpha, opts, iters)


def _search_levels(alpha: float, opts: ViewOptions, cap: float, cap_points: int) -> tuple[list[float], list[int]]:
    """Radii [rad] and direction counts of :func:`local_search`: a first cap of radius ``cap`` with ``cap_points``
    directions (none when either is 0), then polish spirals from polish_deg (at least 0.6 × the cap's spacing)
    shrinking by polish_ratio down to polish_tol_deg (at most 0.05 α)."""
    rad = np.radians
    radii, points = [], []
    if cap_points > 0 and cap > 0:
        radii.append(cap)
        points.append(cap_points)
    if opts.polish_deg > 0:
        r, tol = min(rad(opts.polish_deg), 0.5 * alpha), min(rad(opts.polish_tol_deg), 0.05 * alpha)
        if radii:  # cover the gaps between the cap's directions
            r = max(r, 0.6 * radii[0] * math.sqrt(math.pi / cap_points))
        while True:
            radii.append(r)
            points.append(opts.polish_points)
            if r * opts.polish_ratio < tol:
                break
            r *= opts.polish_ratio
    return radii, points


def _result(
    c: np.ndarray, B: np.ndarray, BT: np.ndarray, w32: np.ndarray, alpha: float,
    opts: ViewOptions, iters: int,
) -> ViewResult:
    """The ViewResult of axis c (3,): hard count in float32, pairs within 2e-6 of cos α settled in float64."""
    c_best = c / np.sqrt(c @ c)
    ca = np.cos(alpha)
    x = c_best.astype(np.float32) @ BT
    x -= np.float32(ca)  # cos θ − cos α
    visible = int(np.count_nonzero(x > np.float32(2e-6)))
    if int(np.count_nonzero(x >= np.float32(-2e-6))) > visible:  # pairs at the edge (rare): settle in float64
        edge = np.flatnonzero(np.abs(x) <= np.float32(2e-6))
        visible += int(np.count_nonzero(B.take(edge, axis=0) @ c_best >= ca - 1e-12))
    # F at α: v = (1 + tanh((k_s/2)(cos θ − cos α))) / 2, in float32 like the ascent
    x *= np.float32(0.5 * ks_from_width(alpha, _width(alpha, opts)))
    np.tanh(x, out=x)
    f = 0.5 * float(w32.sum(dtype=np.float64) + x @ w32)
    return ViewResult(c_best, _frame(c_best), visible, f, iters)


def _full_shift(
    C: np.ndarray, BT: np.ndarray, w32: np.ndarray, alpha: float, shifts: int, reach_ratio: float, uniform: bool
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Mean-shift steps of the candidate axes C (K, 3) on all landmarks (float32 BT (3, n), weights w32 (n,)).

    Each candidate keeps the position with the highest full hard weight among its start and its shifted
    positions. Returns those axes (K, 3), their cos rows (K, n) float32, their hard weights (K,) and
    bounds (K,): the weight within α(1 + reach_ratio) of each kept axis. ``uniform``: all weights equal.
    """
    cos_a = np.float32(np.cos(alpha))
    cos_b = np.float32(np.cos(min(np.pi, alpha * (1.0 + reach_ratio))))
    C = C.astype(float)
    cos_c = C.astype(np.float32) @ BT  # (K, n)
    ins = np.greater_equal(cos_c, cos_a, out=np.empty_like(cos_c))  # 1.0 inside each cone
    score = ins @ w32
    for _ in range(shifts):
        moved = (ins if uniform else ins * w32) @ BT.T  # (K, 3) weighted sums inside each cone
        nrm = np.sqrt(np.einsum("ij,ij->i", moved, moved))
        ok = nrm > 1e-12
        C1 = np.where(ok[:, None], moved / np.where(ok, nrm, 1.0)[:, None], C)
        cos1 = C1.astype(np.float32) @ BT
        ins = np.greater_equal(cos1, cos_a, out=np.empty_like(cos1))
        s1 = ins @ w32
        better = s1 > score  # each keeps the first position with the highest weight
        if better.any():
            C[better], cos_c[better], score[better] = C1[better], cos1[better], s1[better]
    return C, cos_c, score, np.greater_equal(cos_c, cos_b, out=ins) @ w32


def _row_weights(mask: np.ndarray, w32: np.ndarray, uniform: bool) -> np.ndarray:
    """Weight inside each row of ``mask`` (K, n) bool, float32 (K,). With equal weights w32 (n,) and few rows,
    the count times that weight: one count_nonzero per long row beats a (K, n) cast and product."""
    if not uniform or mask.shape[0] > 8:
        return mask @ w32
    unit = w32[0] if w32.size else np.float32(1.0)
    if mask.shape[0] == 1:
        return np.array([np.count_nonzero(mask)], np.float32) * unit
    return np.array([np.count_nonzero(r) for r in mask], np.float32) * unit


def _unit_bearings(bearings: np.ndarray, weights: np.ndarray | None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Validated unit bearings: float64 B (n, 3), its float32 transpose BT (3, n) and weights w (n,).

    Rows shorter than 0.5 (a landmark at the sensor) are dropped, others normalised. One float64 pass
    in the common case: norms and the finiteness check come from the float32 copy; only non-finite or
    non-unit input goes through the float64 checks (which name the offending row).
    """
    B = np.asarray(bearings, dtype=float)
    if B.ndim != 2 or B.shape[1] != 3:
        finite_array("bearings", B)  # raises, naming the expected shape
    w = feature_weights(weights, B.shape[0])
    with np.errstate(over="ignore", invalid="ignore"):
        BT = np.ascontiguousarray(B.T, dtype=np.float32)
        sq = np.einsum("ij,ij->j", BT, BT)
    # one reduction decides the common case: every row unit (to float32 rounding) and finite
    dev = max(1.0 - float(sq.min()), float(sq.max()) - 1.0) if sq.size else 0.0  # NaN stays NaN
    if dev <= 1e-6:
        return B, BT, w
    if not math.isfinite(dev):  # NaN/inf (raises) or beyond float32's range: rescale in float64
        B = finite_array("bearings", B)
        B = B / np.maximum(np.abs(B).max(axis=1, keepdims=True), 1e-300)
        return _unit_bearings(B, w)
    ok = sq > 0.25
    if not ok.all():
        B, w, BT, sq = B[ok], w[ok], np.ascontiguousarray(BT[:, ok]), sq[ok]
    if sq.size and float(np.abs(sq - 1.0).max()) > 1e-6:
        B = B / np.sqrt(np.square(B) @ np.ones(3))[:, None]
        BT = np.ascontiguousarray(B.T, dtype=np.float32)
    return B, BT, w


def _frame(c: np.ndarray) -> np.ndarray:
    """The rotation (3, 3) of :func:`pivotd.geometry.optical_frame_from_direction` for one unit axis c (3,)."""
    right, down = tangent_basis(c, polar=None)
    return np.stack([right, down, c], axis=-1)


def _width(alpha: float, opts: ViewOptions) -> float:
    """Transition width [rad] used at α."""
    return max(np.radians(opts.width_deg), opts.width_ratio * alpha)


def _refine(
    BT: np.ndarray,
    w: np.ndarray,
    C: np.ndarray,
    cos_c: np.ndarray,
    alpha: float,
    opts: ViewOptions,
    uniform: bool,
) -> tuple[np.ndarray, int]:
    """Gradient ascent at α from each unit axis of C (K, 3) over float32 bearings BT (3, n) / weights w (n,),
    all K at once; ``cos_c`` (K, n) = C · k_j; ``uniform``: all weights equal. Returns the final axes (K, 3)
    and the largest number of steps.

    Same step control as :func:`pivotd.pivot._ascent.ascend` (normalised direction, bound grows ×1.2,
    halves on reversal), per axis, on the landmarks within the transition band α ± (2·width + drift) of
    any axis; the band is re-selected when an axis drifts further than ``drift_deg`` from where it was
    selected. The step exp((h Ĵ)^) R turns the axis about the unit tangent Ĵ ⟂ c:
    c ← cos h · c + sin h · (Ĵ × c), so only the axes are tracked (the roll does not change the objective).
    An axis that comes within distinct_ratio · α of the current axis of an earlier row stops there: it is
    climbing the basin that row is climbing.
    One iteration is a handful of numpy calls whatever K: (K, 4) @ (4, m) gives (k_s/2)(c · k_j − cos α)
    for every axis (the band carries a row of ones), then tanh, and v(1 − v) @ band for the ascent directions.
    """
    width = _width(alpha, opts)
    ks = ks_from_width(alpha, width)
    w_eff = min(width, alpha, np.pi - alpha)
    drift = np.radians(opts.drift_deg)
    margin = 2.0 * w_eff + drift
    lo = np.float32(np.cos(min(np.pi, alpha + margin)))
    hi = np.float32(np.cos(alpha - margin)) if alpha > margin else np.float32(2.0)
    half_ks = 0.5 * ks
    shift = -half_ks * float(np.cos(alpha))
    tol = min(np.radians(opts.tol_deg), 0.05 * alpha)
    h_max = min(np.radians(opts.step_max_deg), alpha)
    h0 = min(np.radians(opts.step_init_deg), 0.5 * drift, 0.5 * alpha)
    cos_drift = np.cos(drift)

    def band(cs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Bearings of the band with a row of ones (4, m) and their weighted bearings (m, 3)."""
        inside = (cs >= lo) & (cs <= hi)
        sel = np.flatnonzero(inside.any(axis=0) if inside.shape[0] > 1 else inside[0])
        A = np.empty((4, sel.size), np.float32)
        BT.take(sel, axis=1, out=A[:3])
        A[3] = 1.0
        return A, (A[:3] if uniform else A[:3] * w.take(sel)).T

    K = C.shape[0]
    xyz = [[float(v) for v in c] for c in C]
    ref = [list(c) for c in xyz]
    J = [(0.0, 0.0, 0.0)] * K
    h = [h0] * K
    active = list(range(K))
    A, AwT = band(cos_c)
    cos_near = math.cos(opts.distinct_ratio * alpha)
    it = 0
    for it in range(1, opts.max_iterations + 1):  # noqa: B007
        if not active or A.shape[1] == 0:
            break
        V = np.array([[half_ks * v for v in xyz[k]] + [shift] for k in active], np.float32)
        t = V @ A  # (k_s/2)(c · k_j − cos α), (K', m)
        np.tanh(t, out=t)
        t *= t
        np.subtract(1.0, t, out=t)  # ∝ v(1 − v); the constant factor does not matter after normalisation
        S = (t @ AwT).tolist()  # (K', 3)
        still, moved = [], False
        for k, (sx, sy, sz) in zip(active, S, strict=True):
            x, y, z = xyz[k]
            Jx, Jy, Jz = y * sz - z * sy, z * sx - x * sz, x * sy - y * sx  # c × S
            nJ = math.sqrt(Jx * Jx + Jy * Jy + Jz * Jz)
            jx, jy, jz = J[k]
            agree = Jx * jx + Jy * jy + Jz * jz
            hk = h[k]
            hk = 0.5 * hk if agree < 0 else (min(1.2 * hk, h_max) if agree > 0 else hk)
            h[k] = hk
            J[k] = (0.0, 0.0, 0.0) if agree < 0 else (Jx, Jy, Jz)
            if nJ < 1e-12 or hk < tol:
                continue
            ux, uy, uz = Jx / nJ, Jy / nJ, Jz / nJ
            ch, sh = math.cos(hk), math.sin(hk)
            x, y, z = ch * x + sh * (uy * z - uz * y), ch * y + sh * (uz * x - ux * z), ch * z + sh * (ux * y - uy * x)
            nrm = math.sqrt(x * x + y * y + z * z)
            x, y, z = x / nrm, y / nrm, z / nrm
            xyz[k] = [x, y, z]
            still.append(k)
            r = ref[k]
            moved |= xyz[k][0] * r[0] + xyz[k][1] * r[1] + xyz[k][2] * r[2] < cos_drift
        if K > 1:  # an axis within distinct_ratio · α of an earlier row's axis stops there
            still = [k for k in still if not any(
                xyz[k][0] * xyz[i][0] + xyz[k][1] * xyz[i][1] + xyz[k][2] * xyz[i][2] >= cos_near for i in range(k))]
        active = still
        if moved and active:
            A, AwT = band(np.array(xyz, np.float32) @ BT)
            ref = [list(c) for c in xyz]
    return np.array(xyz), it


def _spiral_frame(c: np.ndarray, toward: np.ndarray) -> np.ndarray:
    """Rows (3, 3): the unit axis c (3,), a unit tangent t1 and c × t1. The spiral's zero azimuth points along
    the tangent part of ``toward`` (3,) (a direction taken from the data, so that a rotated scene gives the
    rotated spiral), or along the first tangent of :func:`pivotd.geometry.tangent_basis` when that part vanishes."""
    x, y, z = (float(v) for v in c)
    gx, gy, gz = (float(v) for v in toward)
    d = gx * x + gy * y + gz * z
    tx, ty, tz = gx - d * x, gy - d * y, gz - d * z
    nt = math.sqrt(tx * tx + ty * ty + tz * tz)
    if nt <= 1e-6 * math.sqrt(gx * gx + gy * gy + gz * gz) or nt == 0.0:
        t1, t2 = tangent_basis(np.array([x, y, z]))
        return np.stack([np.array([x, y, z]), t1, t2])
    tx, ty, tz = tx / nt, ty / nt, tz / nt
    return np.array([[x, y, z], [tx, ty, tz], [y * tz - z * ty, z * tx - x * tz, x * ty - y * tx]])


def local_search(
    c: np.ndarray,
    BT: np.ndarray,
    w: np.ndarray,
    alpha: float,
    cos_c: np.ndarray,
    radii: list[float],
    points: list[int],
) -> np.ndarray:
    """Coarse-to-fine search of the hard visible weight around ``c`` (3,): for each radius r_k [rad] of
    ``radii`` (decreasing), ``points[k]`` directions on a spiral over the cap of radius r_k around the current
    best (:func:`pivotd.pivot.lattice.spiral_caps`); the best one replaces it when it sees strictly more.
    Returns the final axis.

    BT (3, n) float32 unit bearings, w (n,) float32 weights, ``cos_c`` (n,) = c · k_j. The axis moves at
    most Σ r_k, so only landmarks within α ± Σ r_k of ``c`` can change state: that band is taken once. The
    first level counts the part of it within α ± r_0 of ``c``, the later levels (which move the axis by at
    most their sum) the part within α ± Σ_{k≥1} r_k of the first level's result: a landmark outside it is
    inside all or none of their cones, which shifts every score of a level by the same amount. The current
    axis is scored with its spiral (row 0), so each level is one (1 + P, 3) @ (3, m) product, compared in
    place, and one matrix-vector product. On a flat landscape (the sensor inside a dense cloud) the maxima
    are shallow and many: the first, wide cap (a spacing of ≈ 2.35° with 32 directions over α/2 = 7.5°) puts
    a direction near each nearby one; the next levels only have to close the gap between spiral directions
    (each radius above 0.6 × the previous level's spacing, the farthest any point of a cap is from its
    nearest spiral direction).
    """
    band = _edge_band(BT, w, cos_c, alpha, float(sum(radii)))
    if band is None:
        return c
    bT, wb = band
    toward = (bT @ wb).astype(float)  # the band's weighted mean bearing orients every spiral
    cos_a = np.float32(math.cos(alpha) - 1e-7)
    lT, lw = bT, wb
    for k, local in enumerate(spiral_caps(radii, points)):
        if k <= 1:  # narrow the band: level 0 to α ± r_0 around c, the later levels to α ± Σ_{j≥1} r_j
            reach = radii[0] if k == 0 else float(sum(radii[1:]))
            cb = c.astype(np.float32) @ bT  # (m,)
            lo, hi = np.float32(math.cos(min(math.pi, alpha + reach))), np.float32(math.cos(max(0.0, alpha - reach)))
            sel = np.flatnonzero((cb >= lo) & (cb <= hi))
            if sel.size == 0:
                if k == 0:
                    continue
                break
            lT, lw = bT.take(sel, axis=1), wb.take(sel)
        cand = local @ _spiral_frame(c, toward)  # (1 + P, 3), row 0 = c
        inside = cand.astype(np.float32) @ lT  # (1 + P, m')
        vals = np.greater_equal(inside, cos_a, out=inside) @ lw  # 1.0 inside the cone
        best = int(np.argmax(vals))  # the first maximum: 0 (stay) unless a direction sees strictly more
        if best:
            c = cand[best] / math.sqrt(float(cand[best] @ cand[best]))
    return c


def _edge_band(
    BT: np.ndarray, w: np.ndarray, cos_c: np.ndarray, alpha: float, reach: float
) -> tuple[np.ndarray, np.ndarray] | None:
    """The landmarks whose angle to the current axis is within α ± ``reach`` [rad] (``cos_c`` (n,) = c · k_j):
    only they can enter or leave the cone while the axis moves by at most ``reach``. Their bearings (3, m)
    and float32 weights (m,), or None when there are none."""
    lo, hi = np.cos(min(np.pi, alpha + reach)), np.cos(max(0.0, alpha - reach))
    sel = np.flatnonzero((cos_c >= lo) & (cos_c <= hi))
    if sel.size == 0:
        return None
    return BT.take(sel, axis=1), w.take(sel).astype(np.float32)
