"""Trajectory PIVOT (paper §IV-B): one viewing direction per waypoint, visibility plus smoothness.

Maximises Σ_i F_i(R_i)/W_i + λκ Σ_i c_{i+1}·c_i (+ λκ a·c_0 with an anchor direction a), where
F_i = Σ_j s_ij v(θ_ij) (eq. 6) over waypoint i's retained landmarks, s_ij = feature weight × (optionally) the
distance weight of eq. 15, and W_i = Σ_j s_ij normalises each waypoint by its local feature weight (the paper's
ε = 1/(nπ)). All waypoints are updated together with padded arrays: R_i ← exp((h_i Ĵ_i)^) R_i with
J_i = J_vis,i/W_i + λκ c_i × (c_{i−1} + c_{i+1}) (eqs. 12, 18–20; one neighbour at the ends).
With ``TrajectoryOptions.smooth_knee_deg`` > 0 each pair enters as v(c_{i+1}·c_i) instead
(:mod:`pivotd.pivot.smoothness`: a step beyond the knee costs in proportion to its size, not its square). With
``TrajectoryOptions.normalise`` = attainable, W_i is instead the most weight one cone of the FoV holds at that
waypoint (:mod:`pivotd.pivot.normalise`). Under a hard step limit (``max_step``) the limit is the smoothness
asked for: the objective a plan is judged by is then the visible part alone.

One pipeline: a :class:`TrajectoryProblem` is prepared once (the retained pairs and their geometry,
:mod:`pivotd.pivot.pairs`); each :class:`Seed` (a starting plan, from :mod:`pivotd.pivot.seeds` or the caller)
is solved with the same options (:meth:`TrajectoryProblem.solve`: gradient ascent, the step limit, the
step-limited polish), and one judge, the objective, picks the plan (:func:`best_of`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, replace
from enum import Enum

import numpy as np

from pivotd.geometry import optical_frame_from_direction
from pivotd.pivot import _ascent, polish
from pivotd.pivot._checks import feature_weights, finite_array, half_angle, unit_vector
from pivotd.pivot.cone_kernel import cone_kernel
from pivotd.pivot.constraints import PanTiltConstraint
from pivotd.pivot.normalise import Normalisation, attainable_weights
from pivotd.pivot.pairs import dense_geometry, gather_pairs, landmark_weights, path_directions, ragged_geometry
from pivotd.pivot.pairs import spatial_order as spatial_order
from pivotd.pivot.smoothness import pair_value, path_value
from pivotd.pivot.steps import limit_steps, step_angles
from pivotd.pivot.view import ViewOptions, optimize_view

__all__ = ["Seed", "SeedKind", "TrajectoryOptions", "TrajectoryProblem", "TrajectoryResult", "best_of",
           "optimize_trajectory", "path_directions", "spatial_order", "trajectory_problem"]


@dataclass(kw_only=True)
class TrajectoryOptions:
    """Tuning of the trajectory optimizer (angles in degrees), keyword fields only.

    The fields a config key sets (marked ``key:``) have no default: the daemon takes them from its config
    (pivotd.daemon.wiring.trajectory_options), the paper's values are :meth:`paper`. The others are the optimizer's
    own tuning, which no config key sets: their defaults are the only ones, the same for the daemon and the paper
    (docs/design/optimizer.md, "One set of defaults")."""

    width_deg: float  # key: pivot.transition_width_deg. Sigmoid transition width at α (k_s from ks_from_width)
    max_iterations: int  # key: pivot.iterations. Iteration budget of a cold seed (:class:`SeedKind`)
    warm_iterations: int = 20  # iteration budget of a warm seed (the daemon: at most pivot.iterations)
    warm_step_init_deg: float = 1.0  # first step bound of a warm or point seed (a grid seed: half its resolution)
    step_max_deg: float = 20.0
    tol_deg: float = 0.1
    distance_weights: bool  # key: pivot.distance_weights. Eq. 15 distance weights s_ij
    active_cap: int = 128  # landmarks per node waypoint (strided subsample) scoring the chain seed's grid
    final_cap: int = 256  # landmarks per waypoint near the cone boundary in the ascent's active set
    drift_deg: float = 12.0  # grid seed: rebuild a waypoint's active set after its axis moved this far
    warm_drift_deg: float = 5.0  # warm and point seeds: the same (tighter: warm bands are crowded, thinning hurts)
    settle_frac: float = 0.03  # stop once at most 3 % of the waypoints still move by ≥ tol per step
    smooth_scale: float = 25.0  # κ: the smoothness term is λκ Σ c_{i+1}·c_i against per-waypoint visible fractions
    smooth_knee_deg: float  # key: pivot.smooth_knee_deg. > 0: a step beyond about this angle costs in proportion
    # to its size, not its square (pseudo-Huber of the chord, pivotd.pivot.smoothness); 0: 1 − cos per step
    chain_resolution_deg: float = 12.0  # the chain seed's direction grid (pivotd.pivot.chain)
    chain_nodes: int = 64
    polish_tol_deg: float = 0.25  # step-limited polish (pivotd.pivot.polish): smallest ring radius
    polish_cap: int = 2048  # ... landmarks per waypoint in its band (strided beyond)
    step_polish_deg: float = 4.0  # ... largest ring radius, applied to cold seeds (0: off)
    seed_cap: int = 512  # landmarks per (node) waypoint scoring the grids of the step-limited seed (0: no such
    # seed) and of the joint-grid seed (pivotd.daemon.planner)
    normalise: Normalisation  # key: planner.normalise. W_i: total retained weight, or the attainable one
    fixed_nodes: int = 16  # a plan staying within α of one direction: the best single direction for this many
    # node waypoints is a seed (0: off)
    fixed_cap: int = 8192  # ... scored on at most this many strided landmarks per node waypoint
    narrow_seed_nodes: int = 16  # α below ViewOptions.narrow_deg: a seed through this many node waypoints'
    # single-view optima (optimize_view) (0: off)

    @classmethod
    def paper(cls, **changes) -> TrajectoryOptions:
        """The paper's settings (§IV-B): a 3° transition width, 60 iterations, the distance weights of eq. 15, the
        paper's 1 − cos per step (no knee), W_i the total retained weight; ``changes``: fields set otherwise.
        What :func:`optimize_trajectory` uses without options, and ``pivotd plan`` without ``--config`` (there
        without distance weights: its plans are judged by hard counts; the knee of ``--smooth-knee-deg``)."""
        paper = cls(width_deg=3.0, max_iterations=60, distance_weights=True, smooth_knee_deg=0.0,
                    normalise=Normalisation.TOTAL)
        return replace(paper, **changes)


class SeedKind(Enum):
    """How a seed is solved: its iteration budget, first step and active-set drift, and whether it is polished."""

    WARM = "warm"  # a plan to continue (the previous plan, the commanded direction): warm budget, no polish
    GRID = "grid"  # a start on a coarse grid of directions (chain DP, step-limited DP): cold budget, big first
    # step (half the grid's resolution), polished
    POINT = "point"  # a start at precise optima (fixed direction, single-view optima, rescue): cold budget, small
    # first step, polished
    LIMITED = "limited"  # the exact optimum within a hard step limit on a grid: polished within the limit only (an
    # ascent's smoothness term would trade visible landmarks for a smoothness the limit already gives)


@dataclass(frozen=True)
class Seed:
    """A starting plan: ``directions`` (N, 3) (any length, not zero), how it is solved (``kind``) and its name
    (reported with the plan: warm, anchor, chain, fixed, narrow, step_limited, rescue, ...)."""

    name: str
    directions: np.ndarray
    kind: SeedKind


@dataclass
class TrajectoryResult:
    """directions (N, 3) unit; rotations (N, 3, 3) with rotations[i] @ e3 == directions[i];
    visible (N,) int hard counts (angle ≤ α); iterations: gradient steps (of every seed solved); objective: the
    trajectory objective (module docstring) at α; seed: the name of the seed the plan came from."""

    directions: np.ndarray
    rotations: np.ndarray
    visible: np.ndarray
    iterations: int
    objective: float
    seed: str = ""


@dataclass
class TrajectoryProblem:
    """A prepared trajectory problem (build with :func:`trajectory_problem`): everything a solve needs.

    T (N, 3) waypoints [m]; geom: the retained pairs' geometry (None: nothing retained anywhere); norm (N,) W_i;
    lengths (N,) retained landmarks per waypoint; smooth = λκ; knee [rad]; width [rad]; anchor (3,) or None;
    ``views(i)`` waypoint i's landmarks (n, 3) [m] and weights (n,); independent: λ = 0 (or one waypoint without
    an anchor) without limits, where every waypoint is its own single-pose problem."""

    alpha: float
    lam: float
    opts: TrajectoryOptions
    T: np.ndarray
    geom: _ascent.Geometry | None
    norm: np.ndarray
    lengths: np.ndarray
    anchor: np.ndarray | None
    constraint: PanTiltConstraint | None
    max_step: float | None
    views: Callable[[int], tuple[np.ndarray, np.ndarray]]
    independent: bool
    chain_smooth_ratio: float = 1.0

    @property
    def n(self) -> int:
        return int(self.T.shape[0])

    @property
    def smooth(self) -> float:
        """λκ: the smoothness weight against per-waypoint visible fractions."""
        return self.lam * self.opts.smooth_scale

    @property
    def knee(self) -> float:
        return math.radians(self.opts.smooth_knee_deg)

    @property
    def width(self) -> float:
        return math.radians(self.opts.width_deg)

    def judge(self, C: np.ndarray) -> tuple[np.ndarray, float]:
        """Hard visible counts (N,) int and the objective (module docstring) of unit axes C (N, 3)."""
        smooth = 0.0 if self.max_step is not None else self.smooth
        return _judge(self.geom, C, self.norm, self.alpha, self.width, smooth, self.anchor, self.knee)

    def visible_share(self, C: np.ndarray) -> float:
        """Σ_i V_i(c_i) / W_i: the hard visible weight of each waypoint's landmarks over its norm, for unit axes
        C (N, 3) (0 without landmarks)."""
        if self.geom is None:
            return 0.0
        inside = self.geom.cos_all(C) >= np.float32(math.cos(self.alpha))
        if self.geom.valid is not None:
            inside &= self.geom.valid
        V = np.sum(inside * self.geom.weight_rows(), axis=1, dtype=np.float64)
        return float(np.sum(V / np.maximum(self.norm, 1e-12)))

    def project(self, C: np.ndarray) -> np.ndarray:
        """C (N, 3) made unit and reachable (joint limits), then within the step limit."""
        C = np.asarray(C, float)
        n0 = np.linalg.norm(C, axis=1)
        if C.shape != (self.n, 3) or not np.isfinite(C).all() or np.any(n0 < 1e-12):
            raise ValueError(f"a seed must have shape ({self.n}, 3) with finite non-zero rows, got {C.shape}")
        C = C / n0[:, None]
        if self.constraint is not None:
            C = self.constraint.project(C)
        return C

    def evaluate(self, seed: Seed) -> TrajectoryResult:
        """The plan ``seed`` as it is (made unit and reachable, no ascent), judged: a candidate that costs no solve
        (0 iterations)."""
        C = self.project(seed.directions)
        if self.max_step is not None:
            C = limit_steps(C, self.max_step, anchor=self.anchor, constraint=self.constraint)
        visible, obj = self.judge(C)
        return TrajectoryResult(C, optical_frame_from_direction(C), visible, 0, obj, seed.name)

    def solve(self, seed: Seed) -> TrajectoryResult:
        """The plan from ``seed``: gradient ascent (:func:`pivotd.pivot._ascent.ascend`) with the budget of the
        seed's kind, the step limit, the step-limited polish of cold seeds, then the judge."""
        opts, rad = self.opts, math.radians
        C0 = self.project(seed.directions)
        if self.independent:  # every waypoint its own single-pose problem; the seed joins its multi-start set
            r = _independent_views(self.views, self.T, self.alpha, C0, opts.distance_weights)
            return TrajectoryResult(r.directions, r.rotations, r.visible, r.iterations, r.objective, seed.name)
        R0 = optical_frame_from_direction(C0)
        iters = 0
        if self.geom is None:
            C = C0
        elif seed.kind is SeedKind.LIMITED:
            C = self._polish(C0)
        else:
            warm, grid = seed.kind is SeedKind.WARM, seed.kind is SeedKind.GRID
            settings = _ascent.AscentSettings(
                alpha=self.alpha,
                width=self.width,
                iterations=opts.warm_iterations if warm else opts.max_iterations,
                step_init=rad(opts.chain_resolution_deg) / 2 if grid else rad(opts.warm_step_init_deg),
                step_max=rad(opts.step_max_deg),
                tol=rad(opts.tol_deg),
                cap=opts.final_cap,
                drift=rad(opts.drift_deg if grid else opts.warm_drift_deg),
                settle_frac=opts.settle_frac,
            )
            project = None if self.constraint is None else self.constraint.project
            R0, iters = _ascent.ascend(self.geom, R0, self.norm, settings, lam=self.smooth, anchor=self.anchor,
                                       project=project, knee=self.knee)
            C = R0[:, :, 2].copy()
            if not warm:
                C = self._polish(C)
        if self.max_step is not None:  # the guarantee
            C = limit_steps(C, self.max_step, anchor=self.anchor, constraint=self.constraint)
        R = _ascent._turn_to(R0, C)
        C = R[:, :, 2].copy()
        visible, obj = self.judge(C)
        return TrajectoryResult(C, R, visible, iters, obj, seed.name)

    def _polish(self, C: np.ndarray) -> np.ndarray:
        """The step-limited polish of the visible weight at the plan's step limit (its own largest step when
        there is none: the polish keeps the λ trade-off, Φ_hard within the step)."""
        opts, a = self.opts, self.anchor
        if self.max_step is not None:
            C = limit_steps(C, self.max_step, anchor=a, constraint=self.constraint)
            limit, keep_smooth = self.max_step, 0.0
        else:
            limit = float(step_angles(C, a).max(initial=0.0)) if (self.n > 1 or a is not None) else None
            keep_smooth = self.smooth
        if opts.step_polish_deg <= 0 or limit is None or limit <= 0:
            return C
        return _step_polish(self.geom, C, self.alpha, limit, a, self.constraint, opts, keep_smooth, self.norm)


