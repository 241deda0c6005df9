"""Offline analysis of a run: the device's message log and per-frame landmark visibility.

Used by the demo, the end-to-end tests and the control benchmark (:func:`analyse_run`) to judge what the gimbal
actually received and where it actually looked.
"""

from __future__ import annotations

import csv
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from pivotd.gimbal.dynamixel_table import POSITION_RESOLUTION
from pivotd.gimbal.kinematics import camera_position, joints_to_world_direction
from pivotd.gimbal.motion import AxisLimits
from pivotd.maps.formats import load_landmarks

if TYPE_CHECKING:
    from pivotd.bus.probe import Observations
    from pivotd.config import Config


@dataclass(frozen=True)
class DeviceLog:
    """A device message log (``tools/mock_gimbal --log`` / ``mock://?log=``).

    setpoints: host_time [s] (N,), pan/tilt [rad] (N,), rates [rad/s] (N, 2);
    states: device time [s] (K,), pan/tilt [rad] (K,), mode (K,), faults (K,);
    other: (type, device time) of every other message (ENABLE, CLEAR_FAULT, ...).
    """

    sp_time: np.ndarray
    sp_pos: np.ndarray
    sp_rate: np.ndarray
    sp_rx_time: np.ndarray
    st_time: np.ndarray
    st_pos: np.ndarray
    st_mode: np.ndarray
    st_faults: np.ndarray
    other: list[tuple[str, float, str]]


def read_device_log(path: str | Path) -> DeviceLog:
    """Parse the CSV written by the device model's message log."""
    sp_t, sp_p, sp_r, sp_rx, st_t, st_p, st_m, st_f = [], [], [], [], [], [], [], []
    other: list[tuple[str, float, str]] = []
    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            t = float(row["t_s"])
            if row["dir"] == "rx" and row["type"] == "SETPOINT":
                sp_t.append(int(row["host_time_us"]) * 1e-6)
                sp_rx.append(t)
                sp_p.append((float(row["pan"]), float(row["tilt"])))
                sp_r.append((float(row["pan_rate"]), float(row["tilt_rate"])))
            elif row["dir"] == "tx" and row["type"] == "STATE":
                st_t.append(t)
                st_p.append((float(row["pan"]), float(row["tilt"])))
                st_m.append(int(row["mode"]))
                st_f.append(int(row["faults"]))
            else:
                other.append((f"{row['dir']}:{row['type']}", t, row.get("detail", "")))

    def arr(x: list, cols: int | None = None) -> np.ndarray:
        a = np.asarray(x, dtype=float)
        return a.reshape(-1, cols) if cols else a

    return DeviceLog(arr(sp_t), arr(sp_p, 2), arr(sp_r, 2), arr(sp_rx), arr(st_t), arr(st_p, 2),
                     np.asarray(st_m, int), np.asarray(st_f, int), other)


WIRE_RESOLUTION = 1e-6  # [rad]: SETPOINT angles are int32 micro-radians on the wire


