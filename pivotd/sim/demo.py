"""The main job on the embedded default: daemon + simulated robot + in-process mock gimbal.

Starts ``pivotd`` with ``config/demo.yaml`` (gimbal ``mock://`` with a message log) and
``tools/sim_pose`` on the S-shaped hallway, both talking Zenoh on loopback only. While the robot
walks, a live status line shows what the daemon reports. Afterwards it prints a summary: landmarks
visible per frame with PIVOT versus a forward-facing camera on the same route, setpoints sent, worst
velocity/acceleration/jerk versus the limits, and writes a PNG plot.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import socket
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.bus.probe import BusProbe, Observations
from pivotd.config import Config, load_config
from pivotd.gimbal.kinematics import camera_position, joints_to_world_direction
from pivotd.maps.formats import load_landmarks
from pivotd.sim.analysis import read_device_log, setpoint_dynamics, visible_counts

log = logging.getLogger("pivotd.demo")
REPO = Path(__file__).resolve().parents[2]


def derive_config(base: Path, out: Path, changes: dict[str, object]) -> Path:
    """Write a copy of config ``base`` to ``out`` with dotted-key ``changes`` (``"gimbal.port": "mock://"``).

    Relative paths of the base config (``map.file``, ``map.filters.occupancy_file``, ``zenoh.config_file``)
    are made absolute so the copy can live anywhere.
    """
    import yaml

    doc = yaml.safe_load(Path(base).read_text())
    for dotted in ("map.file", "map.filters.occupancy_file", "zenoh.config_file"):
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.get(k) or {}
        value = node.get(keys[-1]) if isinstance(node, dict) else None
        if value:
            node[keys[-1]] = str((Path(base).parent / value).resolve())
    for dotted, value in changes.items():
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.setdefault(k, {})
        node[keys[-1]] = value
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spawn(args: list[str], log_path: Path) -> subprocess.Popen:
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.pop("NOTIFY_SOCKET", None)
    fh = open(log_path, "w")  # noqa: SIM115 - owned by the child for its lifetime
    return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                            cwd=str(REPO), start_new_session=True)


def _status_line(elapsed: float, st: dict) -> str:
    g = st.get("gimbal") or {}
    pl = st.get("planner") or {}
    ctl = st.get("control") or {}
    age = st.get("pose_age_s")
    return (f"t={elapsed:5.1f}s state={st.get('state', '?'):<9} link={st.get('link', '?'):<10} "
            f"pose_age={'-' if age is None else f'{age:.2f}s'} pan={g.get('pan_deg', float('nan')):+7.1f}° "
            f"tilt={g.get('tilt_deg', float('nan')):+6.1f}° visible={pl.get('visible_now', '-')} "
            f"replan_p50={pl.get('solve_ms_p50', '-')}ms jitter_p99={ctl.get('jitter_ms_p99', '-')}ms")


@dataclass(frozen=True)
class DemoSummary:
    """Numbers the demo reports (also returned for tests and benchmarks)."""

    frames: int
    pivot_visible_mean: float
    forward_visible_mean: float
    setpoints: int
    within_limits: bool
    daemon_exit: int | None
    report: dict


def analyse(cfg: Config, obs: Observations, device_log: Path) -> tuple[dict, dict]:
    """Per-frame visibility (PIVOT vs forward-facing) and setpoint dynamics; returns (report, series)."""
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
    dyn = setpoint_dynamics(dev.sp_pos, cfg.control.dt, cfg.motion.pan, cfg.motion.tilt, rates=dev.sp_rate)
    lim = cfg.gimbal.limits
    report = {
        "frames": len(frames),
        "visible_mean_pivot": float(n_piv.mean()),
        "visible_mean_forward": float(n_fwd.mean()),
        "visible_ratio": float(n_piv.mean() / max(n_fwd.mean(), 1e-9)),
        "frames_pivot_below_10": int((n_piv < 10).sum()),
        "frames_forward_below_10": int((n_fwd < 10).sum()),
        "setpoints": int(dev.sp_pos.shape[0]),
        "max_velocity_deg_s": np.degrees(dyn.max_velocity).round(2).tolist(),
        "max_acceleration_deg_s2": np.degrees(dyn.max_acceleration).round(2).tolist(),
        "max_jerk_deg_s3": np.degrees(dyn.max_jerk).round(1).tolist(),
        "velocity_ratio": dyn.velocity_ratio.round(3).tolist(),
        "acceleration_ratio": dyn.acceleration_ratio.round(3).tolist(),
        "jerk_ratio": dyn.jerk_ratio.round(3).tolist(),
        "within_limits": dyn.within_limits,
        "jerk_allowance_deg_s3": round(float(np.degrees(dyn.allowance_jerk)), 2),
        "pan_range_deg": np.degrees([dyn.position_min[0], dyn.position_max[0]]).round(2).tolist(),
        "tilt_range_deg": np.degrees([dyn.position_min[1], dyn.position_max[1]]).round(2).tolist(),
        "joint_limits_deg": np.degrees([lim.pan_min, lim.pan_max, lim.tilt_min, lim.tilt_max]).round(1).tolist(),
    }
    series = {"t": np.array([f[0] for f in frames]), "cams": cams, "pivot": piv, "forward": fwd,
              "n_pivot": n_piv, "n_forward": n_fwd, "pan": np.array([f[1] for f in frames]),
              "tilt": np.array([f[2] for f in frames]), "points": cloud.points}
    return report, series


def plot(series: dict, path: Path) -> None:
    """Route and viewing directions from above, visible counts and pan/tilt over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(14, 6))
    ax = axes[0]
    pts, cams = series["points"], series["cams"]
    ax.scatter(pts[:, 0], pts[:, 1], s=1, c="0.6", label="landmarks")
    ax.plot(cams[:, 0], cams[:, 1], "k-", lw=1, label="route")
    step = max(1, cams.shape[0] // 60)
    for key, color in (("forward", "tab:red"), ("pivot", "tab:blue")):
        d = series[key][::step]
        ax.quiver(cams[::step, 0], cams[::step, 1], d[:, 0], d[:, 1], color=color, scale=25, width=0.003,
                  label=f"{key} view")
    ax.set_aspect("equal")
    ax.set_title("route and viewing directions (top view)")
    ax.legend(loc="best", fontsize=8)
    t = series["t"] - series["t"][0]
    ax2 = axes[1]
    ax2.plot(t, series["n_pivot"], color="tab:blue", label="visible, PIVOT")
    ax2.plot(t, series["n_forward"], color="tab:red", label="visible, forward-facing")
    ax2.set_xlabel("time [s]")
    ax2.set_ylabel("landmarks in the FoV")
    ax3 = ax2.twinx()
    ax3.plot(t, np.degrees(series["pan"]), "g--", lw=1, label="pan [deg]")
    ax3.plot(t, np.degrees(series["tilt"]), "m--", lw=1, label="tilt [deg]")
    ax3.set_ylabel("measured joint angle [deg]")
    lines = ax2.get_legend_handles_labels()
    lines3 = ax3.get_legend_handles_labels()
    ax2.legend(lines[0] + lines3[0], lines[1] + lines3[1], loc="upper left", fontsize=8)
    ax2.set_title("visibility and gimbal motion over time")
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def run_demo(config_path: Path, out_dir: Path, speed: float = 1.2, timeout: float = 90.0,
             live: bool = True) -> DemoSummary:
    """Run the whole demo; returns the summary (also printed)."""
    cfg = load_config(config_path)
    out_dir.mkdir(parents=True, exist_ok=True)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    device_log = out_dir / "gimbal_log.csv"
    py = sys.executable
    daemon = spawn([py, "-m", "pivotd.cli", "--config", str(config_path), "--listen", endpoint,
                     "--port", f"mock://?log={device_log}"], out_dir / "pivotd.log")
    sim = None
    probe = None
    exit_code = None
    try:
        probe = BusProbe.connect(endpoint, cfg.topics)
        start = time.monotonic()
        while not probe.status and time.monotonic() - start < 20:
            if daemon.poll() is not None:
                raise RuntimeError(f"pivotd exited with {daemon.returncode}; see {out_dir / 'pivotd.log'}")
            time.sleep(0.1)
        sim = spawn([py, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--connect", endpoint,
                      "--speed", str(speed), "--rate", "50", "--wait-subscribers", "10", "--quiet"],
                     out_dir / "sim_pose.log")
        start = time.monotonic()
        last_print = 0.0
        while sim.poll() is None and time.monotonic() - start < timeout:
            if daemon.poll() is not None:
                raise RuntimeError(f"pivotd exited with {daemon.returncode}; see {out_dir / 'pivotd.log'}")
            now = time.monotonic()
            status = probe.status
            if live and now - last_print >= 1.0 and status:
                print(_status_line(now - start, status), flush=True)
                last_print = now
            time.sleep(0.05)
        time.sleep(0.5)
        daemon.send_signal(signal.SIGTERM)
        try:
            exit_code = daemon.wait(timeout=15)
        except subprocess.TimeoutExpired:
            exit_code = None
    finally:
        for proc in (sim, daemon):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        if probe is not None:
            probe.close()
    obs = probe.observations()
    report, series = analyse(cfg, obs, device_log)
    report["daemon_exit_code"] = exit_code
    report["final_status"] = obs.status
    png = out_dir / "demo.png"
    plot(series, png)
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2, default=str))
    _print_summary(report, cfg, png)
    return DemoSummary(report["frames"], report["visible_mean_pivot"], report["visible_mean_forward"],
                       report["setpoints"], report["within_limits"], exit_code, report)


