"""``pivotd bench dense``: replans in the planner process on a densely packed map vs the same count spread thinly.

Both maps hold ``--landmarks`` uniform landmarks: *dense* fills the demo hallway's bounding box (thousands
per m³, a lidar map), *thin* a box six times wider and longer (the same height). Each is written to a
``.npy`` file and loaded by a real planner process (:class:`pivotd.daemon.worker.PlannerWorker`) with the
demo config (``map.max_landmarks_per_cell`` from ``--cell-cap``; 0: every landmark is read), which then
replans along the hallway route as the daemon does (0.16 m per replan: 0.8 m/s at 5 Hz, anchored to the
previous plan's first direction). Reported per layout: the first replan [ms] (every waypoint's retained set
is queried), median and worst of the rest [ms], late replans (over ``planner.replan_budget_s``), and the
planner process's peak resident memory [MB] after loading and after the replans, next to the map's own
16 B per landmark. The deadline is raised to 10 min so that a slow replan is measured, not given up.
"""

from __future__ import annotations

import argparse
import json
import statistics
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pivotd.bench._procs import rss_mb
from pivotd.config import load_config
from pivotd.daemon.worker import PlannerWorker
from pivotd.pivot.scenes import hallway

REPO = Path(__file__).resolve().parents[2]
STEP_M = 0.16  # [m] robot displacement between replans
THIN_SCALE = 6.0  # horizontal scale of the thin layout's box


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--landmarks", type=int, default=8_000_000, help="landmarks of each map (default 8M)")
    parser.add_argument("--replans", type=int, default=20, help="replans along the route per map (default 20)")
    parser.add_argument("--cell-cap", type=int, default=None, metavar="N",
                        help="map.max_landmarks_per_cell (default: the config's; 0: read every landmark)")
    parser.add_argument("--layouts", default="dense,thin", help="comma-separated: dense, thin")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    parser.add_argument("--seed", type=int, default=0)


def _box(layout: str) -> tuple[np.ndarray, np.ndarray]:
    base = hallway().points
    lo, hi = base.min(axis=0).astype(float), base.max(axis=0).astype(float)
    if layout == "thin":
        c = 0.5 * (lo + hi)
        lo[:2] = c[:2] + (lo[:2] - c[:2]) * THIN_SCALE
        hi[:2] = c[:2] + (hi[:2] - c[:2]) * THIN_SCALE
    elif layout != "dense":
        raise SystemExit(f"pivotd bench dense: unknown layout {layout!r} (dense, thin)")
    return lo, hi


def _route(replans: int) -> np.ndarray:
    """Positions (replans, 3) every STEP_M along the hallway route."""
    path = hallway().path
    seg = np.linalg.norm(np.diff(path, axis=0), axis=1)
    s = np.concatenate([[0.0], np.cumsum(seg)])
    at = np.minimum(np.arange(replans) * STEP_M, s[-1])
    return np.stack([np.interp(at, s, path[:, k]) for k in range(3)], axis=1)


def run(args: argparse.Namespace) -> int:
    cfg = load_config(REPO / "config" / "demo.yaml")
    cap = cfg.map.max_landmarks_per_cell if args.cell_cap is None else (args.cell_cap or 1 << 62)
    results: dict[str, float | int | str] = {"landmarks": args.landmarks, "cell_cap": args.cell_cap or 0}

    def report(key: str, value: float, unit: str) -> None:
        results[key] = value
        print(f"{key:<40} {value:12.4g} {unit}", flush=True)

    rng = np.random.default_rng(args.seed)
    quat = np.array([0.0, 0.0, 0.0, 1.0])
    route = _route(args.replans)
    report("map_mb", args.landmarks * 16 / 1e6, "MB")
    for layout in args.layouts.split(","):
        lo, hi = _box(layout)
        with tempfile.TemporaryDirectory(prefix="pivotd-bench-dense-") as tmp:
            npy = Path(tmp) / "map.npy"
            np.save(npy, rng.uniform(lo, hi, (args.landmarks, 3)).astype(np.float32))
            run_cfg = replace(cfg, map=replace(cfg.map, file=npy, max_landmarks_per_cell=cap),
                              planner=replace(cfg.planner, replan_deadline=600.0))
            report(f"{layout}_landmarks_per_m3", args.landmarks / float(np.prod(hi - lo)), "/m³")
            worker = PlannerWorker(run_cfg)
            try:
                report(f"{layout}_rss_peak_loaded_mb", rss_mb(worker.pid)[1], "MB")
                worker.set_path(hallway().path, None, 1)
                times, anchor = [], None
                for position in route:
                    t0 = time.perf_counter()
                    plan = worker.replan(position, quat, anchor)
                    times.append(time.perf_counter() - t0)
                    anchor = plan.directions[0]
                report(f"{layout}_first_replan_ms", 1e3 * times[0], "ms")
                rest = times[1:] or times
                report(f"{layout}_replan_ms_median", 1e3 * statistics.median(rest), "ms")
                report(f"{layout}_replan_ms_max", 1e3 * max(rest), "ms")
                report(f"{layout}_late_replans", worker.late, "")
                report(f"{layout}_landmarks_last_plan", plan.landmarks, "")
                report(f"{layout}_visible_last_plan", int(plan.visible[0]), "")
                report(f"{layout}_rss_peak_mb", rss_mb(worker.pid)[1], "MB")
            finally:
                worker.close()
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0