@dataclass(frozen=True)
class DynamicsReport:
    """Worst |velocity|, |acceleration|, |jerk| per axis (2,) of a setpoint stream, their ratio to the limits,
    and the finite-difference error that the wire's angle resolution alone can cause (``allowance_*``); how far
    each axis travelled (2,) [rad] and the share of setpoints (2,) at more than 90 % of its velocity limit."""

    max_velocity: np.ndarray
    max_acceleration: np.ndarray
    max_jerk: np.ndarray
    velocity_ratio: np.ndarray
    acceleration_ratio: np.ndarray
    jerk_ratio: np.ndarray
    position_min: np.ndarray
    position_max: np.ndarray
    allowance_velocity: float = 0.0
    allowance_acceleration: float = 0.0
    allowance_jerk: float = 0.0
    limits: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None
    travel: np.ndarray | None = None
    near_top_speed: np.ndarray | None = None

    @property
    def worst_ratio(self) -> float:
        """Largest of the raw ratios (quantization included)."""
        return float(max(self.velocity_ratio.max(), self.acceleration_ratio.max(), self.jerk_ratio.max()))

    def allowed_ratio(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """The largest velocity, acceleration and jerk ratio (2,) each that :attr:`within_limits` accepts: the
        limit plus the resolution's allowance, over the limit."""
        if self.limits is None:
            return np.ones(2), np.ones(2), np.ones(2)
        lv, la, lj = self.limits
        return (1 + self.allowance_velocity / lv, 1 + self.allowance_acceleration / la, 1 + self.allowance_jerk / lj)

    @property
    def within_limits(self) -> bool:
        """Every derivative within its limit plus the wire-resolution allowance."""
        if self.limits is None:
            return self.worst_ratio <= 1.0
        lv, la, lj = self.limits
        return bool(np.all(self.max_velocity <= lv + self.allowance_velocity)
                    and np.all(self.max_acceleration <= la + self.allowance_acceleration)
                    and np.all(self.max_jerk <= lj + self.allowance_jerk))


def setpoint_dynamics(positions: np.ndarray, dt: float, pan: AxisLimits, tilt: AxisLimits,
                      rates: np.ndarray | None = None, resolution: float = WIRE_RESOLUTION) -> DynamicsReport:
    """Dynamics of setpoints streamed at the constant control period ``dt`` [s].

    positions: (N, 2) [rad]; rates: (N, 2) [rad/s], the SETPOINT rate field, or None. The generator
    advances exactly one period per setpoint, so differences use ``dt``, not the (jittery) send times.
    Velocity is the larger of |rate| and the position difference; acceleration and jerk come from the
    rates when given (micro-radian-per-second resolution: errors ≤ 2·res/dt, 4·res/dt²), otherwise from
    positions (errors ≤ 2·res/dt², 4·res/dt³ for micro-radian angles). ``allowance_*`` hold these bounds.
    """
    p = np.asarray(positions, float)
    v_pos = np.diff(p, axis=0) / dt

    def peak(x: np.ndarray) -> np.ndarray:
        return np.abs(x).max(axis=0) if x.shape[0] else np.zeros(2)

    if rates is not None:
        r = np.asarray(rates, float)
        a = np.diff(r, axis=0) / dt
        j = np.diff(a, axis=0) / dt
        mv = np.maximum(peak(v_pos), peak(r))
        allow = (resolution / dt, 2 * resolution / dt, 4 * resolution / dt**2)
    else:
        a = np.diff(v_pos, axis=0) / dt
        j = np.diff(a, axis=0) / dt
        mv = peak(v_pos)
        allow = (resolution / dt, 2 * resolution / dt**2, 4 * resolution / dt**3)
    lim_v = np.array([pan.max_velocity, tilt.max_velocity])
    lim_a = np.array([pan.max_acceleration, tilt.max_acceleration])
    lim_j = np.array([pan.max_jerk, tilt.max_jerk])
    ma, mj = peak(a), peak(j)
    speed = np.abs(np.asarray(rates, float)) if rates is not None else np.abs(v_pos)
    near = (speed > 0.9 * lim_v).mean(axis=0) if speed.shape[0] else np.zeros(2)
    return DynamicsReport(mv, ma, mj, mv / lim_v, ma / lim_a, mj / lim_j,
                          p.min(axis=0) if p.size else np.zeros(2), p.max(axis=0) if p.size else np.zeros(2),
                          *allow, (lim_v, lim_a, lim_j), travel=np.abs(v_pos).sum(axis=0) * dt, near_top_speed=near)


def device_setpoint_dynamics(cfg: Config, dev: DeviceLog) -> DynamicsReport:
    """:func:`setpoint_dynamics` of what the device logged, as its backend's wire carries it: angles and rates at
    micro-radian resolution, or (dynamixel) goal positions only, in ticks of 2π/4096."""
    if cfg.gimbal.backend == "dynamixel":
        return setpoint_dynamics(dev.sp_pos, cfg.control.dt, cfg.motion.pan, cfg.motion.tilt,
                                 resolution=POSITION_RESOLUTION)
    return setpoint_dynamics(dev.sp_pos, cfg.control.dt, cfg.motion.pan, cfg.motion.tilt, rates=dev.sp_rate)


def commanded_setpoint_dynamics(cfg: Config, positions: np.ndarray, rates: np.ndarray) -> DynamicsReport:
    """:func:`setpoint_dynamics` of the setpoints the daemon sent, as it computed them (``pivotd --record``'s
    command channel: pan/tilt (N, 2) [rad] and rates (N, 2) [rad/s]), judged at the micro-radian resolution of
    pivotd's own protocol: what was commanded before a backend's wire rounded it (DYNAMIXEL: to position ticks)."""
    return setpoint_dynamics(positions, cfg.control.dt, cfg.motion.pan, cfg.motion.tilt, rates=rates)


def dynamics_report(cfg: Config, dev: DeviceLog, commanded: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
    """The setpoint-dynamics part of :func:`analyse_run`'s report: worst velocity, acceleration and jerk per axis,
    their ratios to the limits, whether they are within the limits, the ratios that verdict allows
    (``allowed_ratio``) and what was judged (``dynamics_source``).

    The device's log is judged, except on the DYNAMIXEL backend when ``commanded`` (angles (N, 2) [rad], rates
    (N, 2) [rad/s] of the setpoints sent, from the recording) is given: that wire carries goal positions in ticks
    of 0.088° and no rates, and differences of ticks show the quantisation (one tick between two periods reads as
    hundreds of deg/s² and more than 10⁵ deg/s³), not the motion; the ticks are reported apart (``wire_*``)."""
    ticks = cfg.gimbal.backend == "dynamixel"
    tick_deg = float(np.degrees(POSITION_RESOLUTION))
    if ticks and commanded is not None and len(commanded[0]) > 2:
        dyn = commanded_setpoint_dynamics(cfg, commanded[0], commanded[1])
        source = (f"the setpoints sent, as recorded before the wire rounds them to goal-position ticks of "
                  f"{tick_deg:.4f}°")
    else:
        dyn = device_setpoint_dynamics(cfg, dev)
        source = (f"finite differences of the goal positions the servos received: ticks of {tick_deg:.4f}°, the "
                  "wire's quantisation, not the motion (no recording of the setpoints sent)" if ticks
                  else "the setpoints the device received, acceleration and jerk from their rates")
    allowed = dyn.allowed_ratio()
    out = {
        "dynamics_source": source,
        "max_velocity_deg_s": np.degrees(dyn.max_velocity).round(2).tolist(),
        "max_acceleration_deg_s2": np.degrees(dyn.max_acceleration).round(2).tolist(),
        "max_jerk_deg_s3": np.degrees(dyn.max_jerk).round(1).tolist(),
        "velocity_ratio": dyn.velocity_ratio.round(4).tolist(),
        "acceleration_ratio": dyn.acceleration_ratio.round(4).tolist(),
        "jerk_ratio": dyn.jerk_ratio.round(4).tolist(),
        "allowed_ratio": {k: np.asarray(v).round(4).tolist() for k, v in zip(("velocity", "acceleration", "jerk"),
                                                                              allowed, strict=True)},
        "within_limits": dyn.within_limits,
        "jerk_allowance_deg_s3": round(float(np.degrees(dyn.allowance_jerk)), 2),
        "travel_deg": np.degrees(dyn.travel).round(1).tolist(),
        "near_top_speed_share": np.round(dyn.near_top_speed, 4).tolist(),
        "pan_range_deg": np.degrees([dyn.position_min[0], dyn.position_max[0]]).round(2).tolist(),
        "tilt_range_deg": np.degrees([dyn.position_min[1], dyn.position_max[1]]).round(2).tolist(),
    }
    if ticks:
        wire = device_setpoint_dynamics(cfg, dev)
        out["wire_tick_deg"] = round(tick_deg, 4)
        out["wire_goal_positions"] = int(dev.sp_pos.shape[0])
        out["wire_max_velocity_deg_s"] = np.degrees(wire.max_velocity).round(2).tolist()
    return out


def visible_counts(points: np.ndarray, cameras: np.ndarray, directions: np.ndarray, half_angle: float,
                   min_range: float = 0.0, max_range: float = np.inf, chunk: int = 64) -> np.ndarray:
    """Hard count (T,) of ``points`` (M, 3) inside the cone of half-angle [rad] around ``directions`` (T, 3)
    from ``cameras`` (T, 3), counting only landmarks at a distance in [min_range, max_range] [m]."""
    points = np.asarray(points, float)
    out = np.zeros(cameras.shape[0], dtype=np.int64)
    for start in range(0, cameras.shape[0], chunk):
        rel = points[None, :, :] - cameras[start:start + chunk, None, :]
        ok = in_cone(rel, directions[start:start + chunk], half_angle, min_range, max_range)
        out[start:start + chunk] = ok.sum(axis=1)
    return out


def in_cone(rel: np.ndarray, directions: np.ndarray, half_angle: float, min_range: float = 0.0,
            max_range: float = np.inf) -> np.ndarray:
    """Which landmarks lie in the cone: ``rel`` (..., M, 3) landmark minus camera [m], ``directions`` (..., 3)
    optical axes (any length); returns (..., M) bool for half-angle [rad] and distance in [min_range, max_range]."""
    d = directions / np.linalg.norm(directions, axis=-1, keepdims=True)
    dist = np.linalg.norm(rel, axis=-1)
    cos_t = np.einsum("...mk,...k->...m", rel, d) / np.maximum(dist, 1e-12)
    return (dist >= min_range) & (dist <= max_range) & (dist > 1e-9) & (cos_t >= np.cos(half_angle))


def analyse_run(cfg: Config, obs: Observations, device_log: Path,
                commanded: tuple[np.ndarray, np.ndarray] | None = None) -> tuple[dict, dict]:
    """Per-frame visibility (PIVOT vs forward-facing) and setpoint dynamics (:func:`dynamics_report`, with the
    recorded setpoints sent as ``commanded``); returns (report, series)."""
    cloud = load_landmarks(cfg.map.file)
    poses, joints = obs.poses, obs.joints
    if not poses or not joints:
        raise RuntimeError("no poses or joint states were received during the demo")
    pose_t = np.array([p[0] for p in poses])
    frames = []
    for t, pan, tilt in joints:
        i = int(np.searchsorted(pose_t, t, side="right")) - 1
        if i < 0 or t - pose_t[i] > cfg.control.pose_timeout_s:
            continue  # no fresh pose at this frame (before the start or after the route ended)
        frames.append((t, pan, tilt, poses[i][1], poses[i][2]))
    mount = cfg.gimbal.mount
    cams = np.array([camera_position(f[3], f[4], mount) for f in frames])
    piv = np.array([joints_to_world_direction(f[1], f[2], f[4], mount) for f in frames])
    fwd = np.array([joints_to_world_direction(0.0, 0.0, f[4], mount) for f in frames])
    flt = cfg.map.filters
    n_piv = visible_counts(cloud.points, cams, piv, cfg.pivot.half_angle, flt.min_range, flt.max_range)
    n_fwd = visible_counts(cloud.points, cams, fwd, cfg.pivot.half_angle, flt.min_range, flt.max_range)
    dev = read_device_log(device_log)
    lim = cfg.gimbal.limits
    report = {
        "frames": len(frames),
        "visible_mean_pivot": float(n_piv.mean()),
        "visible_mean_forward": float(n_fwd.mean()),
        "visible_ratio": float(n_piv.mean() / max(n_fwd.mean(), 1e-9)),
        "frames_pivot_below_10": int((n_piv < 10).sum()),
        "frames_forward_below_10": int((n_fwd < 10).sum()),
        "setpoints": int(dev.sp_pos.shape[0]),
        **dynamics_report(cfg, dev, commanded),
        "joint_limits_deg": np.degrees([lim.pan_min, lim.pan_max, lim.tilt_min, lim.tilt_max]).round(1).tolist(),
    }
    series = {"t": np.array([f[0] for f in frames]), "cams": cams, "pivot": piv, "forward": fwd,
              "n_pivot": n_piv, "n_forward": n_fwd, "pan": np.array([f[1] for f in frames]),
              "tilt": np.array([f[2] for f in frames]), "points": cloud.points}
    return report, series


def dynamics_lines(r: dict) -> list[str]:
    """The summary's lines on setpoint dynamics (worst figures per axis, their share of the limits, the verdict
    and what was judged), from :func:`dynamics_report`'s keys; the verdict is computed from
    the figures printed, the share it allows is printed beside it."""
    lines = []
    for i, axis in enumerate(("pan", "tilt")):
        lines.append(f"  {axis:<4} worst velocity {r['max_velocity_deg_s'][i]:7.2f} deg/s "
                     f"({r['velocity_ratio'][i]:.1%} of limit), acceleration {r['max_acceleration_deg_s2'][i]:7.2f} "
                     f"deg/s² ({r['acceleration_ratio'][i]:.1%}), jerk {r['max_jerk_deg_s3'][i]:8.1f} deg/s³ "
                     f"({r['jerk_ratio'][i]:.1%})")
    allowed = r["allowed_ratio"]
    shares = "/".join(f"{max(allowed[k]):.1%}" for k in ("velocity", "acceleration", "jerk"))
    lines.append(f"  judged: {r['dynamics_source']}")
    lines.append(f"  within limits (the resolution allows velocity/acceleration/jerk up to {shares} of the limits): "
                 f"{'yes' if r['within_limits'] else 'NO'}")
    if "wire_tick_deg" in r:
        lines.append(f"  wire: {r['wire_goal_positions']} goal positions in ticks of {r['wire_tick_deg']:g}°, no "
                     f"rates; largest change per period {max(r['wire_max_velocity_deg_s']):.1f} deg/s")
    return lines