def best_of(results: Iterable[TrajectoryResult]) -> TrajectoryResult:
    """The result with the highest objective (the first of equals), its iterations the sum over all."""
    best, total = None, 0
    for r in results:
        total += r.iterations
        if best is None or r.objective > best.objective:
            best = r
    if best is None:
        raise ValueError("no result to choose from")
    return TrajectoryResult(best.directions, best.rotations, best.visible, total, best.objective, best.seed)


def trajectory_problem(
    points: np.ndarray,
    waypoints: np.ndarray,
    alpha: float,
    lam: float,
    *,
    weights: np.ndarray | None = None,
    retained: Sequence[np.ndarray] | None = None,
    anchor: np.ndarray | None = None,
    constraint: PanTiltConstraint | None = None,
    max_step: float | None = None,
    options: TrajectoryOptions | None = None,
) -> TrajectoryProblem:
    """Prepare the problem of :func:`optimize_trajectory` (same arguments, without the seeds; ``options`` None:
    :meth:`TrajectoryOptions.paper`); raises ValueError on NaN/inf or bad shapes. Only the retained rows of
    ``points`` are read."""
    opts = options or TrajectoryOptions.paper()
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
        P = finite_array("points", points)
        fw = feature_weights(weights, P.shape[0])
        if P.shape[0] > 1:  # every landmark is used: lay them out along a space-filling curve (spatial_order)
            order = spatial_order(P, [np.arange(P.shape[0])])[0]
            P, fw = P[order], fw[order]
        pairs = None
    else:
        pairs = gather_pairs(points, weights, retained, N)
    if constraint is not None and len(constraint) != N:
        raise ValueError(f"constraint has {len(constraint)} waypoints, the path has {N}")
    a_vec = None if anchor is None else unit_vector("anchor", anchor)
    views = (lambda i: (P, fw)) if pairs is None else pairs.waypoint
    independent = (lam == 0.0 or (N == 1 and a_vec is None)) and constraint is None and max_step is None
    lengths = np.full(N, P.shape[0]) if pairs is None else pairs.lengths
    if independent or not lengths.any():
        geom, norm = None, np.zeros(N)
    elif pairs is None:
        geom, norm = dense_geometry(P, T, fw, opts.distance_weights)
    else:
        geom, norm = ragged_geometry(pairs, T, opts.distance_weights)
    ratio = 1.0
    if normalise is Normalisation.ATTAINABLE and geom is not None:
        total, norm = norm, attainable_weights(geom, alpha)
        has = total > 0  # the chain scores fractions of the total: scale its smoothness by the typical A_i / W_i
        ratio = float(np.median(norm[has] / total[has])) if has.any() else 1.0
    return TrajectoryProblem(alpha, lam, opts, T, geom, norm, lengths, a_vec, constraint, max_step, views,
                             independent, ratio)


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
) -> TrajectoryResult:
    """Optimise viewing directions for landmarks ``points`` (M, 3) [m] along ``waypoints`` (N, 3) [m].

    α: FoV half-angle [rad]; λ ≥ 0: smoothness weight; ``weights`` (M,) feature weights (None: 1);
    ``retained``: per-waypoint index arrays into ``points`` (None: every landmark everywhere) — only
    those landmarks are read, so the cost does not depend on the map's size; ``init_directions``
    (N, 3): one warm seed — None solves the cold seeds (:func:`pivotd.pivot.seeds.cold_seeds`, then the seeds
    derived from their best plan) and keeps the highest objective; ``anchor`` (3,): a fixed direction just
    before waypoint 0 (adds λκ v(anchor·c_0)); ``constraint``: pan/tilt limits enforced at every step;
    ``max_step`` [rad]: a hard limit on the angle between consecutive directions (and from the anchor),
    guaranteed (pivotd.pivot.steps).
    λ = 0 (or a single waypoint without ``anchor``) without ``constraint`` and ``max_step`` solves each
    waypoint with :func:`pivotd.pivot.view.optimize_view`. Landmarks coinciding with a waypoint are ignored there.
    Raises ValueError on NaN/inf or bad shapes.
    """
    from pivotd.pivot import seeds as seeds_m

    problem = trajectory_problem(points, waypoints, alpha, lam, weights=weights, retained=retained, anchor=anchor,
                                 constraint=constraint, max_step=max_step, options=options)
    warm = None
    if init_directions is not None:
        warm = finite_array("init_directions", init_directions)
        if warm.shape[0] != problem.n:
            raise ValueError(f"init_directions must have shape ({problem.n}, 3), got {warm.shape}")
        n0 = np.linalg.norm(warm, axis=1)
        if np.any(n0 < 1e-12):
            raise ValueError(f"init_directions row {int(np.argmin(n0))} is zero")
    if problem.independent:
        return _independent_views(problem.views, problem.T, problem.alpha,
                                  None if warm is None else warm / n0[:, None], problem.opts.distance_weights)
    if warm is not None:
        return problem.solve(Seed("warm", warm, SeedKind.WARM))
    result = best_of(problem.solve(s) for s in seeds_m.cold_seeds(problem))
    derived = seeds_m.derived_seeds(problem, result)
    if derived:
        result = best_of([result, *(problem.solve(s) for s in derived)])
    return result


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
            w = np.maximum(landmark_weights(n[None].astype(np.float32), None, w[None], True)[0].astype(float), 0.0)
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
