"""``pivotd bench localization``: how often does the robot know where it is, per camera policy.

Simulated visual localization (:mod:`pivotd.localization`): FIF maps with their trajectories and seeded
procedural scenes (rooms, a corridor with a textureless wall, a warehouse aisle) with occluding walls; a
pinhole camera on the gimbal steered by each policy through the daemon's control loop with the limits of
config/demo.yaml; PnP + RANSAC (poselib) every frame; success at (0.05 m, 0.4°), (0.25 m, 2°),
(0.5 m, 5°), median errors, frames without a pose, the longest failure streak and each policy's compute
time per frame, as means over seeds with 95 % bootstrap intervals, and the three goals per scene.
Needs the ``bench`` extra (poselib); ``--plot`` needs the ``plot`` extra (matplotlib).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import os
from concurrent.futures import ProcessPoolExecutor
from dataclasses import asdict, replace
from pathlib import Path

from pivotd.bench._stats import json_safe
from pivotd.progress import with_progress

log = logging.getLogger(__name__)

REPO = Path(__file__).resolve().parents[2]
QUICK_SEEDS = 3


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help=f"{QUICK_SEEDS} seeds, routes cut to 12 s (under 2 minutes on 2 cores with --jobs 2)")
    parser.add_argument("--seeds", type=int, default=10, help="seeds per scene (default 10)")
    parser.add_argument("--seed", type=int, default=0, help="first seed (default 0)")
    parser.add_argument("--scenes", default=None, help="comma-separated scene names (default: all)")
    parser.add_argument("--policies", default=None,
                        help="comma-separated policies (default: forward,pivot,fisher,oracle,teleport,random; "
                             "oracle: the achievable view, teleport: the best view per frame ignoring the motion "
                             "limits)")
    parser.add_argument("--config", type=Path, default=REPO / "config" / "demo.yaml",
                        help="daemon config whose gimbal, motion, planner and control settings are used")
    parser.add_argument("--fif-dir", type=Path, default=REPO / "tests" / "data" / "fif")
    parser.add_argument("--jobs", type=int, default=1, help="worker processes (one scene each)")
    abl = parser.add_argument_group("ablations (change the daemon config for every policy)")
    abl.add_argument("--no-distance-weights", action="store_true",
                     help="pivot.distance_weights: false (the optimizer weighs near and far landmarks alike)")
    abl.add_argument("--continuous-pan", action="store_true", help="a slip-ring gimbal: no pan limits")
    abl.add_argument("--replan-on-waypoint", action="store_true",
                     help="planner.replan_on_waypoint: true (replan once the robot moved a waypoint spacing)")
    abl.add_argument("--normalise", choices=("total", "attainable"), default=None,
                     help="planner.normalise (visible term over each waypoint's total or attainable weight)")
    abl.add_argument("--rescue-blind", choices=("on", "off"), default=None,
                     help="planner.rescue_blind (a second solve where the warm plan sees little of what one cone "
                          "could see)")
    abl.add_argument("--rescue-fraction", type=float, default=None, metavar="F", help="planner.rescue_fraction")
    abl.add_argument("--lambda", dest="lam", type=float, default=None, metavar="L", help="pivot.lambda (smoothness)")
    abl.add_argument("--smooth-knee-deg", type=float, default=None, metavar="DEG",
                     help="pivot.smooth_knee_deg (steps beyond about this cost by their size; 0: 1 − cos per step)")
    parser.add_argument("--json", metavar="FILE", help="write all results as JSON")
    parser.add_argument("--plot", metavar="FILE", help="routes coloured by success and success curves (PNG)")
    cam = parser.add_argument_group("camera")
    cam.add_argument("--width", type=int, default=640)
    cam.add_argument("--height", type=int, default=480)
    cam.add_argument("--fx", type=float, default=500.0)
    cam.add_argument("--fy", type=float, default=500.0)
    cam.add_argument("--min-depth", type=float, default=0.3)
    cam.add_argument("--max-depth", type=float, default=10.0)
    cam.add_argument("--detection", type=float, default=0.9, help="detection probability per landmark in view")
    cam.add_argument("--pixel-noise", type=float, default=1.0, help="σ [px]")
    cam.add_argument("--outliers", type=float, default=0.1, help="share of wrong matches")
    cam.add_argument("--dropout", type=float, default=0.0, help="share of landmarks missing for a whole run")
    cam.add_argument("--max-incidence-deg", type=float, default=75.0,
                     help="largest angle off a surface normal at which a landmark is matched (0: no limit)")


def _settings(args: argparse.Namespace):
    from pivotd.errors import InputError
    from pivotd.localization.benchmark import QUICK_DURATION, BenchSettings
    from pivotd.localization.camera import CameraModel
    from pivotd.localization.policies import PolicyName
    from pivotd.localization.scenes import scene_names
    from pivotd.localization.stack import load_config

    scenes = tuple(s.strip() for s in args.scenes.split(",") if s.strip()) if args.scenes else tuple(scene_names())
    for s in scenes:
        if s not in scene_names():
            raise InputError(f"--scenes: unknown scene '{s}' (known: {', '.join(scene_names())})")
    names = [p.strip() for p in args.policies.split(",")] if args.policies else [p.value for p in PolicyName]
    known = [p.value for p in PolicyName]
    for p in names:
        if p not in known:
            raise InputError(f"--policies: unknown policy '{p}' (known: {', '.join(known)})")
    seeds = QUICK_SEEDS if args.quick else args.seeds
    if seeds < 1:
        raise InputError(f"--seeds: need at least 1, got {seeds}")
    camera = CameraModel(width=args.width, height=args.height, fx=args.fx, fy=args.fy, min_depth=args.min_depth,
                         max_depth=args.max_depth, detection_probability=args.detection, pixel_noise=args.pixel_noise,
                         outlier_ratio=args.outliers, dropout=args.dropout,
                         max_incidence_deg=args.max_incidence_deg or None)
    cfg = load_config(args.config)
    if args.no_distance_weights:
        cfg = replace(cfg, pivot=replace(cfg.pivot, distance_weights=False))
    planner = cfg.planner
    if args.replan_on_waypoint:
        planner = replace(planner, replan_on_waypoint=True)
    if args.normalise is not None:
        from pivotd.pivot.normalise import Normalisation

        planner = replace(planner, normalise=Normalisation(args.normalise))
    if args.rescue_blind is not None:
        planner = replace(planner, rescue_blind=args.rescue_blind == "on")
    if args.rescue_fraction is not None:
        if not (math.isfinite(args.rescue_fraction) and 0.0 < args.rescue_fraction <= 1.0):
            raise InputError(f"--rescue-fraction: must be in (0, 1], got {args.rescue_fraction}")
        planner = replace(planner, rescue_fraction=args.rescue_fraction)
    cfg = replace(cfg, planner=planner)
    if args.lam is not None:
        if not (math.isfinite(args.lam) and args.lam >= 0):
            raise InputError(f"--lambda: must be ≥ 0, got {args.lam}")
        cfg = replace(cfg, pivot=replace(cfg.pivot, lam=args.lam))
    if args.smooth_knee_deg is not None:
        if not (math.isfinite(args.smooth_knee_deg) and 0.0 <= args.smooth_knee_deg <= 180.0):
            raise InputError(f"--smooth-knee-deg: must be in [0, 180], got {args.smooth_knee_deg}")
        cfg = replace(cfg, pivot=replace(cfg.pivot, smooth_knee=math.radians(args.smooth_knee_deg)))
    if args.continuous_pan:
        cfg = replace(cfg, gimbal=replace(cfg.gimbal, limits=replace(cfg.gimbal.limits, continuous_pan=True)))
    return BenchSettings(scenes=scenes, policies=tuple(PolicyName(p) for p in names),
                         seeds=tuple(range(args.seed, args.seed + seeds)), camera=camera, cfg=cfg, fif_dir=args.fif_dir,
                         max_duration=QUICK_DURATION if args.quick else None)


def _worker(st, scene: str):
    from pivotd.bench import pin_single_thread
    from pivotd.localization.benchmark import run_scene

    pin_single_thread()
    return run_scene(st, scene)


def run(args: argparse.Namespace) -> int:
    from pivotd.localization.benchmark import check_goals, run_scene, summarize
    from pivotd.localization.estimator import require_poselib
    from pivotd.localization.metrics import THRESHOLDS, threshold_label

    require_poselib()
    if args.plot:
        from pivotd.localization.plot import require_matplotlib

        require_matplotlib()
    st = _settings(args)
    jobs = max(1, min(args.jobs, len(st.scenes), os.cpu_count() or 1))
    if jobs > 1:
        with ProcessPoolExecutor(jobs) as pool:
            done = pool.map(_worker, [st] * len(st.scenes), st.scenes)
            results = list(with_progress(done, "localization scenes", total=len(st.scenes)))
    else:
        results = [run_scene(st, s) for s in with_progress(st.scenes, "localization scenes")]
    summaries = {r.scene: summarize(r) for r in results}
    goals = [g for r in results for g in check_goals(r.scene, summaries[r.scene])]
    _print_table(st, summaries, [threshold_label(i) for i in range(len(THRESHOLDS))])
    _print_goals(goals)
    if args.json:
        doc = {
            "command": "pivotd bench localization" + (" --quick" if args.quick else f" --seeds {len(st.seeds)}")
            + (" --no-distance-weights" if args.no_distance_weights else "")
            + (" --continuous-pan" if args.continuous_pan else "")
            + (" --replan-on-waypoint" if args.replan_on_waypoint else "")
            + ("" if args.lam is None else f" --lambda {args.lam:g}")
            + ("" if args.smooth_knee_deg is None else f" --smooth-knee-deg {args.smooth_knee_deg:g}")
            + ("" if args.normalise is None else f" --normalise {args.normalise}"),
            "seeds": list(st.seeds),
            "camera": asdict(st.camera),
            "config": str(args.config),
            "max_duration_s": st.max_duration,
            "thresholds": [list(t) for t in THRESHOLDS],
            "scenes": summaries,
            "goals": [asdict(g) for g in goals],
        }
        Path(args.json).write_text(json.dumps(json_safe(doc), indent=1))
        print(f"wrote {args.json}")
    if args.plot:
        from pivotd.localization.plot import plot_results

        plot_results(results, summaries, Path(args.plot))
        print(f"wrote {args.plot}")
    return 0


def _fmt(iv: dict, scale: float = 100.0, digits: int = 1) -> str:
    m, lo, hi = (iv[k] for k in ("mean", "lo", "hi"))
    if not math.isfinite(m):
        return "inf"
    return f"{scale * m:.{digits}f} [{scale * lo:.{digits}f},{scale * hi:.{digits}f}]"


def _print_table(st, summaries: dict, labels: list[str]) -> None:
    print(f"pivotd bench localization — {len(st.seeds)} seeds, camera {st.camera.width}x{st.camera.height} "
          f"fx={st.camera.fx:g}, means with 95 % bootstrap intervals")
    head = (f"{'scene':15s} {'policy':8s} " + " ".join(f"{'ok ' + lb + ' %':>20s}" for lb in labels)
            + f" {'med t [m]':>10s} {'med r [°]':>10s} {'no pose %':>9s} {'turning %':>9s} {'streak s':>9s}"
            + f" {'ms/frame':>9s}"
            + f" {'ms/dec':>8s}")
    print(head)
    for scene, by_policy in summaries.items():
        for policy, s in by_policy.items():
            ok = " ".join(f"{_fmt(s['success_' + lb]):>20s}" for lb in labels)
            mt, mr = s["median_t_m"]["mean"], s["median_r_deg"]["mean"]
            print(f"{scene:15s} {policy:8s} {ok} {mt:10.3f} {mr:10.2f} {100 * s['no_pose']['mean']:9.1f} "
                  f"{100 * s['failure_turning']['mean']:9.1f} "
                  f"{s['longest_failure_s']['mean']:9.1f} {s['compute_ms_per_frame']['mean']:9.2f} "
                  f"{s['compute_ms_per_decision']['mean']:8.2f}")


def _print_goals(goals) -> None:
    print("goals (success at 0.25 m / 2°):")
    for g in goals:
        state = "n/a " if not g.applies else ("met " if g.met else "MISS")
        print(f"  {state} {g.scene:15s} {g.goal:26s} {g.detail}")
