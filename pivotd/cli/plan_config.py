"""``pivotd plan --config``: the daemon's receding-horizon replans along a path, offline (pivotd.daemon.offline)."""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pivotd.errors import InputError

#: Options of the paper mode that a config sets instead: option -> (argparse dest, the config key to set).
CONFLICTS: dict[str, tuple[str, str]] = {
    "--fov-deg": ("fov_deg", "pivot.fov_deg"),
    "--lambda": ("lam", "pivot.lambda"),
    "--smooth-knee-deg": ("smooth_knee_deg", "pivot.smooth_knee_deg"),
    "--max-step-deg": ("max_step_deg", "planner.max_step_deg"),
    "--min-range": ("min_range", "map.filters.min_range"),
    "--max-range": ("max_range", "map.filters.max_range"),
    "--weights-from": ("weights_from", "map.weight_property"),
    "--weight-property": ("weight_property", "map.weight_property"),
    "--max-view-angle-deg": ("max_view_angle_deg", "map.filters.max_view_angle_deg"),
    "--occlusion-voxel": ("occlusion_voxel", "map.filters.occlusion_voxel"),
    "--occupancy": ("occupancy", "map.filters.occupancy_file"),
}


def check_no_conflicts(args: argparse.Namespace) -> None:
    """One-line InputError naming the first paper-mode option given together with ``--config``."""
    for option, (dest, key) in CONFLICTS.items():
        if getattr(args, dest) is not None:
            raise InputError(f"{option} cannot be combined with --config: the config sets it ({key})")


def run_config(args: argparse.Namespace) -> int:
    from pivotd.config import load_config
    from pivotd.daemon.offline import plan_along_path
    from pivotd.daemon.wiring import build_map_store
    from pivotd.robot_path import load_path

    check_no_conflicts(args)
    cfg = load_config(args.config)
    if args.map is not None:
        cfg = replace(cfg, map=replace(cfg.map, file=Path(args.map).resolve()))
    elif cfg.map.file is None:
        raise InputError(f"{args.config}: map.file is not set (the daemon takes its landmarks from the bus): "
                         "give --map MAP")
    path = load_path(args.path)
    store = build_map_store(cfg)  # as the daemon's planner process loads it
    t0 = time.perf_counter()
    steps = plan_along_path(cfg, store, path)
    plan_s = time.perf_counter() - t0
    pans = np.degrees([st.pan for st in steps])
    tilts = np.degrees([st.tilt for st in steps])
    visible = np.array([st.visible for st in steps])
    if args.out:
        from pivotd.cli.plan import write_csv

        write_csv(Path(args.out), np.array([st.position for st in steps]), np.array([st.direction for st in steps]),
                  visible, np.column_stack([pans, tilts]))
    if args.first_plan_out:
        _write_first_plan(Path(args.first_plan_out), steps[0])
    summary = {
        "config": str(cfg.source),
        "map": str(cfg.map.file),
        "landmarks": len(store.snapshot()),
        "path_length_m": round(float(steps[-1].s), 6),
        "replans": len(steps),
        "waypoint_spacing_m": cfg.planner.waypoint_spacing,
        "horizon": cfg.planner.horizon,
        "fov_deg": round(math.degrees(cfg.pivot.fov), 9),
        "lambda": cfg.pivot.lam,
        "smooth_knee_deg": round(math.degrees(cfg.pivot.smooth_knee), 9),
        "plan_s": round(plan_s, 6),
        "visible_mean": float(np.mean(visible)),
        "visible_min": int(np.min(visible)),
        "visible_max": int(np.max(visible)),
        "pan_deg_min": round(float(pans.min()), 6),
        "pan_deg_max": round(float(pans.max()), 6),
        "tilt_deg_min": round(float(tilts.min()), 6),
        "tilt_deg_max": round(float(tilts.max()), 6),
        "clamped": int(sum(st.clamped for st in steps)),
        "degraded": int(sum(st.plan.degrade > 0 for st in steps)),
        "first_visible": steps[0].visible,
        "out": args.out,
        "first_plan_out": args.first_plan_out,
    }
    if args.json:
        sys.stdout.write(json.dumps(summary) + "\n")
    else:
        print(
            f"planned as the daemon of {cfg.source} does: {summary['replans']} replans along "
            f"{summary['path_length_m']:.2f} m ({cfg.planner.waypoint_spacing:g} m apart, {cfg.planner.horizon} "
            f"waypoints ahead) against {summary['landmarks']} landmarks in {plan_s:.1f} s\n"
            f"visible at the robot: mean {summary['visible_mean']:.1f}, min {summary['visible_min']}, "
            f"max {summary['visible_max']}; pan {summary['pan_deg_min']:.1f}..{summary['pan_deg_max']:.1f} deg, "
            f"tilt {summary['tilt_deg_min']:.1f}..{summary['tilt_deg_max']:.1f} deg"
            + (f"; {summary['clamped']} out of reach" if summary["clamped"] else "")
            + (f"\nwrote {args.out}" if args.out else "")
            + (f"\nwrote {args.first_plan_out}" if args.first_plan_out else "")
        )
    return 0


def _write_first_plan(out: Path, step) -> None:
    """The first replan as JSON: the robot's pose, and the plan's mode, arc lengths [m], camera positions [m],
    world directions, hard counts and joint pans [deg] per waypoint."""
    plan = step.plan
    doc = {
        "body_position": step.position.tolist(),
        "body_quat": step.quat.tolist(),
        "path_mode": plan.path_mode.value,
        "s": plan.s.tolist(),
        "positions": plan.positions.tolist(),
        "directions": plan.directions.tolist(),
        "visible": [int(v) for v in plan.visible],
        "pans_deg": None if plan.pans is None else np.degrees(plan.pans).tolist(),
    }
    try:
        out.write_text(json.dumps(doc) + "\n")
    except OSError as exc:
        raise InputError(f"{out}: cannot write ({exc.strerror or exc})") from None
