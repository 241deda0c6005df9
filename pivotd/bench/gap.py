"""``pivotd bench gap``: the running daemon against the achievable view, per scene family (end to end).

For each family × seed of :mod:`pivotd.sim.scene_families` the scene's map and route are written to
``--out``, then the real stack runs on them (:func:`pivotd.sim.stack.run_stack`: ``pivotd`` with config/demo.yaml
derived with the scene's map, ``tools/sim_pose``, the in-process mock gimbal, Zenoh on loopback) ``--repeat``
times, and each recording is judged by ``pivotd.bench.achievable.achievable_report``: landmarks in view per frame
of the daemon, of a forward-facing camera, of the achievable camera path (the best the gimbal can execute on that
route) and of a teleporting camera; ``share`` = daemon / achievable. Without that module the daemon's and forward
figures come from the run's own analysis (:func:`pivotd.sim.analysis.analyse_run`) and share and achievable are
not available. The table gives per scene the means over the repeats and the spread of the share between them.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "config" / "demo.yaml"
DEFAULT_FAMILIES = "turn,aisles,clusters,fif,stop_turn"
KEYS = ("daemon_mean", "forward_mean", "achievable_mean", "teleport_mean", "share", "frames_below_forward_90")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--families", default=DEFAULT_FAMILIES, help=f"comma-separated (default {DEFAULT_FAMILIES})")
    parser.add_argument("--seeds", default="1", help="comma-separated scene seeds (default 1)")
    parser.add_argument("--repeat", type=int, default=1, help="runs per scene (default 1)")
    parser.add_argument("--speed", type=float, default=1.0, help="robot speed [m/s] (default 1.0)")
    parser.add_argument("--config", type=Path, default=DEMO, help="base config (default config/demo.yaml)")
    parser.add_argument("--out", type=Path, default=None,
                        help="directory for the scenes and runs (default: a new temporary directory)")
    parser.add_argument("--json", nargs="?", const="-", default=None, metavar="FILE",
                        help="write the results as JSON to FILE (no FILE: to stdout instead of the table)")


def _settings(args: argparse.Namespace) -> tuple[list[str], list[int]]:
    from pivotd.errors import InputError
    from pivotd.sim.scene_families import FAMILIES

    families = [f.strip() for f in args.families.split(",") if f.strip()]
    for f in families:
        if f not in FAMILIES:
            raise InputError(f"--families: unknown family '{f}' (known: {', '.join(FAMILIES)})")
    try:
        seeds = [int(s) for s in args.seeds.split(",") if s.strip()]
    except ValueError:
        raise InputError(f"--seeds: expected comma-separated integers, got {args.seeds!r}") from None
    if not families or not seeds:
        raise InputError("--families and --seeds must name at least one each")
    if args.repeat < 1:
        raise InputError(f"--repeat: need at least 1, got {args.repeat}")
    if not (math.isfinite(args.speed) and 0.1 <= args.speed <= 3.0):
        raise InputError(f"--speed: must be in [0.1, 3] m/s, got {args.speed}")
    if not args.config.exists():
        raise InputError(f"--config {args.config}: no such file")
    return families, seeds


def _achievable():
    """``achievable_report(run_mcap, config_path) -> dict``, or None while that module is not there."""
    try:
        from pivotd.bench.achievable import achievable_report
    except ModuleNotFoundError as exc:
        if exc.name != "pivotd.bench.achievable":
            raise
        return None
    return achievable_report


def judge(run, achievable_report=None) -> dict:
    """The figures of one :class:`pivotd.sim.stack.StackRun` (keys ``KEYS``): from ``achievable_report`` when
    given, else daemon and forward from the run's analysis (the others NaN)."""
    from pivotd.sim.stack import frames_below

    if achievable_report is not None:
        return from_achievable(achievable_report(run.recording, run.config_path))
    nan = float("nan")
    return {"daemon_mean": run.report["visible_mean_pivot"], "forward_mean": run.report["visible_mean_forward"],
            "achievable_mean": nan, "teleport_mean": nan, "share": nan,
            "frames_below_forward_90": frames_below(run.series, 0.9), "source": "analyse_run"}


