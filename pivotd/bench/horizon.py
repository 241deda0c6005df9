"""``pivotd bench horizon``: receding-horizon replanning latency, warm-started, as the daemon runs it.

Scene: the S-shaped hallway with ``--landmarks`` landmarks (95 % on the rich wall), a
``--horizon``-waypoint window at 0.5 m spacing, 60° FoV, λ = 0.6, range 0.3–10 m, joint limits of
config/demo.yaml. The robot advances ``--step`` metres between replans (1 m/s at 10 Hz); every
replan is warm-started from the previous plan and anchored to its first direction, exactly as in
the daemon. Reported: per-replan medians and p99 of the whole replan (map query + optimisation;
wall-clock, and CPU time of this process) and of its parts, and the cold start. ``--far N`` adds N
landmarks out of range (a building-scale map around the hallway) to a second map and replans on both,
interleaved, so the ratio of the two is measured side by side. ``--compare-with PKG`` replans the same
hallway, interleaved in this process, with the planner and map store of PKG: an importable copy of
another pivotd version (its package renamed, e.g. ``pivotd_base``; docs/PERFORMANCE.md shows how), so
an older commit's replan is timed side by side with this one.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pivotd.progress import with_progress


def _visible_full(snap, plan, retained, alpha: float) -> int:
    """Hard visible count summed over the horizon, over the full retained sets."""
    from pivotd.geometry import normalize
    from pivotd.pivot.visibility import hard_count

    return sum(hard_count(plan.directions[i], normalize(snap.points[idx] - plan.positions[i]), alpha)
               for i, idx in enumerate(retained))

def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--landmarks", type=int, default=20000)
    parser.add_argument("--horizon", type=int, default=40)
    parser.add_argument("--replans", type=int, default=300)
    parser.add_argument("--step", type=float, default=0.1, help="robot motion between replans [m]")
    parser.add_argument("--cap", type=int, default=2000,
                        help="planner.max_landmarks_per_waypoint (systematic subsample; 0: no cap)")
    parser.add_argument("--quick", action="store_true", help="100 replans")
    parser.add_argument("--far", type=int, default=0, metavar="N",
                        help="also replan on a map with N more landmarks out of range, interleaved, and report "
                             "the ratio")
    parser.add_argument("--compare-with", metavar="PKG",
                        help="also replan, interleaved, with the planner of PKG (a renamed copy of another pivotd "
                             "version on PYTHONPATH) and report CPU-time ratios")
    parser.add_argument("--rescue-fraction", type=float, metavar="F",
                        help="also replan, interleaved, with planner.rescue_blind on at rescue_fraction F (and "
                             "--smooth-knee-deg) and report "
                             "CPU-time ratios and how many replans took a second solve")
    parser.add_argument("--smooth-knee-deg", type=float, default=0.0, metavar="K",
                        help="with --rescue-fraction: the interleaved planner's pivot.smooth_knee_deg (the daemon's "
                             "defaults: --rescue-fraction 0.25 --smooth-knee-deg 1; default 0)")
    parser.add_argument("--json", type=Path)


def far_landmarks(n: int, path: np.ndarray, clearance: float, seed: int = 0) -> np.ndarray:
    """``n`` landmarks (n, 3) float32 spread over a 1 km × 1 km floor (0–3 m high) around ``path`` (K, 3),
    none within ``clearance`` [m] of the path's bounding box."""
    rng = np.random.default_rng(seed)
    lo, hi = path.min(axis=0) - clearance, path.max(axis=0) + clearance
    out = np.empty((0, 3), np.float32)
    while out.shape[0] < n:
        p = rng.uniform([-500.0, -500.0, 0.0], [500.0, 500.0, 3.0], (n, 3)).astype(np.float32)
        inside = np.all((p[:, :2] >= lo[:2]) & (p[:, :2] <= hi[:2]), axis=1)
        out = np.concatenate([out, p[~inside]])
    return out[:n]


def _module(pkg: str, *names: str):
    """The first of ``pkg.name`` for ``names`` that imports (module layouts differ between versions)."""
    import importlib

    for name in names:
        try:
            return importlib.import_module(f"{pkg}.{name}")
        except ModuleNotFoundError:
            continue
    from pivotd.errors import InputError

    raise InputError(f"--compare-with {pkg}: none of {', '.join(names)} found in {pkg}")


