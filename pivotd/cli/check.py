"""``pivotd check --config FILE``: validate a config, load its map, print a concise summary.

Exits 0 when everything is usable; a bad config or map raises ConfigError / InputError, which the CLI
prints as one line before exiting 2.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from pivotd.config import Config, load_config
from pivotd.errors import ConfigError, InputError
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.occlusion import OccupancyGrid


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="pivotd YAML config to validate")


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    m = cfg.map  # loaded as the daemon loads it (pivotd.daemon.wiring), so that check fails where it would
    cloud = (load_landmarks(m.file, weight_property=m.weight_property, allow_empty=m.allow_empty)
             if m.file is not None else None)
    _check_occupancy(cfg, cloud)
    sys.stdout.write("\n".join(summary_lines(cfg, cloud)) + "\n")
    if (warning := bus_exposure_warning(cfg)) is not None:
        sys.stderr.write(f"warning: {warning}\n")
    return 0


def bus_exposure_warning(cfg: Config) -> str | None:
    """The one-line warning when the daemon's Zenoh session would let unauthenticated peers publish its inputs."""
    from pivotd.bus.security import exposure_warning, input_key_exprs
    from pivotd.bus.session import build_config

    z = cfg.zenoh
    return exposure_warning(build_config(z.mode, z.connect, z.listen, z.config_file, z.multicast_scouting,
                                         z.security, input_key_exprs(cfg.topics)))


def _check_occupancy(cfg: Config, cloud: LandmarkCloud | None) -> None:
    """Build the occupancy grid the daemon will build, so that a voxel too small for the map's extent fails here."""
    f = cfg.map.filters
    if f.occlusion_voxel is None:
        return
    points = load_landmarks(f.occupancy_file).points if f.occupancy_file is not None else (
        cloud.points if cloud is not None else None)
    if points is None:
        return
    try:
        OccupancyGrid.from_points(points, f.occlusion_voxel)
    except InputError as exc:
        raise ConfigError(f"{cfg.source}: map.filters.occlusion_voxel: {exc}") from None


def _deg(rad: float) -> str:
    return f"{math.degrees(rad):g}"


def summary_lines(cfg: Config, cloud: LandmarkCloud | None) -> list[str]:
    """Human-readable summary of a validated config and its loaded map (one item per line)."""
    z, t, g, m, c = cfg.zenoh, cfg.topics, cfg.gimbal, cfg.motion, cfg.control
    lim = g.limits
    if cloud is None:
        map_line = f"map: none (landmarks from {t.landmarks})"
    elif len(cloud) == 0:
        map_line = f"map: {cfg.map.file} (empty; landmarks from {t.landmarks})"
    else:
        lo, hi = cloud.points.min(axis=0), cloud.points.max(axis=0)
        bounds = " ".join(f"[{a:.2f}, {b:.2f}]" for a, b in zip(lo, hi, strict=True))
        weights = "" if np.all(cloud.weights == 1.0) else f", weights {cloud.weights.min():g}..{cloud.weights.max():g}"
        map_line = f"map: {cfg.map.file} ({len(cloud)} landmarks, bounds x y z {bounds} m{weights})"
    pan_range = "continuous" if lim.continuous_pan else f"[{_deg(lim.pan_min)}, {_deg(lim.pan_max)}]"
    f = cfg.map.filters
    return [
        f"config: {cfg.source} OK",
        f"node: {cfg.name} (status key {cfg.status_key})",
        f"zenoh: {z.mode}, connect {list(z.connect)}, listen {list(z.listen)}, "
        f"multicast scouting {'on' if z.multicast_scouting else 'off'}"
        + (f", config file {z.config_file}" if z.config_file else "")
        + (", mutual TLS" if z.security.tls else "")
        + (", access control on the inputs" if z.security.access_control else ""),
        f"topics (domain {t.domain_id}): pose "
        + (f"from TF {t.map_frame} -> {t.base_frame} on {t.tf}, {t.tf_static}" if t.pose_from_tf else
           f"{t.pose} [{t.pose_type}]")
        + f", path {t.path}, landmarks {t.landmarks}, "
        f"targets {t.targets}, joint states {t.joint_states} ({', '.join(t.joint_names)}), view plan {t.view_plan}, "
        f"frame {t.frame_id}" + (", stamps from /clock" if t.use_sim_time else ""),
        map_line,
        f"filters: range {f.min_range:g}..{f.max_range:g} m"
        + (f", view angle ≤ {f.max_view_angle_deg:g}°" if f.max_view_angle is not None else ""),
        f"pivot: fov {cfg.pivot.fov_deg:g}° (α {math.degrees(cfg.pivot.half_angle):g}°), λ {cfg.pivot.lam:g}, "
        f"transition width {_deg(cfg.pivot.transition_width)}°, {cfg.pivot.iterations} iterations",
        f"planner: spacing {cfg.planner.waypoint_spacing:g} m, horizon {cfg.planner.horizon} waypoints, "
        f"replan {cfg.planner.replan_hz:g} Hz",
        f"gimbal: port {g.port} @ {g.baud} baud, pan {pan_range}°, tilt [{_deg(lim.tilt_min)}, {_deg(lim.tilt_max)}]°, "
        f"park ({_deg(g.park_pan)}, {_deg(g.park_tilt)})°, watchdog {g.watchdog_ms} ms, backend {g.backend}",
        f"motion: pan {_deg(m.pan.max_velocity)}°/s {_deg(m.pan.max_acceleration)}°/s² "
        f"{_deg(m.pan.max_jerk)}°/s³; tilt {_deg(m.tilt.max_velocity)}°/s {_deg(m.tilt.max_acceleration)}°/s² "
        f"{_deg(m.tilt.max_jerk)}°/s³; deadband {_deg(m.deadband)}°",
        f"control: {c.rate_hz:g} Hz, pose timeout {c.pose_timeout_s:g} s, status {c.status_hz:g} Hz, "
        f"joint states {c.joint_state_hz:g} Hz",
    ]
