"""``pivotd bench horizon``: receding-horizon replanning latency, as the daemon runs it.

The planner is the daemon's (:func:`pivotd.daemon.wiring.build_planner` of ``--config``, default
config/demo.yaml: its FoV, λ, knee, rescue, range filters, joint limits and axis speeds), with ``--horizon``
waypoints and ``--cap`` landmarks per waypoint. Scene: the S-shaped hallway with ``--landmarks`` landmarks (95 % on
the rich wall). The robot advances ``--step`` metres between replans at ``--speed``; every replan is warm-started
from the previous plan and anchored to its first direction, exactly as in the daemon; each pass along the hallway
starts on a new path (a new path version: the cold seeds), timed apart. Reported: per-replan medians and p99 of
the warm replans (wall-clock, and CPU time of this process), the plans on a new path, the map query and the first
plan. ``--far N`` adds N landmarks out of range (a building-scale map around the hallway) to a second map and
replans on both, interleaved, so the ratio of the two is measured side by side. ``--compare-with PKG`` replans the
same hallway, interleaved in this process, with the planner (its own ``build_planner`` of the same config file)
and map store of PKG: an importable copy of another pivotd version (its package renamed, e.g. ``pivotd_base``;
docs/PERFORMANCE.md shows how), so an older commit's replan is timed side by side with this one.
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
    parser.add_argument("--config", type=Path, default=None,
                        help="daemon config whose planner is timed (default config/demo.yaml)")
    parser.add_argument("--speed", type=float, default=1.0, help="robot speed [m/s] (replans every step / speed s)")
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


def _other_planner(pkg: str, points: np.ndarray, path: np.ndarray, config: Path, horizon: int, cap: int | None):
    """(planner, snapshot) of another pivotd version ``pkg`` for the same map, path and config file."""
    wiring = _module(pkg, "daemon.wiring")
    config_m = _module(pkg, "config")
    formats = _module(pkg, "maps.formats")
    store_m = _module(pkg, "maps.store")
    store = store_m.MapStore()
    store.set_layer("base", formats.LandmarkCloud(points=points, weights=np.ones(points.shape[0], np.float32)))
    cfg = config_m.load_config(config)
    cfg = replace(cfg, planner=replace(cfg.planner, horizon=horizon, max_landmarks_per_waypoint=cap or 0))
    planner = wiring.build_planner(cfg)
    planner.set_path(path, None, 1)
    return planner, store.snapshot()


def _replan(planner, snap, position: np.ndarray, quat: np.ndarray, anchor, now: float):
    """One replan at pose time ``now`` [s] (versions without the argument plan without it)."""
    try:
        return planner.replan(snap, position, quat, anchor, now=now)
    except TypeError:
        return planner.replan(snap, position, quat, anchor)


def run(args: argparse.Namespace) -> int:
    from pivotd.config import load_config
    from pivotd.daemon.planner import RecedingHorizonPlanner
    from pivotd.daemon.wiring import build_planner
    from pivotd.errors import InputError
    from pivotd.maps.formats import LandmarkCloud
    from pivotd.maps.store import MapStore
    from pivotd.pivot.scenes import hallway
    from pivotd.robot_path import Polyline
    from pivotd.sim.launch import REPO

    if args.far < 0:
        raise InputError(f"--far must be >= 0, got {args.far}")
    if not (math.isfinite(args.speed) and args.speed > 0):
        raise InputError(f"--speed must be > 0 m/s, got {args.speed}")
    config = args.config or REPO / "config" / "demo.yaml"
    cfg = load_config(config)
    cfg = replace(cfg, planner=replace(cfg.planner, horizon=args.horizon, max_landmarks_per_waypoint=args.cap or 0))
    n_rich = round(args.landmarks * 0.95)
    sc = hallway(rich_side_points=n_rich, poor_side_points=args.landmarks - n_rich, spacing=0.5)
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    planner = build_planner(cfg)
    settings, flt = planner.settings, planner.settings.retained_filter
    mount, limits = cfg.gimbal.mount, cfg.gimbal.limits
    planner.set_path(sc.path, None, 1)
    track = Polyline(sc.path)
    snap = store.snapshot()
    far = None
    if args.far:
        big = MapStore()
        pts = np.concatenate([sc.points.astype(np.float32), far_landmarks(args.far, sc.path, 2 * flt.max_range)])
        big.set_layer("base", LandmarkCloud(points=pts, weights=np.ones(pts.shape[0], np.float32)))
        far = (build_planner(cfg), big.snapshot(), [])
        far[0].set_path(sc.path, None, 1)
    other = None
    if args.compare_with:
        other_planner, other_snap = _other_planner(args.compare_with, sc.points.astype(np.float32), sc.path,
                                                   config, args.horizon, args.cap)
        other = {"planner": other_planner, "snap": other_snap, "cpu": [], "wall": [], "visible": [], "new": []}
    replans = 100 if args.quick else args.replans
    horizon_len = 0.5 * (args.horizon - 1)
    s_max = max(track.length - horizon_len, 0.0)
    q = np.array([0.0, 0.0, 0.0, 1.0])

    dt = args.step / args.speed
    t0 = time.perf_counter()
    pos, quat = track.sample(np.array([0.0]))
    plan = _replan(planner, snap, pos[0], quat[0], None, 0.0)
    cold = time.perf_counter() - t0
    anchor = plan.directions[0]
    if far:
        far_anchor = _replan(far[0], far[1], pos[0], quat[0], None, 0.0).directions[0]
    if other:
        other["anchor"] = _replan(other["planner"], other["snap"], pos[0], quat[0], None, 0.0).directions[0]
    prev, prev_anchor = plan, anchor
    total, cpu, query, retained_counts, union_counts, quality = [], [], [], [], [], []
    new_path: list[float] = []
    visible_sums = []
    full = RecedingHorizonPlanner(replace(settings, max_landmarks_per_waypoint=None), mount, limits)
    for k in with_progress(range(1, replans + 1), "replans"):
        s = (k * args.step) % max(s_max, 1e-9)
        fresh = s < args.step
        if fresh:  # wrapped around: start a new pass with a fresh path version
            planner.set_path(sc.path, None, k + 1)
            if far:
                far[0].set_path(sc.path, None, k + 1)
            if other:
                other["planner"].set_path(sc.path, None, k + 1)
        pos, quat = track.sample(np.array([s]))
        qk = quat[0] if quat is not None else q
        if other and k % 2:  # the other version first on odd replans, after this one on even ones
            _replan_other(other, pos[0], qk, k * dt, fresh)
        if far:  # the same replan on the map with the far landmarks, interleaved
            t1 = time.perf_counter()
            far_plan = _replan(far[0], far[1], pos[0], qk, far_anchor, k * dt)
            far[2].append(time.perf_counter() - t1)
            far_anchor = far_plan.directions[0]
        t1, c1 = time.perf_counter(), time.process_time()
        plan = _replan(planner, snap, pos[0], qk, anchor, k * dt)
        if fresh:
            new_path.append(time.process_time() - c1)
        else:
            total.append(time.perf_counter() - t1)
            cpu.append(time.process_time() - c1)
        anchor = plan.directions[0]
        visible_sums.append(int(np.sum(plan.visible)))
        if other and not k % 2:
            _replan_other(other, pos[0], qk, k * dt, fresh)
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
            full.speed, full.turn_rate, full.cruise_speed = planner.speed, planner.turn_rate, planner.cruise_speed
            ref = _replan(full, snap, pos[0], qk, prev_anchor, None)
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
        "new_path_cpu_ms_p50": ms(new_path, 50) if new_path else None,
        "new_path_cpu_ms_max": round(max(new_path) * 1e3, 3) if new_path else None,
        "new_paths": len(new_path),
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
        result["compare_with"] = args.compare_with
        result["other_replan_cpu_ms_p50"] = ms(other["cpu"], 50)
        result["other_replan_cpu_ms_p99"] = ms(other["cpu"], 99)
        result["other_replan_ms_p50"] = ms(other["wall"], 50)
        result["other_replan_ms_p99"] = ms(other["wall"], 99)
        result["other_new_path_cpu_ms_max"] = round(max(other["new"]) * 1e3, 3) if other["new"] else None
        result["cpu_p50_ratio_vs_other"] = round(result["replan_cpu_ms_p50"] / result["other_replan_cpu_ms_p50"], 3)
        result["cpu_p99_ratio_vs_other"] = round(result["replan_cpu_ms_p99"] / result["other_replan_cpu_ms_p99"], 3)
        result["visible_vs_other"] = round(ours_vis / max(float(np.mean(other["visible"])), 1e-9), 4)
    print(f"receding horizon ({config}): {args.landmarks} landmarks, {args.horizon} waypoints, {len(total)} "
          f"warm-started replans, {len(new_path)} on a new path")
    print(f"  retained per waypoint (mean)     {result['retained_per_waypoint_mean']:.0f}  "
          f"(distinct over the horizon {result['retained_union_mean']:.0f})")
    print(f"  replan p50 / p99                 {result['replan_ms_p50']} / {result['replan_ms_p99']} ms  "
          "(goal p99 <= 10 ms)")
    print(f"  replan CPU time p50 / p99        {result['replan_cpu_ms_p50']} / {result['replan_cpu_ms_p99']} ms  "
          "(this process only: less sensitive to other load)")
    print(f"  full map query of all waypoints  {result['map_query_ms_p50']} / {result['map_query_ms_p99']} ms "
          "(p50 / p99; replans query only the waypoints new to the window)")
    print(f"  first plan (cold seeds)          {result['cold_start_ms']} ms")
    if new_path:
        print(f"  plan on a new path (CPU)         p50 {result['new_path_cpu_ms_p50']} ms, max "
              f"{result['new_path_cpu_ms_max']} ms over {len(new_path)} (goal <= 150 ms at 40 waypoints)")
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
    if args.json:
        args.json.write_text(json.dumps(result, indent=2))
    return 0


def _replan_other(other: dict, position: np.ndarray, quat: np.ndarray, now: float, fresh: bool) -> None:
    """One timed replan of the other version (--compare-with), warm-started from its previous plan (``fresh``: the
    first on a new path, timed apart)."""
    c, t = time.process_time(), time.perf_counter()
    plan = _replan(other["planner"], other["snap"], position, quat, other["anchor"], now)
    if fresh:
        other["new"].append(time.process_time() - c)
    else:
        other["wall"].append(time.perf_counter() - t)
        other["cpu"].append(time.process_time() - c)
    other["anchor"] = plan.directions[0]
    other["visible"].append(int(np.sum(plan.visible)))