def _other_planner(pkg: str, points: np.ndarray, path: np.ndarray, settings, limits):
    """(planner, snapshot) of another pivotd version ``pkg`` for the same map, path and settings."""
    from dataclasses import asdict

    planner_m = _module(pkg, "daemon.planner", "planner")
    kin = _module(pkg, "gimbal.kinematics")
    filters = _module(pkg, "maps.filters")
    formats = _module(pkg, "maps.formats")
    store_m = _module(pkg, "maps.store")
    store = store_m.MapStore()
    store.set_layer("base", formats.LandmarkCloud(points=points, weights=np.ones(points.shape[0], np.float32)))
    flt = settings.retained_filter
    other = planner_m.PlannerSettings(
        fov=settings.fov, lam=settings.lam, spacing=settings.spacing, horizon=settings.horizon,
        max_landmarks_per_waypoint=settings.max_landmarks_per_waypoint,
        retained_filter=filters.RetainedFilter(min_range=flt.min_range, max_range=flt.max_range),
    )
    lim = kin.JointLimits(**asdict(limits))
    planner = planner_m.RecedingHorizonPlanner(other, kin.Mount(), lim)
    planner.set_path(path, None, 1)
    return planner, store.snapshot()


def run(args: argparse.Namespace) -> int:
    from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner
    from pivotd.gimbal.kinematics import JointLimits, Mount
    from pivotd.maps.filters import RetainedFilter
    from pivotd.maps.formats import LandmarkCloud
    from pivotd.maps.store import MapStore
    from pivotd.pivot.scenes import hallway
    from pivotd.robot_path import Polyline

    n_rich = round(args.landmarks * 0.95)
    sc = hallway(rich_side_points=n_rich, poor_side_points=args.landmarks - n_rich, spacing=0.5)
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    flt = RetainedFilter(min_range=0.3, max_range=10.0)
    limits = JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60), False)
    settings = PlannerSettings(fov=math.radians(60), lam=0.6, spacing=0.5, horizon=args.horizon,
                               max_landmarks_per_waypoint=args.cap or None, retained_filter=flt)
    planner = RecedingHorizonPlanner(settings, Mount(), limits)
    planner.set_path(sc.path, None, 1)
    track = Polyline(sc.path)
    snap = store.snapshot()
    if args.far < 0:
        from pivotd.errors import InputError

        raise InputError(f"--far must be >= 0, got {args.far}")
    far = None
    if args.far:
        big = MapStore()
        pts = np.concatenate([sc.points.astype(np.float32), far_landmarks(args.far, sc.path, 2 * flt.max_range)])
        big.set_layer("base", LandmarkCloud(points=pts, weights=np.ones(pts.shape[0], np.float32)))
        far = (RecedingHorizonPlanner(settings, Mount(), limits), big.snapshot(), [])
        far[0].set_path(sc.path, None, 1)
    other = None
    if args.rescue_fraction is not None:
        from pivotd.errors import InputError

        if args.compare_with or not (math.isfinite(args.rescue_fraction) and 0 < args.rescue_fraction <= 1):
            raise InputError("--rescue-fraction: needs a value in (0, 1] and no --compare-with")
        if not (math.isfinite(args.smooth_knee_deg) and 0.0 <= args.smooth_knee_deg <= 180.0):
            raise InputError(f"--smooth-knee-deg: must be in [0, 180], got {args.smooth_knee_deg}")
        from pivotd.pivot.trajectory import TrajectoryOptions

        rescue = RecedingHorizonPlanner(
            replace(settings, rescue_fraction=args.rescue_fraction,
                    options=replace(settings.options or TrajectoryOptions(), smooth_knee_deg=args.smooth_knee_deg)),
            Mount(), limits)
        rescue.set_path(sc.path, None, 1)
        other = {"planner": rescue, "snap": snap, "cpu": [], "wall": [], "visible": []}
    elif args.compare_with:
        other_planner, other_snap = _other_planner(args.compare_with, sc.points.astype(np.float32), sc.path,
                                                   settings, limits)
        other = {"planner": other_planner, "snap": other_snap, "cpu": [], "wall": [], "visible": []}
    replans = 100 if args.quick else args.replans
    horizon_len = 0.5 * (args.horizon - 1)
    s_max = max(track.length - horizon_len, 0.0)
    q = np.array([0.0, 0.0, 0.0, 1.0])

    t0 = time.perf_counter()
    pos, quat = track.sample(np.array([0.0]))
    plan = planner.replan(snap, pos[0], quat[0], None)
    cold = time.perf_counter() - t0
    anchor = plan.directions[0]
    if far:
        far_anchor = far[0].replan(far[1], pos[0], quat[0], None).directions[0]
    if other:
        other["anchor"] = other["planner"].replan(other["snap"], pos[0], quat[0], None).directions[0]
    prev, prev_anchor = plan, anchor
    total, cpu, query, retained_counts, union_counts, quality = [], [], [], [], [], []
    visible_sums = []
    full = RecedingHorizonPlanner(replace(settings, max_landmarks_per_waypoint=None), Mount(), limits)
    for k in with_progress(range(1, replans + 1), "replans"):
        s = (k * args.step) % max(s_max, 1e-9)
        if s < args.step:  # wrapped around: start a new pass with a fresh path version
            planner.set_path(sc.path, None, k + 1)
            if far:
                far[0].set_path(sc.path, None, k + 1)
            if other:
                other["planner"].set_path(sc.path, None, k + 1)
        pos, quat = track.sample(np.array([s]))
        qk = quat[0] if quat is not None else q
        if other and k % 2:  # the other version first on odd replans, after this one on even ones
            _replan_other(other, pos[0], qk)
        if far:  # the same replan on the map with the far landmarks, interleaved
            t1 = time.perf_counter()
            far_plan = far[0].replan(far[1], pos[0], quat[0] if quat is not None else q, far_anchor)
            far[2].append(time.perf_counter() - t1)
            far_anchor = far_plan.directions[0]
        unwind_before = planner.unwind_target  # the reference replan below starts from the same state
        t1, c1 = time.perf_counter(), time.process_time()
        plan = planner.replan(snap, pos[0], quat[0] if quat is not None else q, anchor)
        total.append(time.perf_counter() - t1)
        cpu.append(time.process_time() - c1)
        anchor = plan.directions[0]
        visible_sums.append(int(np.sum(plan.visible)))
        if other and not k % 2:
            _replan_other(other, pos[0], qk)
        tq = time.perf_counter()
        ret = snap.retained(plan.positions, flt)
        query.append(time.perf_counter() - tq)
        retained_counts.append(np.mean([r.shape[0] for r in ret]))
        union_counts.append(np.unique(np.concatenate(ret)).shape[0])
        if k % 10 == 0 and args.cap:
            # Quality of the capped plan: hard visible count over the full retained sets, against a plan
            # optimised on the full sets from the same warm start.
            full.set_path(sc.path, None, planner._path_version)
            full.progress, full.last_plan, full.unwind_target = planner.progress, prev, unwind_before
            ref = full.replan(snap, pos[0], quat[0], prev_anchor)
            ours = _visible_full(snap, plan, ret, settings.alpha)
            quality.append(ours / max(_visible_full(snap, ref, ret, settings.alpha), 1))
        prev, prev_anchor = plan, anchor

    ms = lambda x, p: round(float(np.percentile(np.asarray(x), p)) * 1e3, 3)  # noqa: E731
    result = {
        "landmarks": args.landmarks,
        "horizon": args.horizon,
        "replans": replans,
        "retained_union_mean": round(float(np.mean(union_counts)), 1),
        "retained_per_waypoint_mean": round(float(np.mean(retained_counts)), 1),
        "replan_ms_p50": ms(total, 50),
        "replan_ms_p99": ms(total, 99),
        "replan_cpu_ms_p50": ms(cpu, 50),
        "replan_cpu_ms_p99": ms(cpu, 99),
        "map_query_ms_p50": ms(query, 50),
        "map_query_ms_p99": ms(query, 99),
        "cold_start_ms": round(cold * 1e3, 2),
        "cap": args.cap,
        "visible_vs_uncapped_mean": round(float(np.mean(quality)), 4) if quality else None,
        "visible_vs_uncapped_min": round(float(np.min(quality)), 4) if quality else None,
        "far": args.far,
    }
    if far:
        result["far_replan_ms_p50"] = ms(far[2], 50)
        result["far_replan_ms_p99"] = ms(far[2], 99)
        result["far_p50_ratio"] = round(result["far_replan_ms_p50"] / result["replan_ms_p50"], 3)
        result["far_p99_ratio"] = round(result["far_replan_ms_p99"] / result["replan_ms_p99"], 3)
    if other:
        ours_vis = float(np.mean(visible_sums))
        result["compare_with"] = args.compare_with or (f"rescue_blind at {args.rescue_fraction}, smooth_knee_deg "
                                                       f"{args.smooth_knee_deg:g}")
        if args.rescue_fraction is not None:
            result["rescue_second_solves"] = other["planner"].solves - 1 - replans
            result["rescue_kept"] = other["planner"].rescues
        result["other_replan_cpu_ms_p50"] = ms(other["cpu"], 50)
        result["other_replan_cpu_ms_p99"] = ms(other["cpu"], 99)
        result["other_replan_ms_p50"] = ms(other["wall"], 50)
        result["other_replan_ms_p99"] = ms(other["wall"], 99)
        result["cpu_p50_ratio_vs_other"] = round(result["replan_cpu_ms_p50"] / result["other_replan_cpu_ms_p50"], 3)
        result["cpu_p99_ratio_vs_other"] = round(result["replan_cpu_ms_p99"] / result["other_replan_cpu_ms_p99"], 3)
        result["visible_vs_other"] = round(ours_vis / max(float(np.mean(other["visible"])), 1e-9), 4)
    print(f"receding horizon: {args.landmarks} landmarks, {args.horizon} waypoints, {replans} warm-started replans")
    print(f"  retained per waypoint (mean)     {result['retained_per_waypoint_mean']:.0f}  "
          f"(distinct over the horizon {result['retained_union_mean']:.0f})")
    print(f"  replan p50 / p99                 {result['replan_ms_p50']} / {result['replan_ms_p99']} ms  "
          "(goal p99 <= 10 ms)")
    print(f"  replan CPU time p50 / p99        {result['replan_cpu_ms_p50']} / {result['replan_cpu_ms_p99']} ms  "
          "(this process only: less sensitive to other load)")
    print(f"  full map query of all waypoints  {result['map_query_ms_p50']} / {result['map_query_ms_p99']} ms "
          "(p50 / p99; replans query only the waypoints new to the window)")
    print(f"  cold start (no warm start)       {result['cold_start_ms']} ms")
    if quality:
        print(f"  cap {args.cap}/waypoint: visible landmarks vs the uncapped plan: mean "
              f"{result['visible_vs_uncapped_mean']:.2%}, min {result['visible_vs_uncapped_min']:.2%}")
    if far:
        print(f"  with {args.far} landmarks out of range  {result['far_replan_ms_p50']} / "
              f"{result['far_replan_ms_p99']} ms (p50 / p99; ratio {result['far_p50_ratio']:.2f} / "
              f"{result['far_p99_ratio']:.2f}, goal p99 ratio <= 1.2)")
    if other:
        print(f"  {result['compare_with']}, interleaved        CPU {result['other_replan_cpu_ms_p50']} / "
              f"{result['other_replan_cpu_ms_p99']} ms (p50 / p99); this version / it: "
              f"{result['cpu_p50_ratio_vs_other']:.2f} / {result['cpu_p99_ratio_vs_other']:.2f}; "
              f"planned visible {result['visible_vs_other']:.2%} of its")
        if args.rescue_fraction is not None:
            print(f"  rescue: second solves on {result['rescue_second_solves']} of {replans} replans, kept "
                  f"{result['rescue_kept']}")
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


def _replan_other(other: dict, position: np.ndarray, quat: np.ndarray) -> None:
    """One timed replan of the other version (--compare-with), warm-started from its previous plan."""
    c, t = time.process_time(), time.perf_counter()
    plan = other["planner"].replan(other["snap"], position, quat, other["anchor"])
    other["wall"].append(time.perf_counter() - t)
    other["cpu"].append(time.process_time() - c)
    other["anchor"] = plan.directions[0]
    other["visible"].append(int(np.sum(plan.visible)))