def _print_summary(r: dict, cfg: Config, png: Path) -> None:
    print()
    print(f"pivotd demo summary ({r['frames']} frames at {cfg.control.joint_state_hz:g} Hz, "
          f"FoV {np.degrees(cfg.pivot.fov):.0f}°)")
    print(f"  landmarks visible per frame: PIVOT {r['visible_mean_pivot']:.1f}, forward-facing "
          f"{r['visible_mean_forward']:.1f}  ->  {r['visible_ratio']:.2f}x")
    print(f"  frames with < 10 landmarks visible: PIVOT {r['frames_pivot_below_10']}, "
          f"forward-facing {r['frames_forward_below_10']}")
    print(f"  setpoints sent: {r['setpoints']}")
    for i, axis in enumerate(("pan", "tilt")):
        print(f"  {axis:<4} worst velocity {r['max_velocity_deg_s'][i]:7.2f} deg/s ({r['velocity_ratio'][i]:.0%} "
              f"of limit), acceleration {r['max_acceleration_deg_s2'][i]:7.2f} deg/s² "
              f"({r['acceleration_ratio'][i]:.0%}), jerk {r['max_jerk_deg_s3'][i]:8.1f} deg/s³ "
              f"({r['jerk_ratio'][i]:.0%})")
    print(f"  within limits (acceleration and jerk from the setpoint rates; the wire's µrad/s resolution allows "
          f"±{r['jerk_allowance_deg_s3']} deg/s³): {'yes' if r['within_limits'] else 'NO'}")
    print(f"  pan range {r['pan_range_deg']} deg, tilt range {r['tilt_range_deg']} deg "
          f"(limits pan/tilt {r['joint_limits_deg']})")
    print(f"  daemon exit code after SIGTERM: {r['daemon_exit_code']}")
    print(f"  plot: {png}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "config" / "demo.yaml")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "demo")
    parser.add_argument("--speed", type=float, default=1.2, help="robot speed along the hallway [m/s]")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    summary = run_demo(args.config, args.out, speed=args.speed)
    ok = summary.daemon_exit == 0 and summary.within_limits and summary.frames > 0
    return 0 if ok else 1
