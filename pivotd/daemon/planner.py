"""Receding-horizon PIVOT on a translation path.

At waypoint rate the planner locates the robot's progress along the path (monotone, robust to the
robot being off the path), resamples the path ahead every ``spacing`` metres for ``horizon``
waypoints, predicts the body attitude at each waypoint, takes the retained landmarks there from
the map, and runs the trajectory optimizer warm-started from the previous plan and anchored to the
direction currently being commanded. Reachability (joint limits given the predicted attitude) is a
constraint inside the optimisation. The result is an immutable :class:`Plan` that the control
loop samples at its own rate.

Pure computation: no threads and no I/O here; the daemon owns the threads.
"""

from __future__ import annotations

import math
import time
from collections.abc import Sequence
from dataclasses import dataclass, field, replace
from enum import Enum

import numpy as np

from pivotd.config.settings import MAX_MARKER_LANDMARKS, MotionConfig, PivotConfig, PlannerConfig
from pivotd.daemon.pose_gate import turn_angle
from pivotd.geometry import (
    direction_to_pan_tilt,
    normalize,
    pan_tilt_to_direction,
    quat_angles,
    quat_slerp,
    quat_to_matrix,
    slerp,
)
from pivotd.gimbal.kinematics import (
    JointLimits,
    Mount,
    base_from_world,
    world_direction_to_joints,
)
from pivotd.gimbal.pan_unwrap import (
    base_pan_tilt,
    unwrap_pans,
)
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.store import MapSnapshot
from pivotd.pivot.cone_kernel import ConeKernel, cone_kernel
from pivotd.pivot.constraints import PanTiltConstraint
from pivotd.pivot.joint_dp import JointGrid, best_joint_path, cell_counts
from pivotd.pivot.normalise import attainable_counts
from pivotd.pivot.rescue import blind_waypoints, rescue_init
from pivotd.pivot.seeds import cold_seeds, derived_seeds
from pivotd.pivot.trajectory import (
    Seed,
    SeedKind,
    TrajectoryOptions,
    TrajectoryProblem,
    TrajectoryResult,
    best_of,
    trajectory_problem,
)
from pivotd.pivot.view import ViewOptions, optimize_view
from pivotd.pivot.visibility import hard_count, in_cone
from pivotd.robot_path import Polyline, project_onto_polyline

_PIVOT, _PLANNER, _MOTION = PivotConfig(), PlannerConfig(), MotionConfig()


def trajectory_options_from(pivot: PivotConfig, planner: PlannerConfig) -> TrajectoryOptions:
    """The optimizer's options from the ``pivot`` and ``planner`` config sections: every field a config key sets
    (those have no default in :class:`TrajectoryOptions`); the others keep the optimizer's own tuning, which no key
    sets. Warm-started replans iterate at most min(``pivot.iterations``, the optimizer's warm budget)."""
    return TrajectoryOptions(width_deg=math.degrees(pivot.transition_width), max_iterations=pivot.iterations,
                             warm_iterations=min(pivot.iterations, TrajectoryOptions.warm_iterations),
                             distance_weights=pivot.distance_weights, normalise=planner.normalise,
                             smooth_knee_deg=math.degrees(pivot.smooth_knee))

#: Most landmarks a plan reports as inside its first cone (:attr:`Plan.in_view`, shown as live markers).
MAX_IN_VIEW = MAX_MARKER_LANDMARKS


class PathMode(Enum):
    """What a plan was made for: the path ahead, or the robot's pose alone (no path, or too far from it)."""

    ON_PATH = "on_path"  # the horizon along the path, from the robot's progress
    OFF_PATH = "off_path"  # a path, but the robot is farther than max_path_offset from it: its pose alone
    NO_PATH = "no_path"  # no path: the robot's pose alone


class Rescue(Enum):
    """What the rescue of blind warm starts did in a replan (see :meth:`RecedingHorizonPlanner._rescue`)."""

    NOT_TRIED = "not_tried"  # nothing blind, rescue off, a cold start, or a start that lost before on this problem
    LOST = "lost"  # a second solve from the rescue's start did not reach the higher objective
    KEPT = "kept"  # the plan is the rescue's


def directions_at_s(s_grid: np.ndarray, directions: np.ndarray, s: np.ndarray) -> np.ndarray:
    """Unit directions (K, 3) at arc lengths ``s`` (K,) [m] of ``directions`` (N, 3) given at ``s_grid`` (N,)
    (ascending): slerp between neighbours, the end directions held beyond the ends."""
    if s_grid.shape[0] == 1:
        return np.repeat(directions, s.shape[0], axis=0)
    i, t = _segments(s_grid, s)
    return slerp(directions[i], directions[i + 1], t)


