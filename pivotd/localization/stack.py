"""The pivotd components the localization benchmark drives, imported in one place.

Everything the simulator takes from the daemon (config loader, planner and control-loop builders,
jerk-limited motion model, kinematics, map store and occlusion grid, map and path readers) comes
through this module, so a move of any of them is a one-line change here.
"""

from __future__ import annotations

from pivotd.bench.achievable import achievable_path
from pivotd.bus.messages import PoseSample
from pivotd.config import Config, load_config
from pivotd.daemon.control import ControlLoop
from pivotd.daemon.planner import Plan, RecedingHorizonPlanner
from pivotd.daemon.wiring import build_control_loop, build_planner, build_replan_trigger
from pivotd.gimbal.kinematics import (
    JointLimits,
    Mount,
    base_from_world,
    camera_position,
    joints_to_world_direction,
    world_direction_to_joints,
)
from pivotd.gimbal.link import GimbalState
from pivotd.gimbal.motion import AxisLimits, MotionGenerator
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.maps.store import BASE_LAYER, MapStore
from pivotd.pivot.joint_dp import JointGrid
from pivotd.robot_path import Polyline, load_path
from pivotd.sim.analysis import setpoint_dynamics

__all__ = [
    "BASE_LAYER",
    "AxisLimits",
    "Config",
    "ControlLoop",
    "GimbalState",
    "JointGrid",
    "JointLimits",
    "LandmarkCloud",
    "MapStore",
    "MotionGenerator",
    "Mount",
    "OccupancyGrid",
    "Plan",
    "Polyline",
    "PoseSample",
    "RecedingHorizonPlanner",
    "achievable_path",
    "base_from_world",
    "build_control_loop",
    "build_planner",
    "build_replan_trigger",
    "camera_position",
    "joints_to_world_direction",
    "load_config",
    "load_landmarks",
    "load_path",
    "setpoint_dynamics",
    "world_direction_to_joints",
]
