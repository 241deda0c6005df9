"""Builders that turn a validated :class:`~pivotd.config.Config` into runtime components.

One place maps config sections onto the components' own settings, so the daemon, the benchmarks
and the demo build the same things the same way.
"""

from __future__ import annotations

import contextlib
import ctypes
import math
import time
from collections.abc import Callable

import numpy as np

from pivotd.config import Config
from pivotd.config.settings import wire_config
from pivotd.daemon.control import ControlLoop, ControlSettings
from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner, trajectory_options_from
from pivotd.daemon.replan_trigger import ReplanTrigger
from pivotd.daemon.tracking_error import TrackingErrorSettings
from pivotd.errors import ConfigError
from pivotd.gimbal.dynamixel_link import DynamixelGimbal, DynamixelSettings
from pivotd.gimbal.interface import GimbalInterface
from pivotd.gimbal.kinematics import joints_to_world_direction
from pivotd.gimbal.link import GimbalLink, LinkConfig
from pivotd.gimbal.mavlink_link import MavlinkGimbal, MavlinkSettings
from pivotd.gimbal.motion import MotionGenerator
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.fingerprint import MapIdentity, map_identity
from pivotd.maps.store import MapStore, load_map_store
from pivotd.pivot.trajectory import TrajectoryOptions


def build_retained_filter(cfg: Config) -> RetainedFilter:
    """Per-waypoint landmark filter from ``cfg.map.filters`` (occlusion on when a voxel size is set)."""
    f = cfg.map.filters
    return RetainedFilter(
        min_range=f.min_range,
        max_range=f.max_range,
        max_view_angle_deg=None if f.max_view_angle is None else math.degrees(f.max_view_angle),
        occlusion=f.occlusion_voxel is not None,
    )


def build_map_store(cfg: Config) -> MapStore:
    """Load ``cfg.map.file`` into a new store (an empty store when no file and ``allow_empty``)."""
    m = cfg.map
    if m.file is None:
        if not m.allow_empty:
            raise ConfigError(f"{cfg.source}: map.file: required unless map.allow_empty is true")
        return MapStore(occupancy_voxel=m.filters.occlusion_voxel, cell_cap=m.max_landmarks_per_cell)
    store = load_map_store(
        m.file,
        weight_property=m.weight_property,
        occlusion_voxel=m.filters.occlusion_voxel,
        occupancy_file=m.filters.occupancy_file,
        allow_empty=m.allow_empty,
        cell_cap=m.max_landmarks_per_cell,
    )
    release_free_memory()
    return store


def map_files_identity(cfg: Config) -> MapIdentity:
    """The identity on disk of the files :func:`build_map_store` reads for ``cfg`` (pivotd.maps.fingerprint)."""
    return map_identity(cfg.map.file, cfg.map.filters.occupancy_file)


def release_free_memory() -> None:
    """Give freed heap memory back to the OS (glibc ``malloc_trim``), e.g. after loading a large map.

    Loading a map allocates and frees temporaries of several times the map's final size; glibc keeps
    them in the heap, so without this the daemon's RSS stays at the loading peak. No-op elsewhere.
    """
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").malloc_trim(0)


M_MMAP_THRESHOLD = -3  # glibc mallopt parameter
MMAP_THRESHOLD_BYTES = 1 << 20


def return_large_frees_to_the_os() -> None:
    """Serve allocations of 1 MiB and more with their own memory maps, returned to the OS when freed (glibc).

    By default glibc raises that threshold up to 32 MiB after the first large free, so large messages
    received one after another (Zenoh reassembles each on its own threads) land in per-thread heaps that
    keep their peak size. A fixed threshold keeps resident memory flat under a flood. No-op elsewhere.
    """
    with contextlib.suppress(OSError, AttributeError):
        ctypes.CDLL("libc.so.6").mallopt(M_MMAP_THRESHOLD, MMAP_THRESHOLD_BYTES)


#: Planner settings no config key sets (the same for every daemon): the stretch of the path searched behind and
#: ahead of the last progress [m], and the waypoints on either side of a blind run the rescue turns towards it
#: (pivotd.daemon.planner.PlannerSettings).
PROGRESS_BACK_WINDOW_M = 1.0
PROGRESS_AHEAD_WINDOW_M = 5.0
RESCUE_REACH = 2


def trajectory_options(cfg: Config) -> TrajectoryOptions:
    """The optimizer's options from the ``pivot`` and ``planner`` sections
    (:func:`~pivotd.daemon.planner.trajectory_options_from`); the daemon never plans with
    :meth:`TrajectoryOptions.paper`."""
    return trajectory_options_from(cfg.pivot, cfg.planner)


def planner_settings(cfg: Config) -> PlannerSettings:
    """Every planner setting from ``cfg``: the ``pivot`` and ``planner`` sections and the map filters, each passed
    explicitly, so the daemon plans with the config's defaults and never with those of
    :class:`~pivotd.daemon.planner.PlannerSettings` (the ones no key sets are the constants above)."""
    p, pl = cfg.pivot, cfg.planner
    return PlannerSettings(
        fov=p.fov,
        lam=p.lam,
        spacing=pl.waypoint_spacing,
        horizon=pl.horizon,
        max_landmarks_per_waypoint=pl.max_landmarks_per_waypoint,
        retained_filter=build_retained_filter(cfg),
        options=trajectory_options(cfg),
        back_window=PROGRESS_BACK_WINDOW_M,
        ahead_window=PROGRESS_AHEAD_WINDOW_M,
        max_step=pl.max_step,
        max_path_offset=pl.max_path_offset,
        rescue_fraction=pl.rescue_fraction if pl.rescue_blind else None,
        rescue_reach=RESCUE_REACH,
        replan_budget=pl.replan_budget,
        axis_speeds=(cfg.motion.pan.max_velocity, cfg.motion.tilt.max_velocity),
        replan_period=1.0 / pl.replan_hz,
    )


