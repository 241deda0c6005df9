"""Camera policies compared by the localization benchmark.

Every policy except the two oracles is driven through the daemon's control loop (jerk-limited Ruckig motion
inside the joint limits, config/demo.yaml): at the planner rate it returns either a :class:`Plan` (world
directions along the route, followed by the control loop with feed-forward) or a joint target
(pan, tilt) [rad]. The oracles know the whole route in advance and compute their camera path at once.

* ``forward``: gimbal fixed at pan = tilt = 0.
* ``pivot``: the daemon's receding-horizon planner (warm starts, anchored to the commanded direction).
* ``fisher``: at the route's waypoints every ``planner.waypoint_spacing`` metres (FIF's per-position
  search), the argmax of log det of the pose Fisher information over a pan × tilt grid inside the joint
  limits at the attitude the body will have there; the control loop follows these directions.
* ``oracle``: the achievable view: the exact best path of in-image landmark counts over a pan × tilt grid
  inside the joint limits, every step between frames within the axis velocity limits
  (:func:`pivotd.pivot.joint_dp.best_joint_path`), executed through the motion generator with the configured
  velocity, acceleration and jerk limits (``pivotd bench achievable``'s reference).
* ``teleport``: the largest count of landmarks in the image on a fine grid of the whole sphere, per frame,
  ignoring every joint and motion limit.
* ``random``: a smooth random joint trajectory (two sines per axis, 0.03–0.12 Hz).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

from pivotd.compat import StrEnum
from pivotd.geometry import pan_tilt_to_direction
from pivotd.localization.camera import camera_rotation, in_view_counts
from pivotd.localization.fisher import best_view
from pivotd.localization.stack import (
    JointGrid,
    Plan,
    PoseSample,
    achievable_path,
    base_from_world,
    build_planner,
    build_replan_trigger,
)
from pivotd.localization.world import World
from pivotd.pivot.lattice import azimuth_elevation_grid

FISHER_GRID_DEG = 10.0  # pan × tilt step of the Fisher-information baseline
FISHER_LOOKAHEAD = 4  # waypoints ahead of the robot the Fisher baseline plans
ORACLE_GRID_DEG = 3.0  # largest pan/tilt spacing of the achievable oracle's joint grid
TELEPORT_COARSE_DEG = 10.0  # whole-sphere grid of the teleporting oracle, refined around the best cells
TELEPORT_FINE_DEG = 2.0
TELEPORT_REFINE = 3  # coarse cells refined
_ROTATIONS_PER_BLOCK = 256  # camera orientations counted together (bounds the temporaries)


class PolicyName(StrEnum):
    FORWARD = "forward"
    PIVOT = "pivot"
    FISHER = "fisher"
    ORACLE = "oracle"
    TELEPORT = "teleport"
    RANDOM = "random"


Command = Plan | tuple[float, float]


@dataclass
class Policy:
    """Base: ``limited`` policies keep the joint and motion limits; ``open_loop`` ones compute their camera path
    for the whole route at once (:meth:`camera_path`) instead of steering the control loop (:meth:`update`)."""

    world: World
    seed: int = 0
    name: PolicyName = PolicyName.FORWARD
    limited: bool = True
    open_loop: bool = False

    def update(self, t: float, pose: PoseSample, commanded: np.ndarray | None) -> Command:
        """Command at time ``t`` [s] for body ``pose``; ``commanded``: world direction now being commanded."""
        return (0.0, 0.0)

    def camera_path(self, centres: np.ndarray, quats: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Open-loop policies: world optical axes (F, 3) for camera ``centres`` (F, 3) with the body at ``quats``
        (F, 4) at ``frames`` (F,) [s], and the commanded stream (S, 4) (pan, tilt, pan rate, tilt rate) at the
        control period (empty when the policy commands none)."""
        raise NotImplementedError(f"{self.name} is steered through the control loop")

    def decisions(self, calls: int) -> int:
        """Decisions taken in a run with ``calls`` calls (of :meth:`update`, or per-frame looks): one each."""
        return calls


@dataclass
class ForwardPolicy(Policy):
    name: PolicyName = PolicyName.FORWARD


@dataclass
class PivotPolicy(Policy):
    name: PolicyName = PolicyName.PIVOT

    def __post_init__(self) -> None:
        self.planner = build_planner(self.world.cfg)
        self.trigger = build_replan_trigger(self.world.cfg)
        self.replans = 0
        self._plan: Plan | None = None
        sc = self.world.scene
        self.planner.set_path(sc.route, sc.route_quats, 1)

    def update(self, t: float, pose: PoseSample, commanded: np.ndarray | None) -> Command:
        """A new plan when the daemon's replan trigger says so (pivotd.daemon.replan_trigger), else the last one."""
        snapshot = self.world.store.snapshot()
        inputs = (1, snapshot.version)
        if self._plan is not None and self.trigger.due(t, pose.position, inputs) is None:
            return self._plan
        self._plan = self.planner.replan(snapshot, pose.position, pose.quat, commanded)
        self.trigger.planned(t, pose.position, inputs)
        self.replans += 1
        return self._plan

    def decisions(self, calls: int) -> int:
        """The replans made."""
        return self.replans