def from_achievable(doc: dict) -> dict:
    """``KEYS`` from an ``achievable_report`` dict: ``share`` is daemon / achievable (also read as
    ``share_daemon_achievable``), ``frames_below_forward_90`` a share of the frames (also computed from the count
    ``frames_daemon_below_90pct_forward`` over ``frames``)."""
    nan = float("nan")
    out = {k: float(doc.get(k, nan)) for k in KEYS}
    if not math.isfinite(out["share"]):
        out["share"] = float(doc.get("share_daemon_achievable", nan))
    if not math.isfinite(out["frames_below_forward_90"]) and doc.get("frames"):
        out["frames_below_forward_90"] = float(doc.get("frames_daemon_below_90pct_forward", nan)) / doc["frames"]
    return out | {"source": "achievable_report"}


def host_stalls(report: dict) -> int:
    """Stalls of the daemon's process its gimbal link counted (``link_counters.host_stalls`` of the last status): on
    a loaded machine the control loop then resynchronises the setpoint stream, and the device may see a step."""
    status = report.get("final_status") or {}
    return int((status.get("link_counters") or {}).get("host_stalls", 0))


def longest_setpoint_gap(run) -> float:
    """The longest interval [s] between two setpoints the device received in a :class:`StackRun` (one control period
    when the host keeps up; beyond the device watchdog, 250 ms in config/demo.yaml, it holds and the stream
    restarts)."""
    from pivotd.sim.analysis import read_device_log

    rx = read_device_log(run.device_log).sp_rx_time
    return float(np.max(np.diff(rx))) if rx.size > 1 else float("nan")


def _mean(xs: list[float]) -> float:
    ok = [x for x in xs if math.isfinite(x)]
    return sum(ok) / len(ok) if ok else float("nan")


def summarise(name: str, family: str, seed: int, runs: list[dict]) -> dict:
    """Means over repeats of each key, the share's spread (max − min, points of %), the daemon/forward ratio."""
    row: dict = {"scene": name, "family": family, "seed": seed, "repeats": len(runs)}
    for k in KEYS:
        row[k] = _mean([r[k] for r in runs])
    shares = [r["share"] for r in runs if math.isfinite(r["share"])]
    row["share_spread_pts"] = 100.0 * (max(shares) - min(shares)) if shares else float("nan")
    row["daemon_over_forward"] = row["daemon_mean"] / row["forward_mean"] if row["forward_mean"] > 0 else float("nan")
    row["host_stalls"] = sum(int(r.get("host_stalls", 0)) for r in runs)
    row["setpoint_gap_s"] = max((float(r.get("setpoint_gap_s", float("nan"))) for r in runs), default=float("nan"))
    row["runs"] = runs
    return row


def _fmt(x: float, width: int, digits: int = 1, scale: float = 1.0) -> str:
    return f"{scale * x:{width}.{digits}f}" if math.isfinite(x) else f"{'-':>{width}}"