def build_planner(cfg: Config) -> RecedingHorizonPlanner:
    """Receding-horizon planner with :func:`planner_settings` and the gimbal's mount and joint limits."""
    return RecedingHorizonPlanner(planner_settings(cfg), cfg.gimbal.mount, cfg.gimbal.limits)


def build_replan_trigger(cfg: Config) -> ReplanTrigger:
    """When to replan (``planner.replan_on_waypoint``: once the body moved one waypoint spacing, at least every
    ``replan_max_interval_s``; otherwise at every tick of ``replan_hz``)."""
    pl = cfg.planner
    return ReplanTrigger(pl.waypoint_spacing if pl.replan_on_waypoint else None, pl.replan_max_interval)


def build_link_config(cfg: Config) -> LinkConfig:
    """CONFIG limits for the device: joint limits, and the motion limits as the device's rate limits."""
    return LinkConfig(wire_config(cfg.gimbal, cfg.motion))


def build_motion(cfg: Config) -> MotionGenerator:
    """Jerk-limited setpoint generator at the control period."""
    return MotionGenerator(1.0 / cfg.control.rate_hz, cfg.motion.pan, cfg.motion.tilt, cfg.gimbal.limits,
                           deadband=cfg.motion.deadband)


def build_control_loop(cfg: Config, link: GimbalInterface, clock: Callable[[], float] = time.monotonic) -> ControlLoop:
    """The control tick for ``link`` on the monotonic ``clock`` [s]."""
    return ControlLoop(build_control_settings(cfg), build_motion(cfg), cfg.gimbal.mount, cfg.gimbal.limits, link,
                       clock=clock)


def build_control_settings(cfg: Config) -> ControlSettings:
    """The control tick's timing: rate, stale-pose and stale-plan timeouts (ten replanning periods, ≥ 1 s, and
    with event-driven replanning at least twice its longest interval); the tracking-error supervision."""
    pl = cfg.planner
    longest = 2.0 * pl.replan_max_interval if pl.replan_on_waypoint else 0.0
    c = cfg.control
    return ControlSettings(rate_hz=c.rate_hz, pose_timeout=c.pose_timeout_s,
                           plan_timeout=max(1.0, 10.0 / pl.replan_hz, longest),
                           tracking_error=TrackingErrorSettings(c.tracking_error, c.tracking_error_s))


def build_mavlink_settings(cfg: Config) -> MavlinkSettings:
    """The mavlink backend's identities and the joint limits it enforces and checks against the device's."""
    m = cfg.gimbal.mavlink
    return MavlinkSettings(limits=cfg.gimbal.limits, system_id=m.system_id, component_id=m.component_id,
                           target_system=m.target_system, target_component=m.target_component,
                           gimbal_device_id=m.gimbal_device_id)


def build_dynamixel_settings(cfg: Config) -> DynamixelSettings:
    """The dynamixel backend's servo ids, directions and zero ticks, and the limits the servos are configured
    with."""
    d = cfg.gimbal.dynamixel
    return DynamixelSettings(limits=cfg.gimbal.limits, pan_motion=cfg.motion.pan, tilt_motion=cfg.motion.tilt,
                             pan_id=d.pan_id, tilt_id=d.tilt_id, pan_reversed=d.pan_reversed,
                             tilt_reversed=d.tilt_reversed, pan_zero_tick=d.pan_zero_tick,
                             tilt_zero_tick=d.tilt_zero_tick, watchdog_ms=cfg.gimbal.watchdog_ms,
                             control_period_s=cfg.control.dt, idle_period_s=2.0 / cfg.control.rate_hz)


def build_gimbal(cfg: Config) -> GimbalInterface:
    """The gimbal of ``cfg.gimbal.backend`` on ``gimbal.port``, not yet started."""
    backend = cfg.gimbal.backend
    if backend == "pivot":
        return GimbalLink(cfg.gimbal.port, build_link_config(cfg), baudrate=cfg.gimbal.baud)
    if backend == "mavlink":
        return MavlinkGimbal(cfg.gimbal.port, build_mavlink_settings(cfg), baudrate=cfg.gimbal.baud)
    if backend == "dynamixel":
        return DynamixelGimbal(cfg.gimbal.port, build_dynamixel_settings(cfg), baudrate=cfg.gimbal.baud)
    raise ConfigError(f"{cfg.source}: gimbal.backend: {backend!r} is not available in this version")


def park_joints(cfg: Config) -> tuple[float, float]:
    """The park pose (pan, tilt) [rad], inside the joint limits."""
    return cfg.gimbal.limits.clamp(cfg.gimbal.park_pan, cfg.gimbal.park_tilt)


def replan_anchor(cfg: Config, commanded_joints: tuple[float, float] | None, body_quat: np.ndarray) -> np.ndarray:
    """The direction a replan is anchored to (3,): the joints being commanded (pan, tilt) [rad] for a body at
    ``body_quat`` (x, y, z, w), the attitude the replan plans for; before the first setpoint the park pose (where
    the daemon left the gimbal when it stopped), as ``pivotd plan --config`` anchors its first replan."""
    joints = park_joints(cfg) if commanded_joints is None else commanded_joints
    return joints_to_world_direction(joints[0], joints[1], np.asarray(body_quat, float), cfg.gimbal.mount)