def joint_grid(limits, step_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """Pan (G,) and tilt (G,) [rad] of a grid with ``step_deg`` spacing covering the joint limits."""
    step = math.radians(step_deg)
    pans = np.arange(limits.pan_min, limits.pan_max + 1e-9, step)
    tilts = np.arange(limits.tilt_min, limits.tilt_max + 1e-9, step)
    p, t = np.meshgrid(pans, tilts, indexing="ij")
    return p.ravel(), t.ravel()


@dataclass
class FisherPolicy(Policy):
    name: PolicyName = PolicyName.FISHER
    _cache: dict = field(default_factory=dict)

    def __post_init__(self) -> None:
        self._pan, self._tilt = joint_grid(self.world.limits, FISHER_GRID_DEG)
        self._d_base = pan_tilt_to_direction(self._pan, self._tilt)  # (G, 3)
        self._progress: float | None = None

    def direction_at(self, centre: np.ndarray, body_quat: np.ndarray, key: object) -> np.ndarray:
        """Fisher-optimal world direction (3,) for a camera at ``centre`` with the body at ``body_quat``."""
        d_world = self._d_base @ base_from_world(body_quat, self.world.mount)  # rows: Rᵀ d
        R = camera_rotation(d_world)
        sight = self.world.sight(key, centre)
        best, _ = best_view(self.world.camera, R, centre, self.world.scene.landmarks[sight])
        return d_world[best]

    def decisions(self, calls: int) -> int:
        """One grid search per route position (each computed once)."""
        return len(self._cache)

    def update(self, t: float, pose: PoseSample, commanded: np.ndarray | None) -> Command:
        w = self.world
        spacing = w.cfg.planner.waypoint_spacing
        self._progress, _ = w.route.locate(pose.position, self._progress)
        first = math.floor(self._progress / spacing + 1e-9)
        s = (first + np.arange(FISHER_LOOKAHEAD + 1)) * spacing
        s = np.unique(np.minimum(s, w.route.length))
        body, quats = w.route.sample(s)
        cams = w.camera_centres(body, quats)
        dirs = np.empty_like(cams)
        for i in range(s.shape[0]):
            key = ("fisher", round(float(s[i]) * 1e6))
            if key not in self._cache:
                self._cache[key] = self.direction_at(cams[i], quats[i], key)
            dirs[i] = self._cache[key]
        if s.shape[0] == 1:  # at the end of the route
            cams, dirs, quats, s = (np.repeat(a, 2, axis=0) for a in (cams, dirs, quats, s))
            s[1] += 1e-6
        return Plan(created=t, positions=cams, directions=dirs, body_quats=quats, visible=np.zeros(s.shape[0]),
                    s=s, map_version=0, path_version=0, solve_s=0.0)


def _in_view(world: World, d_world: np.ndarray, centre: np.ndarray, pts: np.ndarray) -> np.ndarray:
    """In-image counts (G,) of ``pts`` for a camera at ``centre`` looking along each of ``d_world`` (G, 3)."""
    out = np.zeros(d_world.shape[0], np.int64)
    for s in range(0, d_world.shape[0], _ROTATIONS_PER_BLOCK):
        block = d_world[s:s + _ROTATIONS_PER_BLOCK]
        out[s:s + block.shape[0]] = in_view_counts(world.camera, camera_rotation(block), centre, pts)
    return out


@dataclass
class OraclePolicy(Policy):
    """The achievable oracle: the best in-image count path over a joint grid inside the limits with every step
    within the velocity limits × the frame interval, executed through the motion generator from pan = tilt = 0."""

    name: PolicyName = PolicyName.ORACLE
    open_loop: bool = True

    def __post_init__(self) -> None:
        lim = self.world.limits
        self.grid = JointGrid.inside(lim.pan_min, lim.pan_max, lim.tilt_min, lim.tilt_max,
                                     math.radians(ORACLE_GRID_DEG), continuous_pan=lim.continuous_pan)
        self._d_base = self.grid.base_directions()  # (P·T, 3)

    def scores(self, frame: int, centre: np.ndarray, body_quat: np.ndarray) -> np.ndarray:
        """In-image counts (P, T) of every grid cell at frame number ``frame``."""
        pts = self.world.scene.landmarks[self.world.sight(frame, centre)]
        if pts.shape[0] == 0:
            return np.zeros(self.grid.shape)
        d_world = self._d_base @ base_from_world(body_quat, self.world.mount)  # rows: Rᵀ d
        return _in_view(self.world, d_world, centre, pts).reshape(self.grid.shape).astype(float)

    def camera_path(self, centres: np.ndarray, quats: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        scores = np.stack([self.scores(i, c, q) for i, (c, q) in enumerate(zip(centres, quats, strict=True))])
        _, ex = achievable_path(self.world.cfg, frames, scores, self.grid, np.zeros(2),
                                end_time=self.world.scene.duration)
        R = base_from_world(quats, self.world.mount).reshape(-1, 3, 3)
        dirs = np.einsum("fji,fj->fi", R, pan_tilt_to_direction(ex.at_frames[:, 0], ex.at_frames[:, 1]))
        return dirs, np.column_stack([ex.positions, ex.velocities])


@dataclass
class TeleportPolicy(Policy):
    """Best in-image count on a fine grid at every frame, teleporting (no joint or motion limits)."""

    name: PolicyName = PolicyName.TELEPORT
    limited: bool = False
    open_loop: bool = True

    def __post_init__(self) -> None:
        self._coarse = azimuth_elevation_grid(TELEPORT_COARSE_DEG)
        k = math.ceil(TELEPORT_COARSE_DEG / TELEPORT_FINE_DEG)
        off = np.radians(np.arange(-k, k + 1) * TELEPORT_FINE_DEG)
        self._offsets = np.stack(np.meshgrid(off, off, indexing="ij"), axis=-1).reshape(-1, 2)

    def _counts(self, dirs: np.ndarray, centre: np.ndarray, pts: np.ndarray) -> np.ndarray:
        return in_view_counts(self.world.camera, camera_rotation(dirs), centre, pts)

    def look(self, centre: np.ndarray, sight: np.ndarray) -> np.ndarray:
        """World viewing direction (3,) for a camera at ``centre`` seeing landmarks ``sight`` (indices)."""
        pts = self.world.scene.landmarks[sight]
        if pts.shape[0] == 0:
            return self._coarse[0]
        counts = self._counts(self._coarse, centre, pts)
        best_dir, best_count = self._coarse[int(np.argmax(counts))], int(counts.max())
        for i in np.argsort(-counts, kind="stable")[:TELEPORT_REFINE]:
            az = math.atan2(self._coarse[i, 1], self._coarse[i, 0])
            el = math.asin(float(np.clip(self._coarse[i, 2], -1, 1)))
            els = np.clip(el + self._offsets[:, 1], -math.pi / 2 + 1e-3, math.pi / 2 - 1e-3)
            fine = pan_tilt_to_direction(az + self._offsets[:, 0], -els)
            c = self._counts(fine, centre, pts)
            if int(c.max()) > best_count:
                best_dir, best_count = fine[int(np.argmax(c))], int(c.max())
        return best_dir

    def camera_path(self, centres: np.ndarray, quats: np.ndarray, frames: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        dirs = np.array([self.look(c, self.world.sight(i, c)) for i, c in enumerate(centres)])
        return dirs, np.zeros((0, 4))


@dataclass
class RandomSmoothPolicy(Policy):
    name: PolicyName = PolicyName.RANDOM

    def __post_init__(self) -> None:
        rng = np.random.default_rng([self.seed, 77])
        self._f = rng.uniform(0.03, 0.12, (2, 2))  # [Hz] axis × component
        self._phi = rng.uniform(0, 2 * math.pi, (2, 2))
        lim = self.world.limits
        pan_span = min(lim.pan_max, -lim.pan_min, math.radians(120.0))
        self._centre = np.array([0.0, 0.5 * (lim.tilt_min + lim.tilt_max)])
        self._amp = np.array([pan_span, 0.4 * (lim.tilt_max - lim.tilt_min)])

    def update(self, t: float, pose: PoseSample, commanded: np.ndarray | None) -> Command:
        wave = np.sin(2 * math.pi * self._f * t + self._phi).mean(axis=1)
        pan, tilt = self._centre + self._amp * wave
        return float(pan), float(tilt)


POLICIES: dict[PolicyName, type[Policy]] = {
    PolicyName.FORWARD: ForwardPolicy,
    PolicyName.PIVOT: PivotPolicy,
    PolicyName.FISHER: FisherPolicy,
    PolicyName.ORACLE: OraclePolicy,
    PolicyName.TELEPORT: TeleportPolicy,
    PolicyName.RANDOM: RandomSmoothPolicy,
}


def make_policy(name: PolicyName | str, world: World, seed: int) -> Policy:
    """Policy ``name`` for ``world``; ``seed`` drives the random policy."""
    return POLICIES[PolicyName(name)](world=world, seed=seed)