def print_table(rows: list[dict], out=None) -> None:
    """The table: per scene the mean landmarks in view (daemon, forward, achievable), share [%], daemon/forward,
    frames where the daemon saw < 90 % of forward [%], spread of the share between repeats [points], the longest
    interval between setpoints the device received [ms] (the most of the repeats)."""
    out = out or sys.stdout
    print(f"{'family':<10} {'seed':>4} {'scene':<20} {'daemon':>7} {'forward':>7} {'achiev':>7} {'share%':>6} "
          f"{'d/fwd':>6} {'<90%fwd':>7} {'spread':>6} {'gap_ms':>6}", file=out)
    for r in rows:
        print(f"{r['family']:<10} {r['seed']:>4} {r['scene']:<20} {_fmt(r['daemon_mean'], 7)} "
              f"{_fmt(r['forward_mean'], 7)} {_fmt(r['achievable_mean'], 7)} {_fmt(r['share'], 6, scale=100)} "
              f"{_fmt(r['daemon_over_forward'], 6, 2)} {_fmt(r['frames_below_forward_90'], 7, scale=100)} "
              f"{_fmt(r['share_spread_pts'], 6)} {_fmt(r.get('setpoint_gap_s', float('nan')), 6, 0, 1000)}", file=out)
    shares = [(r["share"], r) for r in rows if math.isfinite(r["share"])]
    if shares:
        worst = min(shares, key=lambda x: x[0])[1]
        print(f"mean share {100 * _mean([s for s, _ in shares]):.1f} %; worst scene {worst['family']} seed "
              f"{worst['seed']} ({worst['scene']}) at {100 * worst['share']:.1f} %", file=out)
    else:
        ratios = [(r["daemon_over_forward"], r) for r in rows if math.isfinite(r["daemon_over_forward"])]
        print("share: no achievable reference (pivotd.bench.achievable not available); daemon/forward shown", file=out)
        if ratios:
            worst = min(ratios, key=lambda x: x[0])[1]
            print(f"mean daemon/forward {_mean([x for x, _ in ratios]):.2f}; worst scene {worst['family']} seed "
                  f"{worst['seed']} ({worst['scene']}) at {worst['daemon_over_forward']:.2f}", file=out)


def run(args: argparse.Namespace) -> int:
    import tempfile

    from pivotd.bench._stats import json_safe
    from pivotd.progress import with_progress
    from pivotd.sim.scene_families import generate, write_scene
    from pivotd.sim.stack import run_stack

    families, seeds = _settings(args)
    out = args.out or Path(tempfile.mkdtemp(prefix="pivotd-gap-"))
    report = _achievable()
    rows = []
    jobs = [(f, s) for f in families for s in seeds]
    for family, seed in with_progress(jobs, "scenes", stream=sys.stderr):
        scene = generate(family, seed, args.speed)
        base = out / f"{family}-{seed}"
        map_file, route = write_scene(scene, base / "scene")
        runs = []
        for k in range(args.repeat):
            result = run_stack(args.config, base / f"run{k}", route=route, map_file=map_file, speed=args.speed,
                               timed=scene.timed)
            (result.recording.parent / "summary.json").write_text(
                json.dumps(json_safe(result.report), indent=1, default=str))
            runs.append(judge(result, report) | {"daemon_exit": result.daemon_exit,
                                                 "within_limits": result.report["within_limits"],
                                                 "host_stalls": host_stalls(result.report),
                                                 "setpoint_gap_s": longest_setpoint_gap(result),
                                                 "frames": result.report["frames"],
                                                 "recording": str(result.recording)})
        rows.append(summarise(scene.name, family, seed, runs))
    doc = {"config": str(args.config), "speed": args.speed, "repeat": args.repeat, "out": str(out),
           "achievable_reference": report is not None, "scenes": rows}
    if args.json == "-":
        print(json.dumps(json_safe(doc), indent=1, default=str))
    else:
        print_table(rows)
        print(f"runs in {out}")
        if args.json:
            Path(args.json).write_text(json.dumps(json_safe(doc), indent=1, default=str))
            print(f"wrote {args.json}")
    bad = [(row, r) for row in rows for r in row["runs"] if r["daemon_exit"] != 0 or not r["within_limits"]]
    for row, r in bad:
        print(f"{row['family']} seed {row['seed']}: daemon exit {r['daemon_exit']}, setpoints within limits "
              f"{'yes' if r['within_limits'] else 'NO'} (longest setpoint gap {1000 * r['setpoint_gap_s']:.0f} ms, "
              f"{r['host_stalls']} host stalls); {r['recording']}",
              file=sys.stderr)
    return 1 if bad else 0