def _segments(s_grid: np.ndarray, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For arc lengths ``s`` (K,) [m] on the waypoints ``s_grid`` (N,) (ascending, N ≥ 2): the waypoint each
    segment starts at (K,) int and the fraction of it covered (K,), ``s`` clamped to the grid's ends."""
    sc = np.clip(s, s_grid[0], s_grid[-1])
    i = np.clip(np.searchsorted(s_grid, sc, side="right") - 1, 0, s_grid.shape[0] - 2)
    return i, (sc - s_grid[i]) / np.maximum(s_grid[i + 1] - s_grid[i], 1e-12)


def joint_directions_at_s(s_grid: np.ndarray, pans: np.ndarray, tilts: np.ndarray, base_frames: np.ndarray,
                          s: np.ndarray) -> np.ndarray:
    """Unit world directions (K, 3) at arc lengths ``s`` (K,) [m] of a plan whose waypoints at ``s_grid`` (N,)
    (ascending, N ≥ 2) have joints ``pans``, ``tilts`` (N,) [rad] in the gimbal base frames ``base_frames``
    (N, 3, 3) (world → base): the joints interpolated linearly, as the gimbal moves between them, each in the
    two neighbouring waypoints' base frames and those directions slerped; the ends held beyond the ends.

    Between waypoints far apart on the sphere this is the gimbal's sweep, not the great circle (which can dive
    through the floor or the unreachable sector of a bounded pan); between close ones the two agree."""
    i, t = _segments(s_grid, s)
    d = pan_tilt_to_direction(pans[i] + t * (pans[i + 1] - pans[i]), tilts[i] + t * (tilts[i + 1] - tilts[i]))
    a = np.einsum("kji,kj->ki", base_frames[i], d)
    b = np.einsum("kji,kj->ki", base_frames[i + 1], d)
    return slerp(a, b, t)


@dataclass(frozen=True)
class Plan:
    """An immutable view plan over a horizon.

    s: (N,) arc length of each waypoint along the path [m] (zeros for a single-pose plan);
    positions: (N, 3) camera centres [m]; directions: (N, 3) world unit viewing directions;
    body_quats: (N, 4) predicted body attitude (x, y, z, w); visible: (N,) hard counts;
    pans: (N,) joint pan [rad] chosen for each waypoint over the whole horizon (None: the control loop
    picks the branch nearest its previous pan); tilts: (N,) joint tilt [rad] of each waypoint and base_frames:
    (N, 3, 3) world → gimbal base rotations (both None: directions between waypoints are slerped, else the
    joints are interpolated, :func:`joint_directions_at_s`); rescue: what the rescue of a blind warm start did.
    """

    created: float
    positions: np.ndarray
    directions: np.ndarray
    body_quats: np.ndarray
    visible: np.ndarray
    s: np.ndarray
    map_version: int
    path_version: int
    solve_s: float
    landmarks: int = 0
    in_view: np.ndarray = field(default_factory=lambda: np.zeros((0, 3)))  # (K, 3) landmarks in the first cone
    pans: np.ndarray | None = None
    rescue: Rescue = Rescue.NOT_TRIED
    degrade: int = 0  # halvings of the horizon and landmark cap this plan was made with (see PlannerSettings)
    path_mode: PathMode = PathMode.NO_PATH
    path_offset: float | None = None  # [m] the robot's distance from the path (None without one)
    seed: str = ""  # the seed the plan came from (pivotd.pivot.trajectory.Seed: warm, anchor, chain, ...)
    tilts: np.ndarray | None = None
    base_frames: np.ndarray | None = None


    def direction_at_s(self, s: np.ndarray | float) -> np.ndarray:
        """Viewing directions (K, 3) (or (3,)) at arc lengths ``s``: the joints interpolated where the plan has
        them (:func:`joint_directions_at_s`), else the directions slerped."""
        scalar = np.ndim(s) == 0
        sv = np.atleast_1d(np.asarray(s, float))
        if self.pans is not None and self.tilts is not None and self.base_frames is not None and self.s.shape[0] > 1:
            out = joint_directions_at_s(self.s, self.pans, self.tilts, self.base_frames, sv)
        else:
            out = directions_at_s(self.s, self.directions, sv)
        return out[0] if scalar else out

    def body_turn(self, s0: float, s1: float) -> np.ndarray:
        """The rotation (3, 3) (world frame) the predicted body attitude makes from arc length ``s0`` to ``s1`` [m]
        (each slerped between its neighbouring waypoints, held beyond the ends); the identity for a single pose."""
        if self.s.shape[0] < 2:
            return np.eye(3)
        i, t = _segments(self.s, np.array([s0, s1], float))
        q = self.body_quats
        r0, r1 = quat_to_matrix(np.array([quat_slerp(q[k], q[k + 1], np.array([f]))[0]
                                          for k, f in zip(i, t, strict=True)]))
        return r1 @ r0.T

    def locate(self, position: np.ndarray, window: tuple[float, float] | None = None) -> tuple[float, float]:
        """Arc length [m] of the point of the plan's camera polyline nearest to ``position`` (3,) [m], and its
        distance [m]; with ``window`` = (lo, hi) [m] only the stretch of the plan overlapping that arc range."""
        return project_onto_polyline(self.positions, self.s, position, window)


@dataclass(frozen=True)
class PlannerSettings:
    """fov: full cone opening [rad]; lam: smoothness weight λ; spacing [m]; horizon: waypoints;
    max_step: hard limit on the turn between consecutive planned directions, from the commanded one
    on [rad] (None: no limit); max_path_offset [m]: progress advances only with the robot this close to the
    path, and by at most the robot's displacement since the last replan plus this distance; replan_budget [s]:
    a replan slower than this halves the next one's horizon and landmarks per waypoint (at most MAX_DEGRADE
    times), one under a quarter of it undoes a halving (None: never).

    The defaults are the config's (:class:`~pivotd.config.settings.PivotConfig`, ``PlannerConfig``,
    ``MotionConfig``; the daemon passes every one of them from its config, pivotd.daemon.wiring.planner_settings);
    those no config key sets are marked."""

    fov: float = _PIVOT.fov
    lam: float = _PIVOT.lam
    spacing: float = _PLANNER.waypoint_spacing
    horizon: int = _PLANNER.horizon
    max_landmarks_per_waypoint: int | None = _PLANNER.max_landmarks_per_waypoint
    retained_filter: RetainedFilter = field(default_factory=RetainedFilter)
    options: TrajectoryOptions = field(default_factory=lambda: trajectory_options_from(_PIVOT, _PLANNER))
    back_window: float = 1.0  # [m] no key: the stretch of the path searched behind the last progress ...
    ahead_window: float = 5.0  # [m] ... and ahead of it
    max_step: float | None = _PLANNER.max_step
    max_path_offset: float = _PLANNER.max_path_offset
    rescue_fraction: float | None = _PLANNER.rescue_fraction if _PLANNER.rescue_blind else None  # blind warm
    # starts (None: off): see RecedingHorizonPlanner._rescue
    rescue_reach: int = 2  # no key: waypoints on either side of a blind run turned towards it in the rescue's start
    replan_budget: float | None = _PLANNER.replan_budget  # [s] a slower replan halves the next one's horizon and cap
    axis_speeds: tuple[float, float] | None = (_MOTION.pan.max_velocity, _MOTION.tilt.max_velocity)  # [rad/s] pan
    # and tilt speed limits: the joint-grid seed (None: no such seed) and the judge of plans as executed
    joint_grid_step: float = math.radians(4.0)  # [rad] no key: the joint grid's largest spacing
    replan_period: float = 1.0 / _PLANNER.replan_hz  # [s] the time between replans: how far the gimbal can turn
    # towards a plan's first waypoint before the next plan replaces it (the judge of plans as executed)
    nominal_speed: float = 1.0  # [m/s] no key: the robot's speed assumed until it has been measured
    nominal_turn_rate: float = math.radians(90.0)  # [rad/s] no key: the robot's turn rate assumed until it has turned

    #: Most halvings of the horizon and of the landmarks per waypoint after late replans.
    MAX_DEGRADE = 3

    @property
    def alpha(self) -> float:
        """The paper's half-angle α [rad]."""
        return 0.5 * self.fov


def _cap_retained(retained: Sequence[np.ndarray], cap: int | None) -> list[np.ndarray]:
    """Evenly subsample any waypoint's retained set larger than ``cap`` (deterministic).

    Keeps the elements at np.linspace(0, n - 1, cap).astype(int64), computed as k · (n − 1)/(cap − 1)
    from one shared ramp (the same floating-point operations as linspace, without its per-call cost).
    """
    if not cap:
        return list(retained)
    ramp = np.arange(cap, dtype=float)
    out = []
    for idx in retained:
        n = idx.shape[0]
        if n > cap:
            pos = ramp * ((n - 1) / (cap - 1)) if cap > 1 else np.zeros(1)
            pos[-1] = n - 1 if cap > 1 else 0
            idx = idx.take(pos.astype(np.int64))
        out.append(idx)
    return out


def _grid_keys(s: np.ndarray) -> list[int]:
    """Cache keys of waypoints at arc lengths ``s`` (N,) [m] along the path: micrometres, rounded."""
    return [round(float(x) * 1e6) for x in s]


def _scatter(directions: np.ndarray, rows: np.ndarray, values: np.ndarray) -> np.ndarray:
    """A copy of ``directions`` (N, 3) with ``rows`` (B,) set to ``values`` (B, 3)."""
    out = directions.copy()
    out[rows] = values
    return out


#: [rad/s] a turn slower than this between two replans is not a measurement of the turn rate.
TURNING = math.radians(5.0)


def camera_positions(body_positions: np.ndarray, body_quats: np.ndarray, mount: Mount) -> np.ndarray:
    """Sensor centres (N, 3) in the world for body positions (N, 3) and attitudes (N, 4)."""
    return body_positions + np.einsum("nij,j->ni", quat_to_matrix(body_quats), np.asarray(mount.translation, float))


class _Execution:
    """A replan's plans as the gimbal can follow them, and the judge that compares them.

    A plan's joint pans are chosen along it from the commanded pan (:func:`pivotd.gimbal.pan_unwrap.unwrap_pans`:
    the least total slew inside the limits) and each move between waypoints is clamped to the axis speeds over the
    time the robot takes between them; the directions of that rate-limited joint path are judged by the objective.
    A plan within the speeds is its own execution; one that must slew the long way round a bounded pan range is
    judged by what the slew sees. Without axis speeds the plans are judged as they are."""

    def __init__(self, planner: RecedingHorizonPlanner, s: np.ndarray, quats: np.ndarray,
                 anchor: np.ndarray | None) -> None:
        st = planner.settings
        self._planner, self._quats = planner, quats
        self.frames = base_from_world(quats, planner.mount)  # (N, 3, 3) world → gimbal base, also the plan's
        self._on = st.axis_speeds is not None and s.shape[0] > 1
        if st.axis_speeds is None:
            return
        self.steps = planner._step_limits(s, quats)  # (N − 1,) pan and tilt moves [rad], also the joint-grid seed's
        self.start = planner._commanded_joints(anchor, quats[0])  # (pan, tilt) [rad] commanded, or None
        if not self._on:
            return
        self._dpan, self._dtilt = self.steps
        self._dpan_l, self._dtilt_l = self._dpan.tolist(), self._dtilt.tolist()
        self._reach = planner._first_reach()  # (pan, tilt) [rad] the gimbal turns towards the first waypoint
        self._memo: dict[bytes, np.ndarray] = {}  # executed directions by the plan's bytes

    def directions(self, directions: np.ndarray) -> np.ndarray:
        """The directions (N, 3) of the rate-limited joint path following ``directions`` (N, 3) (each plan's
        computed once per replan)."""
        if not self._on:
            return directions
        key = np.asarray(directions, float).tobytes()
        out = self._memo.get(key)
        if out is None:
            out = self._memo[key] = self._follow(directions)
        return out

    def _base_pan_tilt(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Pan and tilt (N,) [rad] of ``directions`` (N, 3) in the waypoints' base frames (base_pan_tilt's)."""
        return direction_to_pan_tilt(np.einsum("nij,nj->ni", self.frames, np.asarray(directions, float).reshape(-1, 3)))

    def _joints(self, directions: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Joint pans and tilts (N,) [rad] of ``directions`` (N, 3) as the plan's own (:meth:`RecedingHorizonPlanner.
        _plan_joints`): the pans unwrapped from the commanded pan inside the limits, the tilts clamped."""
        pl = self._planner
        pans, tilts = self._base_pan_tilt(directions)
        pans, _ = unwrap_pans(pans, self._pan_start(directions, None if self.start is None else self.start[0]),
                              pl.limits)
        return pans, np.clip(tilts, pl.limits.tilt_min, pl.limits.tilt_max)

    def _follow(self, directions: np.ndarray) -> np.ndarray:
        pan0, tilt0 = (None, None) if self.start is None else self.start
        pans, tilts = self._joints(directions)
        pan_l, tilt_l = pans.tolist(), tilts.tolist()
        if pan0 is None:
            p, t = pan_l[0], tilt_l[0]
        else:  # from the commanded joints, as far towards the first waypoint as the gimbal turns before the next plan
            p = pan0 + min(max(pan_l[0] - pan0, -self._reach[0]), self._reach[0])
            t = tilt0 + min(max(tilt_l[0] - tilt0, -self._reach[1]), self._reach[1])
        out_p, out_t = [p], [t]
        for k, (dp, dt) in enumerate(zip(self._dpan_l, self._dtilt_l, strict=True), start=1):
            p += min(max(pan_l[k] - p, -dp), dp)
            t += min(max(tilt_l[k] - t, -dt), dt)
            out_p.append(p)
            out_t.append(t)
        d_base = pan_tilt_to_direction(np.array(out_p), np.array(out_t))
        return np.einsum("nji,nj->ni", self.frames, d_base)

    def held_at_limits(self, directions: np.ndarray) -> np.ndarray | None:
        """``directions`` (N, 3) with their pans followed continuously from the commanded pan (each step the
        shorter way round) and held at the end of a bounded range they run past, where the joints would otherwise
        slew the long way round to the other end; None when that changes nothing (no such step, continuous pan,
        or no commanded pan)."""
        pl = self._planner
        if not self._on or self.start is None or pl.limits.continuous_pan:
            return None
        pans, tilts = self._base_pan_tilt(directions)
        steps = np.remainder(np.diff(np.concatenate([[self.start[0]], pans])) + np.pi, 2 * np.pi) - np.pi
        held = np.clip(self.start[0] + np.cumsum(steps), pl.limits.pan_min, pl.limits.pan_max)
        joint, _ = unwrap_pans(pans, self.start[0], pl.limits)
        if np.allclose(held, joint, atol=1e-9, rtol=0.0):
            return None
        d_base = pan_tilt_to_direction(held, np.clip(tilts, pl.limits.tilt_min, pl.limits.tilt_max))
        return np.einsum("nji,nj->ni", self.frames, d_base)

    def anticipated(self, directions: np.ndarray) -> np.ndarray | None:
        """``directions`` (N, 3) with each joint move between waypoints brought within the axis speeds by starting it
        early: from the last waypoint back, each waypoint's pan and tilt are moved towards the next one's until the
        step fits (the joints as :meth:`directions` takes them). A plan that jumps between two waypoints farther
        apart than the gimbal can turn is followed late (the slew starts at the jump); this one arrives on time at the
        cost of the views before it. None when every step already fits (or without axis speeds)."""
        if not self._on:
            return None
        pans, tilts = self._joints(directions)
        if (np.all(np.abs(np.diff(pans)) <= self._dpan + 1e-12)
                and np.all(np.abs(np.diff(tilts)) <= self._dtilt + 1e-12)):
            return None
        pan_l, tilt_l = pans.tolist(), tilts.tolist()
        for k in range(len(pan_l) - 2, -1, -1):
            dp, dt = self._dpan_l[k], self._dtilt_l[k]
            pan_l[k] = min(max(pan_l[k], pan_l[k + 1] - dp), pan_l[k + 1] + dp)
            tilt_l[k] = min(max(tilt_l[k], tilt_l[k + 1] - dt), tilt_l[k + 1] + dt)
        d_base = pan_tilt_to_direction(np.array(pan_l), np.array(tilt_l))
        return np.einsum("nji,nj->ni", self.frames, d_base)

    def objective(self, problem: TrajectoryProblem, result: TrajectoryResult) -> float:
        """The objective of ``result`` as executed (its own without axis speeds)."""
        if not self._on:
            return result.objective
        return problem.judge(self.directions(result.directions))[1]

    def pick(self, problem: TrajectoryProblem, results: list[TrajectoryResult]) -> int:
        """Index of the result with the highest objective as executed (the first of equals)."""
        if len(results) == 1:
            return 0
        return int(np.argmax([self.objective(problem, r) for r in results]))

    def best(self, problem: TrajectoryProblem, results: list[TrajectoryResult]) -> TrajectoryResult:
        """The result with the highest objective as executed (the first of equals); iterations summed."""
        if len(results) == 1 or not self._on:
            return best_of(results)
        r = results[self.pick(problem, results)]
        return TrajectoryResult(r.directions, r.rotations, r.visible, sum(x.iterations for x in results),
                                r.objective, r.seed)

    def _pan_start(self, directions: np.ndarray, pan0: float | None) -> float:
        """The pan a plan's joint sequence starts from: the commanded one, else the first waypoint's own."""
        if pan0 is not None:
            return pan0
        pl = self._planner
        pan, _ = base_pan_tilt(directions[:1], self._quats[:1], pl.mount)
        return float(np.clip(pan[0], pl.limits.pan_min, pl.limits.pan_max))


class RecedingHorizonPlanner:
    """Stateful receding-horizon planner (single-threaded: call :meth:`replan` from one thread)."""

    def __init__(self, settings: PlannerSettings, mount: Mount, limits: JointLimits) -> None:
        self.settings = settings
        self.mount = mount
        self.limits = limits
        self._tracker: Polyline | None = None
        self._path_version = -1
        self.progress: float | None = None
        self._located_at: np.ndarray | None = None  # body position of the last progress update [m]
        self._off_moved = 0.0  # [m] the robot's travel while off the path (the progress may catch up by as much)
        self.last_plan: Plan | None = None
        self._cache_key: tuple[int, int, int | None] | None = None
        self._cache: dict[int, np.ndarray] = {}
        self._attainable_cache: dict[int, float] = {}
        self._rejected: tuple[int, set[int]] = (0, set())  # horizon length, grid cells of blind waypoints tried
        self.solves = 0  # optimize_trajectory calls so far
        self.last_objective = math.nan  # the trajectory objective of the last replan's plan (before the unwinds)
        self.rescues = 0  # replans whose rescue candidate was kept
        self.degrade = 0  # halvings of horizon and landmark cap in force (late replans; see _adapt)
        self._joint_scores: dict[int, np.ndarray] = {}  # joint-grid cell shares (P, T) by grid key
        self._joint_keys: tuple[int, ...] = ()  # grid keys of the horizon when the joint-grid seed was last made
        self._queried = False  # whether this replan queried the map for a waypoint new to the horizon
        self._grid: JointGrid | None = None
        self._moved: tuple[float, np.ndarray, np.ndarray] | None = None  # (time [s], body position, attitude) of the
        # last replan
        self.speed: float | None = None  # [m/s] the robot's measured speed (smoothed over replans)
        self.cruise_speed: float | None = None  # [m/s] the fastest smoothed speed measured on this path
        self.turn_rate: float | None = None  # [rad/s] the fastest turn of the robot measured between two replans
        self.joint_solves = 0  # replans that solved the joint-grid seed (another basin than the plan's)
        self._deferred: tuple[int, np.ndarray, np.ndarray] | None = None  # (path version, s (N,), directions (N, 3))
        # of a joint-grid seed in another basin, to be solved by the next replan
        self._kernel: ConeKernel | None = None  # the rescue's single-view cone kernel (see _view_kernel)
        self._warm_from: tuple[Plan, Plan] | None = None  # (last plan, the same as solved) when its slew was started
        # early (RecedingHorizonPlanner.replan): the next warm start is the solved one

    def set_path(self, positions: np.ndarray | None, quats: np.ndarray | None, version: int) -> None:
        """Install a new translation path (None clears it); progress restarts from the nearest point."""
        if version == self._path_version:
            return
        self._path_version = version
        self._tracker = (None if positions is None or len(positions) == 0
                         else Polyline(positions, quats, ignore_constant_quats=True))
        self.progress = None
        self._located_at = None
        self._off_moved = 0.0
        self.cruise_speed = None

    def _advance(self, body_position: np.ndarray) -> tuple[float, float]:
        """The robot's progress along the path [m] and its distance from the path [m] near that progress.

        Progress never goes backwards, advances only while the robot is within ``max_path_offset`` of the
        path, and by at most its displacement since the last call plus that distance (a pose far from the
        path, or next to a later stretch of it, cannot push it ahead). While the robot is off the path its
        travel is added to the stretch searched ahead and to that bound, so it resumes the path where it
        comes back to it, however far along."""
        st = self.settings
        previous, located_at = self.progress, self._located_at
        slack = self._off_moved
        found, offset = self._tracker.locate(body_position, previous, st.back_window, st.ahead_window + slack)
        self._located_at = body_position.copy()
        if previous is None or located_at is None:
            return found, offset
        moved = float(np.linalg.norm(body_position - located_at))
        if offset > st.max_path_offset:
            self._off_moved += moved
            return previous, offset
        self._off_moved = 0.0
        return min(found, previous + moved + slack + st.max_path_offset), offset

    def _horizon_arc(self, progress: float) -> np.ndarray:
        """Arc lengths of the horizon: the robot's progress, then the path's fixed grid k · spacing ahead.

        Waypoints after the first stay at the same places from one replan to the next (only one enters
        the window each time the robot passes a grid point), so their retained sets are cached and the
        warm start is exact for them.
        """
        st = self.settings
        horizon = self._horizon()
        length = self._tracker.length
        first = math.floor(progress / st.spacing + 1e-9) + 1
        grid = (first + np.arange(horizon - 1)) * st.spacing
        grid = grid[(grid < length - 1e-9) & (grid - progress > 0.05 * st.spacing)]
        s = np.concatenate([[progress], grid])
        if s[-1] < length - 1e-9 and s.shape[0] < horizon:
            s = np.append(s, length)  # the end of the path closes the window
        return s

    def _sample_turns(self, s: np.ndarray, body_pos: np.ndarray,
                      quats: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The horizon at arc lengths ``s`` (N,) [m], body positions (N, 3) and attitudes (N, 4) with waypoints added
        where the body turns for longer than it travels (a turn in place, a tight corner): one per waypoint period
        (``spacing`` at :attr:`cruise_speed`) of the turn's time at :attr:`turn_rate` beyond the travel's, at most
        half the horizon in all. The added waypoints split the turn into equal angles (equal times) and lie where the
        path turns within the interval. Without them the seconds of a turn in place lie between two waypoints: the
        objective, which counts waypoints, gives them no weight and has no direction to place in them."""
        st = self.settings
        cruise = max(self.cruise_speed or st.nominal_speed, 1e-3)
        period = st.spacing / cruise
        turn_s = quat_angles(quats[:-1], quats[1:]) / self._assumed_turn_rate()
        extra = np.clip(np.floor((turn_s - np.diff(s) / cruise) / period + 1e-9).astype(int), 0, None)
        budget = self._horizon() // 2
        if budget < 1 or not np.any(extra > 0):
            return s, body_pos, quats
        out_s, out_p, out_q = [s[:1]], [body_pos[:1]], [quats[:1]]
        for i in range(s.shape[0] - 1):
            n = min(int(extra[i]), budget)
            budget -= n
            if n:
                f = np.arange(1, n + 1) / (n + 1)
                out_s.append(self._where_turning(s[i], s[i + 1], f))
                out_p.append(self._tracker.sample(out_s[-1])[0])
                out_q.append(quat_slerp(quats[i], quats[i + 1], f))
            out_s.append(s[i + 1:i + 2])
            out_p.append(body_pos[i + 1:i + 2])
            out_q.append(quats[i + 1:i + 2])
        return np.concatenate(out_s), np.concatenate(out_p), np.concatenate(out_q)

    def _where_turning(self, s0: float, s1: float, fractions: np.ndarray) -> np.ndarray:
        """Arc lengths (K,) in (s0, s1) [m] by which the path's attitude has made ``fractions`` (K,) of its turn over
        [s0, s1] (evenly spread where it does not turn), strictly increasing."""
        grid = np.linspace(s0, s1, 17)
        q = self._tracker.sample(grid)[1]
        turned = np.concatenate([[0.0], np.cumsum(quat_angles(q[:-1], q[1:]))])
        turning = turned[-1] > 1e-9
        at = np.interp(fractions * turned[-1], turned, grid) if turning else s0 + fractions * (s1 - s0)
        gap = 1e-6 * max(s1 - s0, 1e-3)
        at = np.maximum.accumulate(np.maximum(at, s0 + gap)) + gap * np.arange(at.shape[0])
        return np.minimum(at, s1 - gap)

    def _horizon(self) -> int:
        """Waypoints of the horizon in force: ``horizon`` halved per :attr:`degrade` step, at least 2 (or 1)."""
        h = self.settings.horizon
        return max(min(h, 2), h >> self.degrade)

    def _cap(self) -> int | None:
        """Landmarks per waypoint in force: ``max_landmarks_per_waypoint`` halved per :attr:`degrade` step."""
        cap = self.settings.max_landmarks_per_waypoint
        return None if not cap else max(1, cap >> self.degrade)

    def _adapt(self, solve_s: float) -> None:
        """After a replan of ``solve_s`` [s]: one more halving when it was over ``replan_budget``, one less
        when it took under a quarter of it (hysteresis: a level that fits is kept)."""
        budget = self.settings.replan_budget
        if budget is None:
            return
        if solve_s > budget:
            self.degrade = min(self.degrade + 1, PlannerSettings.MAX_DEGRADE)
        elif solve_s < 0.25 * budget and self.degrade > 0:
            self.degrade -= 1

    def _retained(self, snapshot: MapSnapshot, cams: np.ndarray, s: np.ndarray) -> list[np.ndarray]:
        """Capped retained sets per waypoint; grid waypoints (all but the first) come from a cache that is
        valid for one path and map version (and landmark cap)."""
        if len(snapshot) == 0:
            return [np.zeros(0, np.int64) for _ in range(cams.shape[0])]
        key = (self._path_version, snapshot.version, self._cap())
        if self._cache_key != key:
            self._cache_key, self._cache, self._attainable_cache = key, {}, {}
            self._joint_scores = {}
            self._rejected = (0, set())
        keys = _grid_keys(s)
        cached = {i: self._cache.get(keys[i]) for i in range(1, s.shape[0])}
        todo = [0] + [i for i, r in cached.items() if r is None]
        self._queried = len(todo) > 1
        # the snapshot's rows are in a spatial order fixed by the landmarks (pivotd.maps.store.spatial_cell_order),
        # so the cap's strided subsample (and the optimizer's) do not depend on the map's landmark order
        fresh = _cap_retained(snapshot.retained(cams[todo], self.settings.retained_filter), self._cap())
        out: list[np.ndarray] = [np.zeros(0, np.int64)] * s.shape[0]
        for i, r in zip(todo, fresh, strict=True):
            out[i] = r
        for i, r in cached.items():
            if r is not None:
                out[i] = r
        self._cache = {keys[i]: out[i] for i in range(1, s.shape[0])}
        return out

    def _in_view(self, snapshot: MapSnapshot, cam: np.ndarray, direction: np.ndarray,
                 retained: np.ndarray) -> np.ndarray:
        """Landmarks (K, 3) [m] of the first waypoint's retained set inside its planned cone, at most
        :data:`MAX_IN_VIEW`, nearest the axis first (for live markers)."""
        if retained.size == 0:
            return np.zeros((0, 3))
        pts = snapshot.points[retained]
        idx = in_cone(direction, normalize(pts - cam), self.settings.alpha, MAX_IN_VIEW)
        return pts[idx]

    def _constraint(self, body_quats: np.ndarray) -> PanTiltConstraint:
        lim = self.limits
        pan_min, pan_max = (-np.inf, np.inf) if lim.continuous_pan else (lim.pan_min, lim.pan_max)
        return PanTiltConstraint(base_from_world(body_quats, self.mount), pan_min, pan_max, lim.tilt_min, lim.tilt_max)

    def _warm_start(self, s: np.ndarray, n: int, mode: PathMode) -> np.ndarray | None:
        """The previous plan's directions at ``s`` (N,) [m] (its last one for a single pose); None when it was
        made for another path or mode (the anchor starts the plan then)."""
        prev = self.last_plan
        if prev is None or prev.path_version != self._path_version or prev.path_mode is not mode:
            return None
        if self._warm_from is not None and self._warm_from[0] is prev:
            prev = self._warm_from[1]  # the plan as solved, before its slew was started early
        if mode is not PathMode.ON_PATH:
            return np.repeat(prev.directions[-1:], n, axis=0)
        return prev.direction_at_s(s)

    def replan(self, snapshot: MapSnapshot, body_position: np.ndarray, body_quat: np.ndarray,
               anchor: np.ndarray | None, now: float | None = None) -> Plan:
        """Plan the horizon ahead of the robot at ``body_position`` / ``body_quat`` (x, y, z, w).

        ``anchor`` is the world direction currently being commanded (None before the first command); ``now``
        [s] the time of the pose, for the robot's speed (None: not measured; the last measurement, else
        ``nominal_speed``, stands).
        With the robot farther than ``max_path_offset`` from the path the plan is for its pose alone, as
        without a path (:class:`PathMode`), until it comes back within that distance.
        """
        t0 = time.perf_counter()
        st = self.settings
        body_position = np.asarray(body_position, float)
        body_quat = normalize(np.asarray(body_quat, float))
        if now is not None:
            self._measure_speed(float(now), body_position, body_quat)
        mode, offset = PathMode.NO_PATH, None
        if self._tracker is not None:
            self.progress, offset = self._advance(body_position)
            mode = PathMode.ON_PATH if offset <= st.max_path_offset else PathMode.OFF_PATH
        if mode is PathMode.ON_PATH:
            s = self._horizon_arc(self.progress)
            body_pos, quats = self._tracker.sample(s)
            # The first waypoint is where the robot is now, with its measured attitude.
            body_pos[0] = body_position
            quats[0] = body_quat
            s, body_pos, quats = self._sample_turns(s, body_pos, quats)
        else:
            s = np.zeros(1)
            body_pos, quats = body_position[None, :], body_quat[None, :]
        cams = camera_positions(body_pos, quats, self.mount)
        retained = self._retained(snapshot, cams, s)
        warm = self._warm_start(s, cams.shape[0], mode)
        problem = trajectory_problem(
            snapshot.points, cams, st.alpha, st.lam, weights=snapshot.query_weights, retained=retained,
            anchor=anchor,
            constraint=self._constraint(quats), max_step=st.max_step, options=st.options,
        )
        executed = _Execution(self, s, quats, anchor)
        deferred = self._take_deferred(s, mode) if warm is not None else None
        if deferred is None:
            result = executed.best(problem, self._solve_each(problem, self._seeds(problem, warm, anchor)))
        else:  # one solve per replan: the other basin found last replan is solved, the warm plan kept as it is
            self.joint_solves += 1
            kept = problem.evaluate(Seed("warm", warm, SeedKind.WARM))
            result = executed.best(problem, [kept, *self._solve_each(problem, [deferred])])
        # the joint-grid seed where the problem brings something new: a plan without a previous one, or a waypoint
        # that entered the horizon (between those the grid's answer barely moves; the rescue covers blind plans)
        # (not on the replan that queried the map for it: the work of a new waypoint is spread over two replans)
        keys = tuple(_grid_keys(s[1:]))
        due = warm is None or (keys != self._joint_keys and not self._queried)
        joint = self._joint_seed(problem, s, executed) if due else None
        if due:
            self._joint_keys = keys
        other_basin = joint is not None and self._other_basin(problem, joint, result, executed)
        if other_basin and warm is None:
            self.joint_solves += 1
            result = executed.best(problem, [result, *self._solve_each(problem, [joint[0]])])
        elif other_basin:  # a warm replan has had its solve: the next one solves this seed (_take_deferred)
            self._deferred = (self._path_version, s.copy(), joint[0].directions.copy())
        if warm is None:
            derived = derived_seeds(problem, result)
            if derived:
                result = executed.best(problem, [result, *self._solve_each(problem, derived)])
        rescue = Rescue.NOT_TRIED
        # one second solve per warm replan at most: the rescue only where the joint-grid seed found no other basin
        if warm is not None and st.rescue_fraction is not None and not other_basin and deferred is None:
            result, rescue = self._rescue(snapshot, cams, s, retained, result, problem, executed)
        # a plan that runs past the end of a bounded pan range, held there rather than slewed the long way round,
        # when that sees more as executed (no solve: the plan as it is)
        held = executed.held_at_limits(result.directions)
        if held is not None:
            result = executed.best(problem, [result, problem.evaluate(Seed(result.seed, held, SeedKind.WARM))])
        # a plan with a jump the axes cannot make between two waypoints, the slew started early enough to arrive on
        # time, when that sees more as executed than following it late
        # (the next replan starts from the plan before that: a start the ascent has already converged from)
        solved = result
        early = executed.anticipated(result.directions)
        if early is not None:
            result = executed.best(problem, [result, problem.evaluate(Seed(result.seed, early, SeedKind.WARM))])
        self.last_objective = result.objective
        directions, visible = result.directions, np.asarray(result.visible)
        pans, tilts = self._plan_joints(directions, executed.frames, quats, anchor)
        plan = Plan(
            created=time.monotonic(),
            positions=cams,
            directions=directions,
            body_quats=quats,
            visible=visible,
            s=s,
            map_version=snapshot.version,
            path_version=self._path_version,
            solve_s=time.perf_counter() - t0,
            landmarks=int(sum(r.shape[0] for r in retained)),
            in_view=self._in_view(snapshot, cams[0], result.directions[0], retained[0]),
            pans=pans,
            rescue=rescue,
            degrade=self.degrade,
            path_mode=mode,
            path_offset=offset,
            seed=result.seed,
            tilts=tilts,
            base_frames=executed.frames,
        )
        self.last_plan = plan
        self._warm_from = None
        if result is not solved:
            pans_s, tilts_s = self._plan_joints(solved.directions, executed.frames, quats, anchor)
            self._warm_from = (plan, replace(plan, directions=solved.directions, pans=pans_s, tilts=tilts_s))
        self._adapt(plan.solve_s)
        return plan

    @staticmethod
    def _seeds(problem: TrajectoryProblem, warm: np.ndarray | None, anchor: np.ndarray | None) -> list[Seed]:
        """The seeds of a replan: the previous plan when there is one for this path and mode (warm); otherwise
        the commanded direction (when there is one) and the cold seeds (pivotd.pivot.seeds.cold_seeds)."""
        if warm is not None:
            return [Seed("warm", warm, SeedKind.WARM)]
        out = [] if anchor is None else [Seed("anchor", np.repeat(np.asarray(anchor, float)[None, :], problem.n,
                                                                  axis=0), SeedKind.WARM)]
        return out + cold_seeds(problem)

    def _take_deferred(self, s: np.ndarray, mode: PathMode) -> Seed | None:
        """The joint-grid seed the last warm replan found in another basin, at this horizon's arc lengths ``s``
        (N,) [m] (its last direction held beyond its end), once; None when there is none or it was made for another
        path or mode."""
        deferred, self._deferred = self._deferred, None
        if deferred is None or mode is not PathMode.ON_PATH:
            return None
        version, s_old, dirs = deferred
        if version != self._path_version or s_old.shape[0] < 2:
            return None
        return Seed("joint_grid", directions_at_s(s_old, dirs, s), SeedKind.WARM)

    def _measure_speed(self, now: float, body_position: np.ndarray, body_quat: np.ndarray) -> None:
        """Update :attr:`speed` from the travel since the last replan (an average over about a second) and
        :attr:`turn_rate` from the turn (the fastest seen: a turn in place is not assumed slower than the robot
        turns)."""
        last, self._moved = self._moved, (now, body_position.copy(), body_quat.copy())
        if last is None or now <= last[0]:
            return
        dt = now - last[0]
        v = float(np.linalg.norm(body_position - last[1])) / dt
        k = min(1.0, dt)  # weight of this sample: its share of a second
        self.speed = v if self.speed is None else (1.0 - k) * self.speed + k * v
        self.cruise_speed = max(self.cruise_speed or 0.0, self.speed)
        w = turn_angle(last[2], body_quat) / dt
        if w > TURNING:
            self.turn_rate = w if self.turn_rate is None else max(self.turn_rate, w)

    def _joint_seed(self, problem: TrajectoryProblem, s: np.ndarray,
                    executed: _Execution) -> tuple[Seed, float] | None:
        """The best pan/tilt path over the horizon on a joint grid inside the limits (pivotd.pivot.joint_dp), each
        move within the axis speeds at the robot's speed (:attr:`speed`, else ``nominal_speed``), starting from
        the commanded joints; scored by each cell's hard visible share of the waypoint (the objective's terms) on at
        most ``TrajectoryOptions.seed_cap`` strided landmarks per waypoint.
        Returns the seed and its total score (the visible shares summed, as
        :meth:`~pivotd.pivot.trajectory.TrajectoryProblem.visible_share`), or None without ``axis_speeds`` or
        landmarks. Grid waypoints keep their scores while the cache key holds."""
        st, geom = self.settings, problem.geom
        if st.axis_speeds is None or geom is None:
            return None
        if self._grid is None:
            lim = self.limits
            self._grid = JointGrid.inside(lim.pan_min, lim.pan_max, lim.tilt_min, lim.tilt_max, st.joint_grid_step,
                                          continuous_pan=lim.continuous_pan)
        grid = self._grid
        cap = max(1, st.options.seed_cap)
        R = executed.frames
        keys = _grid_keys(s)
        scores = np.empty((s.shape[0], *grid.shape))
        fresh: dict[int, np.ndarray] = {}
        for i, key in enumerate(keys):
            sc = self._joint_scores.get(key) if i > 0 else None
            if sc is None:
                n = int(problem.lengths[i])
                cols = np.arange(n) if n <= cap else (np.arange(cap) * n) // cap  # a strided sample, weights
                B, W = geom.points[i, cols], geom.weights[i, cols]  # scaled to the waypoint's total
                total = float(W.sum(dtype=np.float64))
                share = float(geom.weights[i, :n].sum(dtype=np.float64)) / total if total > 0 else 0.0
                sc = cell_counts(B, W, grid, R[i], st.alpha) * (share / max(float(problem.norm[i]), 1e-12))
            if i > 0:
                fresh[key] = sc
            scores[i] = sc
        self._joint_scores = fresh
        dpan, dtilt = executed.steps
        start = executed.start
        path = best_joint_path(scores, dpan, dtilt, grid, start=start,
                               start_reach=None if start is None else self._first_reach())
        dirs = np.einsum("nji,nj->ni", R, grid.base_directions()[path.cells[:, 0] * grid.shape[1] + path.cells[:, 1]])
        return Seed("joint_grid", dirs, SeedKind.WARM), path.total

    @staticmethod
    def _other_basin(problem: TrajectoryProblem, joint: tuple[Seed, float], plan: TrajectoryResult,
                     executed: _Execution) -> bool:
        """Whether the joint-grid seed is worth a solve next to ``plan``: it leaves the plan's cone somewhere (a
        basin the plan's ascent cannot reach: a cone without landmarks has no gradient) and its visible shares
        add up to more than the plan's as the gimbal can follow it (:class:`_Execution`)."""
        seed, total = joint
        cos = np.einsum("ij,ij->i", normalize(seed.directions), plan.directions)
        return bool(cos.min() < math.cos(problem.alpha)) and total > problem.visible_share(
            executed.directions(plan.directions))

    def _solve_each(self, problem: TrajectoryProblem, seeds: list[Seed]) -> list[TrajectoryResult]:
        """Each seed solved (:meth:`TrajectoryProblem.solve`); counted in :attr:`solves`."""
        self.solves += len(seeds)
        return [problem.solve(seed) for seed in seeds]

    def _solve(self, problem: TrajectoryProblem, seeds: list[Seed]) -> TrajectoryResult:
        """The best plan (the objective) of ``seeds``."""
        return best_of(self._solve_each(problem, seeds))

    def _attainable(self, snapshot: MapSnapshot, cams: np.ndarray, s: np.ndarray,
                    retained: list[np.ndarray]) -> np.ndarray:
        """Estimated most retained landmarks (N,) one cone holds at each waypoint
        (:func:`pivotd.pivot.normalise.attainable_counts`, unit weights); grid waypoints reuse theirs while the
        retained cache's key holds, so a replan estimates only the ones entering the horizon. The first waypoint
        (the robot's position, new at every replan) takes the estimate of the next one, less than ``spacing`` ahead.
        """
        keys = _grid_keys(s)
        out = np.array([np.nan if i == 0 else self._attainable_cache.get(k, np.nan) for i, k in enumerate(keys)])
        todo = np.flatnonzero(np.isnan(out))
        if s.shape[0] > 1:
            todo = todo[todo > 0]
        L = max((retained[i].shape[0] for i in todo), default=0)
        if todo.size and L:
            B = np.zeros((todo.size, L, 3), np.float32)
            W = np.zeros((todo.size, L), np.float32)
            for r, i in enumerate(todo):
                rel = snapshot.points[retained[i]] - cams[i]
                n = np.linalg.norm(rel, axis=1)
                ok = n > 1e-9
                B[r, :rel.shape[0]][ok] = rel[ok] / n[ok, None]
                W[r, :rel.shape[0]] = ok
            out[todo] = attainable_counts(B, W, self.settings.alpha)
        if s.shape[0] > 1:
            out[0] = out[1]
        out[np.isnan(out)] = 0.0
        self._attainable_cache = {k: float(out[i]) for i, k in enumerate(keys) if i > 0}
        return out

    def _rescue(self, snapshot: MapSnapshot, cams: np.ndarray, s: np.ndarray, retained: list[np.ndarray],
                result: TrajectoryResult, problem: TrajectoryProblem,
                executed: _Execution) -> tuple[TrajectoryResult, Rescue]:
        """The warm plan ``result``, or a second solve from a start where its blind waypoints look at their best
        single-cone axis when that one reaches the higher objective (both solved with the same options).

        Blind: the plan sees fewer than ``rescue_fraction`` × the landmarks one cone could see there
        (:func:`pivotd.pivot.rescue.blind_waypoints`). A cone without landmarks has no gradient, so a warm start
        cannot leave a blank view for a rich one far away; the second start can. Nothing blind: no second solve.
        Blind waypoints whose best axis is out of the joint limits count with the nearest reachable one.
        A rescue that lost is not tried again while the problem stays the same: same path and map, same number
        of waypoints, and no blind waypoint outside the path's grid cells (``spacing`` long) already tried.
        """
        st = self.settings
        blind = blind_waypoints(result.visible, self._attainable(snapshot, cams, s, retained), st.rescue_fraction)
        if blind.size == 0:
            return result, Rescue.NOT_TRIED
        cells = {math.floor(float(x) / st.spacing + 1e-9) for x in s[blind]}
        size, tried = self._rejected
        if size == s.shape[0] and cells <= tried:
            return result, Rescue.NOT_TRIED
        lost = (s.shape[0], (tried if size == s.shape[0] else set()) | cells)  # what to remember if it loses
        axes = np.empty((blind.size, 3))
        for k, i in enumerate(blind):
            idx = retained[i]
            w = snapshot.query_weights[idx]
            axes[k] = optimize_view(snapshot.points[idx] - cams[i], w, st.alpha,
                                    init=result.directions[i], kernel=self._view_kernel()).direction
        constraint = problem.constraint
        if constraint is not None:  # the best reachable axis: blind only if it still sees the share asked for
            axes = constraint.project(_scatter(result.directions, blind, axes))[blind]
            reach = np.array([self._count(snapshot, cams[i], retained[i], a) for i, a in zip(blind, axes, strict=True)])
            still = result.visible[blind] < st.rescue_fraction * reach
            if not still.any():
                self._rejected = lost
                return result, Rescue.NOT_TRIED
            blind, axes = blind[still], axes[still]
        init = rescue_init(result.directions, blind, axes, st.rescue_reach)
        if constraint is not None:
            init = constraint.project(init)
        alt = self._solve(problem, [Seed("rescue", init, SeedKind.WARM)])
        if executed.pick(problem, [result, alt]) == 1:
            self.rescues += 1
            self._rejected = (0, set())
            return alt, Rescue.KEPT
        self._rejected = lost
        return result, Rescue.LOST

    def _view_kernel(self) -> ConeKernel:
        """The cone kernel of the FoV that :func:`~pivotd.pivot.view.optimize_view` would build for itself at every
        call (its default cells per face), built once (about 10 ms)."""
        alpha = self.settings.alpha
        if self._kernel is None or self._kernel.alpha != alpha:
            self._kernel = cone_kernel(alpha, ViewOptions().cells)
        return self._kernel

    def _plan_joints(self, directions: np.ndarray, frames: np.ndarray, quats: np.ndarray,
                     anchor: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
        """Joint pans and tilts (N,) [rad] for the planned ``directions`` (N, 3) in the base frames ``frames``
        (N, 3, 3) (world → base) over the whole horizon: the pans from the commanded pan
        (pivotd.gimbal.pan_unwrap.unwrap_pans: the least total slew inside the limits), the tilts clamped to their
        limits. When the bounded pan range forces a slew the long way round, the joint-grid seed and the judge of
        plans as executed have already weighed it (:class:`_Execution`)."""
        commanded = self._commanded_joints(anchor, quats[0])
        if commanded is not None:
            start = commanded[0]
        else:
            reference = self._reference_pan()
            start = reference if reference is not None else self.limits.clamp(0.0, 0.0)[0]
        pan, tilt = direction_to_pan_tilt(np.einsum("nij,nj->ni", frames, directions))
        return unwrap_pans(pan, start, self.limits)[0], np.clip(tilt, self.limits.tilt_min, self.limits.tilt_max)

    def _reference_pan(self) -> float | None:
        """The previous plan's first joint pan [rad] (the branch a direction's pan is taken nearest to), if any."""
        prev = self.last_plan
        return None if prev is None or prev.pans is None else float(prev.pans[0])

    def _commanded_joints(self, anchor: np.ndarray | None, quat: np.ndarray) -> tuple[float, float] | None:
        """Joints (pan, tilt) [rad] of the commanded direction ``anchor`` (3,) at the body attitude ``quat``, on the
        branch nearest the previous plan's first pan; None without an anchor."""
        if anchor is None:
            return None
        pan, tilt, _ = world_direction_to_joints(np.asarray(anchor, float), quat, self.mount, self.limits,
                                                 self._reference_pan())
        return pan, tilt

    def _first_reach(self) -> tuple[float, float]:
        """Largest pan and tilt moves [rad] from the commanded joints to a plan's first waypoint: the axis speeds times
        :attr:`PlannerSettings.replan_period` (the time that plan is followed before the next one)."""
        st = self.settings
        return st.axis_speeds[0] * st.replan_period, st.axis_speeds[1] * st.replan_period

    def _assumed_turn_rate(self) -> float:
        """The robot's turn rate [rad/s] for the time of a turn: :attr:`turn_rate`, else ``nominal_turn_rate``."""
        return max(self.turn_rate if self.turn_rate is not None else self.settings.nominal_turn_rate, 1e-3)

    def _step_limits(self, s: np.ndarray, quats: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Largest pan and tilt moves [rad] (N − 1,) between waypoints at arc lengths ``s`` (N,) [m] with body attitudes
        ``quats`` (N, 4), over the time the robot takes between them: the longer of its travel at :attr:`speed` (else
        ``nominal_speed``) and its turn at :attr:`turn_rate` (else ``nominal_turn_rate``; a turn in place takes time
        and no arc length), times the axis speeds."""
        st = self.settings
        speed = max(self.speed if self.speed is not None else st.nominal_speed, 1e-3)
        q = np.asarray(quats, float)
        dt = np.maximum(np.diff(s) / speed, quat_angles(q[:-1], q[1:]) / self._assumed_turn_rate())
        return st.axis_speeds[0] * dt, st.axis_speeds[1] * dt

    def _count(self, snapshot: MapSnapshot, cam: np.ndarray, idx: np.ndarray, direction: np.ndarray) -> int:
        """Hard count of the retained landmarks ``idx`` within α of ``direction`` seen from ``cam``."""
        rel = snapshot.points[idx] - cam
        rel = rel / np.maximum(np.linalg.norm(rel, axis=1, keepdims=True), 1e-12)
        return hard_count(direction, rel, self.settings.alpha)

