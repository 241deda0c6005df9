"""``pivotd check --config FILE``: validate a config, load its map, print a concise summary.

Exits 0 when everything is usable; a bad config or map, or anything that would stop ``run`` or leave the gimbal
unreachable (pivotd.cli.check_rules), raises ConfigError / InputError, which the CLI prints as one line before
exiting 2. Implausible values are ``warning:`` lines on stderr; ``--strict`` makes them exit 1.
"""

from __future__ import annotations

import argparse
import math
import sys

import numpy as np

from pivotd.cli.check_rules import (
    Finding,
    RawConfig,
    Severity,
    filter_findings,
    live_findings,
    map_has_directions,
    plausibility_findings,
    static_findings,
    under_system_unit,
)
from pivotd.config import Config, load_config
from pivotd.errors import ConfigError, InputError
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.occlusion import OccupancyGrid


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="pivotd YAML config to validate")
    parser.add_argument("--port", help="check this gimbal port instead of gimbal.port, as `run --port` uses it")
    parser.add_argument("--offline", action="store_true",
                        help="skip the live probes (open the serial device, connect to a TCP port or the Zenoh router)")
    parser.add_argument("--strict", action="store_true", help="exit 1 when there are warnings")


def run(args: argparse.Namespace) -> int:
    cfg = load_config(args.config)
    if getattr(args, "port", None) is not None:
        cfg = cfg.with_overrides(port=args.port)
    raw = RawConfig.read(cfg)
    static = static_findings(cfg, raw, under_systemd=under_system_unit(), offline=getattr(args, "offline", False))
    _raise_first_error(cfg, static)
    m = cfg.map  # loaded as the daemon loads it (pivotd.daemon.wiring), so that check fails where it would
    cloud = (load_landmarks(m.file, weight_property=m.weight_property, allow_empty=m.allow_empty)
             if m.file is not None else None)
    _check_occupancy(cfg, cloud)
    if not getattr(args, "offline", False):
        _raise_first_error(cfg, live_findings(cfg, raw))
    warnings = [f.text(cfg.source) for f in
                [*static, *plausibility_findings(cfg, raw),
                 *filter_findings(cfg, raw, cloud)] if f.severity is Severity.WARNING]
    if (exposure := bus_exposure_warning(cfg)) is not None:
        warnings.append(exposure)
    sys.stdout.write("\n".join(summary_lines(cfg, cloud, raw)) + "\n")
    for warning in warnings:
        sys.stderr.write(f"warning: {warning}\n")
    return 1 if warnings and getattr(args, "strict", False) else 0


def _raise_first_error(cfg: Config, findings: list[Finding]) -> None:
    for f in findings:
        if f.severity is Severity.ERROR:
            raise ConfigError(f.text(cfg.source))


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


def summary_lines(cfg: Config, cloud: LandmarkCloud | None, raw: RawConfig | None = None) -> list[str]:
    """Human-readable summary of a validated config and its loaded map (one item per line); ``raw`` (the file
    as written) adds the mount's angles as configured."""
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
    map_line += f"; observation directions: {'yes' if map_has_directions(cloud) else 'no'}"
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
        mount_line(cfg, raw),
        *backend_lines(cfg),
        f"motion: pan {_deg(m.pan.max_velocity)}°/s {_deg(m.pan.max_acceleration)}°/s² "
        f"{_deg(m.pan.max_jerk)}°/s³; tilt {_deg(m.tilt.max_velocity)}°/s {_deg(m.tilt.max_acceleration)}°/s² "
        f"{_deg(m.tilt.max_jerk)}°/s³; deadband {_deg(m.deadband)}°",
        f"control: {c.rate_hz:g} Hz, pose timeout {c.pose_timeout_s:g} s, status {c.status_hz:g} Hz, "
        f"joint states {c.joint_state_hz:g} Hz",
    ]


def mount_line(cfg: Config, raw: RawConfig | None) -> str:
    """The gimbal base in the body frame: translation [m] and the roll, pitch, yaw [deg] as configured."""
    mount = cfg.gimbal.mount
    rpy = raw.value("gimbal.mount.rpy_deg") if raw is not None else None
    xyz = ", ".join(f"{v:g}" for v in mount.translation)
    angles = ", ".join(f"{v:g}" for v in rpy) if isinstance(rpy, list) else "0, 0, 0"
    return f"mount: xyz [{xyz}] m, rpy [{angles}]°"


def backend_lines(cfg: Config) -> list[str]:
    """What the backend maps the axes to: the servos' ids and directions, or the MAVLink identities."""
    g = cfg.gimbal
    if g.backend == "dynamixel":
        d = g.dynamixel
        turn = {False: "as mounted", True: "reversed"}
        return [f"servos: pan id {d.pan_id} {turn[d.pan_reversed]}, 0° at tick {d.pan_zero_tick}; tilt id "
                f"{d.tilt_id} {turn[d.tilt_reversed]}, 0° at tick {d.tilt_zero_tick}; {g.baud} baud"]
    if g.backend == "mavlink":
        v = g.mavlink
        return [f"mavlink: system/component {v.system_id}/{v.component_id}, gimbal manager "
                f"{v.target_system or 'first heard'}/{v.target_component or 'first heard'}, gimbal device "
                f"{v.gimbal_device_id or 'all'}"]
    return []
