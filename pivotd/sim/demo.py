"""The main job on the embedded default: daemon + simulated robot + simulated gimbal.

Starts ``pivotd`` with ``config/demo.yaml`` (gimbal ``mock://`` with a message log, or with ``--backend
mavlink`` / ``dynamixel`` the MAVLink gimbal manager on UDP / the DYNAMIXEL servo chain on a pty of
``tools/mock_gimbal``, logging the same CSV) and
``tools/sim_pose`` on the S-shaped hallway, both talking Zenoh on loopback only. While the robot
walks, a live status line shows what the daemon reports. Afterwards it prints a summary: landmarks
visible per frame with PIVOT versus a forward-facing camera on the same route, the share of the achievable view
(``pivotd bench achievable`` on its recording) the daemon saw, setpoints sent, worst
velocity/acceleration/jerk versus the limits, and draws its recording (``run.mcap``) as ``pivotd plot``
does.
"""

from __future__ import annotations

import argparse
import json
import logging
import os
import signal
import subprocess
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.bench.achievable import achievable, summary_line
from pivotd.bus.probe import BusProbe
from pivotd.config import Config, load_config
from pivotd.sim.analysis import analyse_run, dynamics_lines
from pivotd.sim.launch import REPO, SIMULATED_BACKENDS, derive_config, free_port, spawn, start_gimbal_simulator
from pivotd.viz.figures import build_figure, save_figure
from pivotd.viz.recording import read_recording

log = logging.getLogger("pivotd.demo")


def _status_line(elapsed: float, st: dict) -> str:
    g = st.get("gimbal") or {}
    pl = st.get("planner") or {}
    ctl = st.get("control") or {}
    age = st.get("pose_age_s")
    return (f"t={elapsed:5.1f}s state={st.get('state', '?'):<9} link={st.get('link', '?'):<10} "
            f"pose_age={'-' if age is None else f'{age:.2f}s'} pan={g.get('pan_deg', float('nan')):+7.1f}° "
            f"tilt={g.get('tilt_deg', float('nan')):+6.1f}° visible={pl.get('visible_now', '-')} "
            f"replan_p50={pl.get('solve_ms_p50', '-')}ms rescues_kept/tried={pl.get('rescues_kept', '-')}/"
            f"{pl.get('rescues_tried', '-')} jitter_p99={ctl.get('jitter_ms_p99', '-')}ms")


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


def run_demo(config_path: Path, out_dir: Path, speed: float = 1.2, timeout: float = 90.0,
             live: bool = True, backend: str | None = None) -> DemoSummary:
    """Run the whole demo (with the config's gimbal backend, or ``backend`` against its simulator); returns the
    summary (also printed)."""
    out_dir.mkdir(parents=True, exist_ok=True)
    backend = backend or load_config(config_path).gimbal.backend
    device_log = out_dir / "gimbal_log.csv"
    gimbal, port = start_gimbal_simulator(backend, device_log, out_dir / "mock_gimbal.log")
    config_path = derive_config(config_path, out_dir / "demo.yaml", {"gimbal.backend": backend, "gimbal.port": port})
    cfg = load_config(config_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    py = sys.executable
    recording = out_dir / "run.mcap"
    daemon = spawn([py, "-m", "pivotd.cli", "--config", str(config_path), "--listen", endpoint,
                     "--port", port, "--record", str(recording)], out_dir / "pivotd.log")
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
        if gimbal is not None:
            gimbal.send_signal(signal.SIGTERM)
            try:
                gimbal.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(gimbal.pid, signal.SIGKILL)
                gimbal.wait()
        if probe is not None:
            probe.close()
    obs = probe.observations()
    run = read_recording(recording, config_path)
    report, _ = analyse_run(cfg, obs, device_log, (run.commanded.angles, run.commanded.rates))
    report["daemon_exit_code"] = exit_code
    report["final_status"] = obs.status
    ach = achievable(run)
    report["achievable"] = ach.report
    png = save_figure(build_figure(run, "all", achievable=ach.series), out_dir / "demo.png")
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2, default=str))
    _print_summary(report, cfg, png)
    return DemoSummary(report["frames"], report["visible_mean_pivot"], report["visible_mean_forward"],
                       report["setpoints"], report["within_limits"], exit_code, report)


def _print_summary(r: dict, cfg: Config, png: Path) -> None:
    print()
    print(f"pivotd demo summary ({r['frames']} frames at {cfg.control.joint_state_hz:g} Hz, "
          f"FoV {np.degrees(cfg.pivot.fov):.0f}°, gimbal backend {cfg.gimbal.backend})")
    print(f"  landmarks visible per frame: PIVOT {r['visible_mean_pivot']:.1f}, forward-facing "
          f"{r['visible_mean_forward']:.1f}  ->  {r['visible_ratio']:.2f}x")
    print(f"  frames with < 10 landmarks visible: PIVOT {r['frames_pivot_below_10']}, "
          f"forward-facing {r['frames_forward_below_10']}")
    if "achievable" in r:
        print(summary_line(r["achievable"]))
    print(f"  setpoints sent: {r['setpoints']}")
    for line in dynamics_lines(r):
        print(line)
    print(f"  travel: pan {r['travel_deg'][0]:.0f} deg, tilt {r['travel_deg'][1]:.0f} deg; setpoints above 90 % of the "
          f"velocity limit: pan {r['near_top_speed_share'][0]:.1%}, tilt {r['near_top_speed_share'][1]:.1%}")
    print(f"  pan range {r['pan_range_deg']} deg, tilt range {r['tilt_range_deg']} deg "
          f"(limits pan/tilt {r['joint_limits_deg']})")
    print(f"  daemon exit code after SIGTERM: {r['daemon_exit_code']}")
    print(f"  plot: {png}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "config" / "demo.yaml")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "demo")
    parser.add_argument("--speed", type=float, default=1.2, help="robot speed along the hallway [m/s]")
    parser.add_argument("--backend", choices=SIMULATED_BACKENDS, default=None,
                        help="gimbal backend, driven against its simulator (default: the config's)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    summary = run_demo(args.config, args.out, speed=args.speed, backend=args.backend)
    ok = summary.daemon_exit == 0 and summary.within_limits and summary.frames > 0
    return 0 if ok else 1
