"""``pivotd bench control``: the real daemon under load, measured from outside.

Runs ``pivotd`` (config/demo.yaml: 100 Hz control) against the simulated gimbal of each ``--backend`` (pivot:
the in-process mock; mavlink: the gimbal manager simulator on UDP), one after the other in one invocation, with
replanning at ``--replan-hz`` while ``tools/sim_pose`` walks the hallway at 50 Hz, then reads the daemon's own
status: control period jitter (deadline to wake-up), latency from a pose arriving to the first setpoint that
uses it, replanning time, and checks the setpoints the device logged against the limits. A second run loads a
map of ``--rss-landmarks`` random landmarks and reports the daemon's resident memory while tracking.
"""

from __future__ import annotations

import argparse
import json
import signal
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from pivotd.bench._procs import process_tree, rss_mb
from pivotd.progress import with_progress

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "config" / "demo.yaml"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--duration", type=float, default=20.0, help="seconds of tracking to measure")
    parser.add_argument("--replan-hz", type=float, default=10.0)
    parser.add_argument("--control-hz", type=float, default=100.0)
    parser.add_argument("--realtime-priority", type=int, default=0,
                        help="control.realtime_priority (SCHED_FIFO; needs CAP_SYS_NICE)")
    parser.add_argument("--rss-landmarks", type=int, default=1_000_000, help="map size for the memory run (0: skip)")
    parser.add_argument("--json", type=Path, help="write the results to this file")
    parser.add_argument("--backend", nargs="+", default=["pivot"], choices=("pivot", "mavlink", "dynamixel"),
                        help="gimbal backends to measure, each against its simulator (default: pivot)")


def _tree_rss_mb(pid: int) -> tuple[float, float, dict[int, float]]:
    """RSS and peak RSS [MB] summed over ``pid`` and its descendants (the planner process), and RSS per pid."""
    per = {p: rss_mb(p) for p in process_tree(pid)}
    return sum(v[0] for v in per.values()), sum(v[1] for v in per.values()), {p: round(v[0], 1) for p, v in per.items()}


def _run(config: Path, endpoint: str, duration: float, out: Path) -> dict:
    """Daemon + sim_pose for ``duration`` s of walking; returns the final status and memory."""
    from pivotd.bus.session import open_session
    from pivotd.cli.status import query_status
    from pivotd.config import load_config
    from pivotd.sim.launch import spawn, stop_processes

    cfg = load_config(config)
    py = sys.executable
    daemon = spawn([py, "-m", "pivotd.cli", "--config", str(config), "--log-level", "WARNING"], out / "pivotd.log")
    sim = None
    session = open_session(connect=[endpoint])
    try:
        def status() -> dict | None:
            return next(iter(query_status(session, cfg.status_key, 2.0).values()), None)

        t0 = time.monotonic()
        while (st := status()) is None or st.get("link") != "up":
            if daemon.poll() is not None or time.monotonic() - t0 > 60:
                raise RuntimeError(f"pivotd did not come up; see {out / 'pivotd.log'}")
            time.sleep(0.2)
        sim = spawn([py, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--connect", endpoint, "--speed",
                     "1.0", "--rate", "50", "--loop", "--quiet", "--wait-subscribers", "10"], out / "sim_pose.log")
        t0 = time.monotonic()
        while (st := status()) is None or st.get("state") != "tracking":
            if time.monotonic() - t0 > 30:
                raise RuntimeError(f"pivotd never started tracking; see {out / 'pivotd.log'}")
            time.sleep(0.2)
        time.sleep(duration)
        st = status() or {}
        rss, hwm, per = _tree_rss_mb(daemon.pid)
        st["rss_mb"], st["rss_peak_mb"], st["rss_by_pid"] = round(rss, 1), round(hwm, 1), per
        return st
    finally:
        stop_processes((sim, daemon))
        session.close()


def _setpoints_within_limits(cfg_path: Path, device_log: Path) -> bool:
    """Whether every setpoint the device logged respects the joint limits and the motion limits."""
    from pivotd.config import load_config
    from pivotd.sim.analysis import device_setpoint_dynamics, read_device_log

    cfg = load_config(cfg_path)
    dev = read_device_log(device_log)
    if dev.sp_pos.shape[0] < 3:
        return False
    dyn = device_setpoint_dynamics(cfg, dev)
    lim, tol = cfg.gimbal.limits, 1e-6
    inside = (lim.pan_min - tol <= dyn.position_min[0] and dyn.position_max[0] <= lim.pan_max + tol
              and lim.tilt_min - tol <= dyn.position_min[1] and dyn.position_max[1] <= lim.tilt_max + tol)
    return bool(dyn.within_limits and inside)


