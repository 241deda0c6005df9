"""The main job on the embedded default: daemon + simulated robot + simulated gimbal.

Starts ``pivotd`` with ``config/demo.yaml`` (gimbal ``mock://`` with a message log, or with ``--backend
mavlink`` / ``dynamixel`` the MAVLink gimbal manager on UDP / the DYNAMIXEL servo chain on a pty of
``tools/mock_gimbal``, logging the same CSV) and
``tools/sim_pose`` on the S-shaped hallway (or the config's ``sim.route``, or ``--route`` with ``--map``), both
talking Zenoh on loopback only (the run itself: :func:`pivotd.sim.stack.run_stack`). While the robot
walks, a live status line shows what the daemon reports. Afterwards it prints a summary: landmarks
visible per frame with PIVOT versus a forward-facing camera on the same route, the share of the achievable view
(``pivotd bench achievable`` on its recording) the daemon saw, setpoints sent, worst
velocity/acceleration/jerk versus the limits, and draws its recording (``run-<UTC time>.mcap``) as ``pivotd plot``
does.
"""

from __future__ import annotations

import argparse
import json
import logging
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.bench.achievable import achievable, summary_line
from pivotd.config import Config
from pivotd.sim.analysis import dynamics_lines
from pivotd.sim.launch import REPO, SIMULATED_BACKENDS
from pivotd.sim.stack import POSE_SOURCES, run_stack
from pivotd.viz.figures import build_figure, save_figure

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
    """Numbers the demo reports (also returned for tests and benchmarks); ``recording``: its ``run-<UTC time>.mcap``."""

    frames: int
    pivot_visible_mean: float
    forward_visible_mean: float
    setpoints: int
    within_limits: bool
    daemon_exit: int | None
    report: dict
    recording: Path | None = None


def run_demo(config_path: Path, out_dir: Path, speed: float = 1.2, timeout: float | None = None,
             live: bool = True, backend: str | None = None, route: str | None = None,
             map_file: Path | None = None, timed: bool = False, plot: bool = True, pose: str = "topic") -> DemoSummary:
    """Run the whole demo (with the config's gimbal backend, or ``backend`` against its simulator) on ``route`` (a
    ``sim_pose`` route spec; default: the config's ``sim.route``, else the hallway) and ``map_file`` (default: the
    config's map) through :func:`pivotd.sim.stack.run_stack`, the daemon taking the pose from ``pose``
    (:data:`pivotd.sim.stack.POSE_SOURCES`); returns the summary (also printed)."""
    on_status = (lambda elapsed, st: print(_status_line(elapsed, st), flush=True)) if live else None
    result = run_stack(config_path, out_dir, route=route, map_file=map_file, speed=speed, timeout=timeout,
                       backend=backend, timed=timed, on_status=on_status, pose=pose)
    cfg, report, exit_code = result.cfg, result.report, result.daemon_exit
    ach = achievable(result.run)
    report["achievable"] = ach.report
    png = save_figure(build_figure(result.run, "all", achievable=ach.series), out_dir / "demo.png") if plot else None
    (out_dir / "summary.json").write_text(json.dumps(report, indent=2, default=str))
    _print_summary(report, cfg, png, pose)
    return DemoSummary(report["frames"], report["visible_mean_pivot"], report["visible_mean_forward"],
                       report["setpoints"], report["within_limits"], exit_code, report, result.recording)


def _print_summary(r: dict, cfg: Config, png: Path | None, pose: str = "topic") -> None:
    print()
    source = "" if pose == "topic" else f", pose from {pose.upper().replace('-', ' ')}"
    print(f"pivotd demo summary ({r['frames']} frames at {cfg.control.joint_state_hz:g} Hz, "
          f"FoV {np.degrees(cfg.pivot.fov):.0f}°, gimbal backend {cfg.gimbal.backend}{source})")
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
    if png is not None:
        print(f"  plot: {png}")


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--config", type=Path, default=REPO / "config" / "demo.yaml")
    parser.add_argument("--out", type=Path, default=REPO / "out" / "demo")
    parser.add_argument("--speed", type=float, default=1.2, help="robot speed along the route [m/s]")
    parser.add_argument("--route", default=None, metavar="SPEC",
                        help="sim_pose route: 'hallway' or 'csv:FILE' (default: the config's sim.route, else hallway)")
    parser.add_argument("--map", type=Path, default=None, help="landmark map (default: the config's map.file)")
    parser.add_argument("--timed", action="store_true", help="play the route by its time stamps (sim_pose --timed)")
    parser.add_argument("--backend", choices=SIMULATED_BACKENDS, default=None,
                        help="gimbal backend, driven against its simulator (default: the config's)")
    parser.add_argument("--pose", choices=tuple(POSE_SOURCES), default="topic",
                        help="where the daemon takes the pose from: topic (/odom, the default), tf (map -> odom at 5 "
                             "Hz and odom -> base_link on /tf), tf-static (map -> odom on /tf_static)")
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.WARNING)
    summary = run_demo(args.config, args.out, speed=args.speed, backend=args.backend, route=args.route,
                       map_file=args.map, timed=args.timed, pose=args.pose)
    ok = summary.daemon_exit == 0 and summary.within_limits and summary.frames > 0
    return 0 if ok else 1


if __name__ == "__main__":
    raise SystemExit(main())
