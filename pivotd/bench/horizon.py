"""``pivotd bench horizon``: receding-horizon replanning latency, warm-started, as the daemon runs it.

Scene: the S-shaped hallway with ``--landmarks`` landmarks (95 % on the rich wall), a
``--horizon``-waypoint window at 0.5 m spacing, 60° FoV, λ = 0.6, range 0.3–10 m, joint limits of
config/demo.yaml. The robot advances ``--step`` metres between replans (1 m/s at 10 Hz); every
replan is warm-started from the previous plan and anchored to its first direction, exactly as in
the daemon. Reported: per-replan medians and p99 of the whole replan (map query + optimisation;
wall-clock, and CPU time of this process) and of its parts, and the cold start. ``--far N`` adds N
landmarks out of range (a building-scale map around the hallway) to a second map and replans on both,
interleaved, so the ratio of the two is measured side by side.
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
    prev, prev_anchor = plan, anchor
    total, cpu, query, retained_counts, union_counts, quality = [], [], [], [], [], []
    full = RecedingHorizonPlanner(replace(settings, max_landmarks_per_waypoint=None), Mount(), limits)
    for k in with_progress(range(1, replans + 1), "replans"):
        s = (k * args.step) % max(s_max, 1e-9)
        if s < args.step:  # wrapped around: start a new pass with a fresh path version
            planner.set_path(sc.path, None, k + 1)
            if far:
                far[0].set_path(sc.path, None, k + 1)
        pos, quat = track.sample(np.array([s]))
        if far:  # the same replan on the map with the far landmarks, interleaved
            t1 = time.perf_counter()
            far_plan = far[0].replan(far[1], pos[0], quat[0] if quat is not None else q, far_anchor)
            far[2].append(time.perf_counter() - t1)
            far_anchor = far_plan.directions[0]
        t1, c1 = time.perf_counter(), time.process_time()
        plan = planner.replan(snap, pos[0], quat[0] if quat is not None else q, anchor)
        total.append(time.perf_counter() - t1)
        cpu.append(time.process_time() - c1)
        anchor = plan.directions[0]
        tq = time.perf_counter()
        ret = snap.retained(plan.positions, flt)
        query.append(time.perf_counter() - tq)
        retained_counts.append(np.mean([r.shape[0] for r in ret]))
        union_counts.append(np.unique(np.concatenate(ret)).shape[0])
        if k % 10 == 0 and args.cap:
            # Quality of the capped plan: hard visible count over the full retained sets, against a plan
            # optimised on the full sets from the same warm start.
            full.set_path(sc.path, None, planner._path_version)
            full.progress, full.last_plan = planner.progress, prev
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
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0