def run(args: argparse.Namespace) -> int:
    from pivotd.sim.launch import derive_config, free_port, start_gimbal_simulator

    results: dict = {}
    prio = f", SCHED_FIFO {args.realtime_priority}" if args.realtime_priority else ""
    with tempfile.TemporaryDirectory(prefix="pivotd-bench-") as tmp_s:
        tmp = Path(tmp_s)
        for backend in with_progress(args.backend, "control runs, one per backend"):
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            device_log = tmp / f"gimbal_{backend}.csv"
            gimbal, port = start_gimbal_simulator(backend, device_log, tmp / f"mock_gimbal_{backend}.log")
            try:
                cfg_path = derive_config(DEMO, tmp / f"load_{backend}.yaml", {
                    "zenoh.listen": [endpoint], "planner.replan_hz": args.replan_hz,
                    "control.rate_hz": args.control_hz, "control.status_hz": 2,
                    "control.realtime_priority": args.realtime_priority, "gimbal.backend": backend,
                    "gimbal.port": port})
                st = _run(cfg_path, endpoint, args.duration, tmp)
            finally:
                if gimbal is not None:
                    gimbal.send_signal(signal.SIGTERM)
                    gimbal.wait(timeout=10)
            results[f"load_{backend}"] = {
                "backend": backend,
                "control_hz": args.control_hz,
                "replan_hz": args.replan_hz,
                "jitter_ms_p99": st["control"]["jitter_ms_p99"],
                "pose_to_setpoint_ms_p99": st["control"]["pose_latency_ms_p99"],
                "replan_ms_p50": st["planner"]["solve_ms_p50"],
                "replan_ms_p99": st["planner"]["solve_ms_p99"],
                "plans": st["planner"]["plans"],
                "setpoints": st["control"]["setpoints"],
                "setpoints_within_limits": _setpoints_within_limits(cfg_path, device_log),
                "rss_mb": st["rss_mb"],
            }
        print(f"control {args.control_hz:g} Hz with replanning at {args.replan_hz:g} Hz{prio}, {args.duration:g} s "
              "tracking per backend (one after the other):")
        print(f"  {'backend':<9} {'jitter p99':>11} {'pose->setpoint p99':>19} {'replan p50/p99':>16} "
              f"{'setpoints':>9} {'in limits':>9} {'RSS':>8}")
        for r in (results[f"load_{b}"] for b in args.backend):
            print(f"  {r['backend']:<9} {r['jitter_ms_p99']:>8} ms {r['pose_to_setpoint_ms_p99']:>16} ms "
                  f"{r['replan_ms_p50']:>6}/{r['replan_ms_p99']:<6} ms {r['setpoints']:>9} "
                  f"{'yes' if r['setpoints_within_limits'] else 'NO':>9} {r['rss_mb']:>5} MB")
        print("  goals: jitter p99 <= 1 ms, pose -> first setpoint p99 <= 15 ms, setpoints within limits")
        if args.rss_landmarks > 0:
            rng = np.random.default_rng(0)
            n = args.rss_landmarks
            # A building-sized map around the hallway: uniform in a 200 m x 200 m x 10 m box.
            pts = np.column_stack([rng.uniform(-100, 100, n), rng.uniform(-100, 100, n), rng.uniform(0, 10, n)])
            np.save(tmp / "big.npy", pts)
            endpoint = f"tcp/127.0.0.1:{free_port()}"
            big = derive_config(DEMO, tmp / "big.yaml", {"zenoh.listen": [endpoint], "map.file": str(tmp / "big.npy")})
            st = _run(big, endpoint, min(args.duration, 5.0), tmp)
            results["memory"] = {"landmarks": n, "rss_mb": st["rss_mb"], "rss_peak_mb": st["rss_peak_mb"],
                                 "rss_by_process_mb": st["rss_by_pid"]}
            print(f"  RSS with a {n:,}-landmark map, daemon + planner process: {st['rss_mb']} MB "
                  f"(sum of peaks {st['rss_peak_mb']} MB; per process {list(st['rss_by_pid'].values())}; "
                  "goal <= 200 MB)")
    if args.json:
        args.json.write_text(json.dumps(results, indent=2))
    return 0
