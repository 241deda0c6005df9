"""The daemon's planning along a path, offline (``pivotd plan --config``).

The same map store (:func:`~pivotd.daemon.wiring.build_map_store`), planner
(:func:`~pivotd.daemon.wiring.build_planner`) and anchor (:func:`~pivotd.daemon.wiring.replan_anchor`) as the
daemon, fed the poses of a robot that follows the path exactly: one replan every ``planner.waypoint_spacing``
along it, from its start to its end. The path is installed as the daemon receives it from a ``nav_msgs/Path``
(identity orientations when the file has none, which the planner then ignores for the path's heading), and the
robot's attitude at each replan is the one the planner predicts there (the path's orientations, else its
heading). The first replan is anchored as the daemon's first one with the gimbal at its park pose; each later one
to the previous plan's first direction, the direction the daemon would be commanding by then. The planner's
computations run on one BLAS thread, as in the daemon's planner process.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from threadpoolctl import threadpool_limits

from pivotd.config import Config
from pivotd.daemon.planner import Plan
from pivotd.daemon.wiring import build_planner, replan_anchor
from pivotd.gimbal.kinematics import world_direction_to_joints
from pivotd.maps.store import MapStore
from pivotd.robot_path import PathData, Polyline

#: The path's version as the daemon numbers the first path it receives.
FIRST_PATH_VERSION = 1


@dataclass(frozen=True)
class RobotPoses:
    """Where the robot is at each replan: arc length ``s`` (K,) [m] along the path, body ``positions`` (K, 3) [m]
    and attitudes ``quats`` (K, 4) (x, y, z, w)."""

    s: np.ndarray
    positions: np.ndarray
    quats: np.ndarray


@dataclass(frozen=True)
class PathStep:
    """One replan: the robot's arc length ``s`` [m], ``position`` (3,) [m] and ``quat`` (4,); the ``plan`` made
    there; the joints ``pan``, ``tilt`` [rad] of its first direction (within the joint limits; ``clamped`` when
    the direction is out of reach and the nearest reachable joints are given)."""

    s: float
    position: np.ndarray
    quat: np.ndarray
    plan: Plan
    pan: float
    tilt: float
    clamped: bool

    @property
    def direction(self) -> np.ndarray:
        """The plan's first world viewing direction (3,): the one commanded at this point."""
        return self.plan.directions[0]

    @property
    def visible(self) -> int:
        """Hard count of the landmarks within α of :attr:`direction` from the camera here."""
        return int(self.plan.visible[0])


def path_message(path: PathData) -> tuple[np.ndarray, np.ndarray]:
    """The positions (N, 3) [m] and orientations (N, 4) (x, y, z, w) the daemon receives for ``path`` published
    as a ``nav_msgs/Path`` (identity orientations when the file has none)."""
    positions = np.asarray(path.positions, float)
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (positions.shape[0], 1)) if path.quats is None else path.quats
    return positions, np.asarray(quats, float)


def robot_poses(path: PathData, spacing: float) -> RobotPoses:
    """The robot's poses every ``spacing`` [m] along ``path`` from its start, and at its end (unless the last one
    is within 5 % of ``spacing`` of it): positions on the path, and the attitude the planner predicts there (the
    path's orientations, else its heading)."""
    positions, quats = path_message(path)
    line = Polyline(positions, quats, ignore_constant_quats=True)
    s = np.arange(int(np.floor(line.length / spacing + 1e-9)) + 1) * spacing
    if line.length - s[-1] > 0.05 * spacing:  # the end, unless the last one is there already
        s = np.append(s, line.length)
    pos, q = line.sample(s)
    return RobotPoses(s, pos, q)


def plan_along_path(cfg: Config, store: MapStore, path: PathData) -> list[PathStep]:
    """The replans the daemon configured by ``cfg`` would make on ``store``'s map as the robot follows ``path``
    (module docstring); one step per pose of :func:`robot_poses`."""
    planner = build_planner(cfg)
    planner.set_path(*path_message(path), FIRST_PATH_VERSION)
    poses = robot_poses(path, cfg.planner.waypoint_spacing)
    steps: list[PathStep] = []
    with threadpool_limits(1):
        for s, position, quat in zip(poses.s, poses.positions, poses.quats, strict=True):
            anchor = replan_anchor(cfg, None, quat) if not steps else steps[-1].direction
            # the robot at the planner's nominal speed: the pose of arc length s comes s / speed after the start
            plan = planner.replan(store.snapshot(), position, quat, anchor,
                                  now=float(s) / planner.settings.nominal_speed)
            previous_pan = None if plan.pans is None else float(plan.pans[0])
            pan, tilt, clamped = world_direction_to_joints(plan.directions[0], quat, cfg.gimbal.mount,
                                                           cfg.gimbal.limits, previous_pan)
            steps.append(PathStep(float(s), position, quat, plan, pan, tilt, clamped))
    return steps
