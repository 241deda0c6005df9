"""``pivotd plan``: optimise one viewing direction per waypoint of a path against a landmark map, offline.

Without ``--config`` the paper's trajectory PIVOT on the whole path at once (the paper mode); with it the
daemon's own replans along the path (:mod:`pivotd.cli.plan_config`)."""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from dataclasses import replace
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.maps.formats import TEXT_SUFFIXES, text_map_weight_column
from pivotd.pivot.steps import MAX_STEP_RANGE_DEG

log = logging.getLogger(__name__)

WEIGHTS_HELP = (
    "where feature weights come from: 'auto' (default) uses the map's 4th column when it has one, "
    "else uniform weights; '4' or 'w' requires the 4th column (x y z w) and uses it; "
    "'none' ignores any weight column (uniform weights)"
)


#: The paper mode's settings (without --config): FoV [deg], λ, weights column; the optimizer's are
#: TrajectoryOptions.paper() (its smoothness knee the default of --smooth-knee-deg), without distance weights.
PAPER_FOV_DEG = 30.0
PAPER_LAMBDA = 0.6
PAPER_WEIGHTS_FROM = "auto"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", default=None, metavar="CFG",
                        help="plan as the daemon configured by CFG does: its map, filters, planner, mount and joint "
                             "limits, one receding-horizon replan every planner.waypoint_spacing along the path "
                             "(docs/CLI.md); the paper-mode options below are then errors")
    parser.add_argument("--map", default=None, metavar="MAP",
                        help="landmark map (.npy, .txt, .csv, .xyz, .ply, .pcd, COLMAP); required without --config, "
                             "default with it: the config's map.file")
    parser.add_argument("--path", required=True, metavar="PATH", help="path CSV: x,y,z or t,x,y,z,qw,qx,qy,qz rows")
    parser.add_argument("--fov-deg", type=float, default=None,
                        help=f"full cone opening angle [deg] (default {PAPER_FOV_DEG:g})")
    parser.add_argument(
        "--lambda", dest="lam", type=float, default=None, metavar="LAMBDA",
        help=f"smoothness weight λ ≥ 0 (default {PAPER_LAMBDA:g}); 0 optimises every waypoint independently",
    )
    parser.add_argument(
        "--smooth-knee-deg", type=float, default=None, metavar="DEG",
        help="steps beyond about DEG cost in proportion to their size, not its square (0–180; default 0: the "
             "paper's 1 − cos per step; the daemon's pivot.smooth_knee_deg defaults to 1)",
    )
    parser.add_argument(
        "--max-step-deg", type=float, default=None, metavar="S",
        help=f"hard limit on the turn between consecutive directions [deg], {MAX_STEP_RANGE_DEG[0]:g}–"
             f"{MAX_STEP_RANGE_DEG[1]:g}; every step of the plan stays within it (default: no limit)",
    )
    parser.add_argument("--min-range", type=float, default=None, metavar="M", help="ignore landmarks closer than M")
    parser.add_argument("--max-range", type=float, default=None, metavar="M", help="ignore landmarks farther than M")
    parser.add_argument("--weights-from", default=None, metavar="COLUMN", help=WEIGHTS_HELP)
    parser.add_argument("--weight-property", default=None, metavar="NAME",
                        help="the feature weight's vertex property (PLY), field (PCD) or header column (text maps)")
    parser.add_argument("--max-view-angle-deg", type=float, default=None, metavar="DEG",
                        help="drop landmarks seen from more than DEG away from their mean observation direction "
                             "(needs observation directions: a COLMAP model with its images)")
    parser.add_argument("--occlusion-voxel", type=float, default=None, metavar="M",
                        help="drop landmarks hidden from the waypoint by occupied voxels of this size [m]; the "
                             "occupancy grid is built from the map itself or from --occupancy")
    parser.add_argument("--occupancy", default=None, metavar="FILE",
                        help="separate occupancy cloud (any map format) for --occlusion-voxel")
    parser.add_argument("--out", default=None, metavar="OUT.csv",
                        help="write i,x,y,z,dx,dy,dz,visible rows here (with --config also pan_deg,tilt_deg)")
    parser.add_argument("--first-plan-out", default=None, metavar="FILE.json",
                        help="with --config: write the first replan (every waypoint of its horizon) as JSON")
    parser.add_argument("--json", action="store_true", help="print one JSON object with the summary on stdout")


def _paper_defaults(args: argparse.Namespace, knee_deg: float) -> None:
    """Fill the paper mode's defaults into the options left out (they are None so --config can tell); ``knee_deg``:
    the smoothness knee of the optimizer's paper settings [deg]."""
    if args.map is None:
        raise InputError("--map MAP is required (or --config CFG, whose map.file is the default)")
    if args.first_plan_out is not None:
        raise InputError("--first-plan-out needs --config (without it there is one plan, written by --out)")
    for dest, value in (("fov_deg", PAPER_FOV_DEG), ("lam", PAPER_LAMBDA), ("smooth_knee_deg", knee_deg),
                        ("weights_from", PAPER_WEIGHTS_FROM)):
        if getattr(args, dest) is None:
            setattr(args, dest, value)


def check_max_step_deg(value: float | None, what: str = "--max-step-deg") -> None:
    """Raise InputError unless ``value`` is None or a finite step limit within MAX_STEP_RANGE_DEG [deg]."""
    lo, hi = MAX_STEP_RANGE_DEG
    if value is not None and not (math.isfinite(value) and lo <= value <= hi):
        raise InputError(f"{what} must be a finite angle in [{lo:g}, {hi:g}] degrees, got {value}")


def _check_args(args: argparse.Namespace) -> None:
    if not (math.isfinite(args.fov_deg) and 0.0 < args.fov_deg < 180.0):
        raise InputError(f"--fov-deg must be in (0, 180) degrees, got {args.fov_deg}")
    if not (math.isfinite(args.lam) and args.lam >= 0.0):
        raise InputError(f"--lambda must be a finite number >= 0, got {args.lam}")
    if not (math.isfinite(args.smooth_knee_deg) and 0.0 <= args.smooth_knee_deg <= 180.0):
        raise InputError(f"--smooth-knee-deg must be in [0, 180], got {args.smooth_knee_deg}")
    check_max_step_deg(args.max_step_deg)
    for name in ("min_range", "max_range"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v >= 0.0):
            raise InputError(f"--{name.replace('_', '-')} must be a finite distance >= 0 m, got {v}")
    for name in ("max_view_angle_deg", "occlusion_voxel"):
        v = getattr(args, name)
        if v is not None and not (math.isfinite(v) and v > 0.0):
            raise InputError(f"--{name.replace('_', '-')} must be a finite number > 0, got {v}")
    if args.occupancy is not None and args.occlusion_voxel is None:
        raise InputError(f"--occupancy {args.occupancy}: needs --occlusion-voxel")
    if args.min_range is not None and args.max_range is not None and args.min_range > args.max_range:
        raise InputError(f"--min-range ({args.min_range}) is larger than --max-range ({args.max_range})")
    if args.weights_from.lower() not in ("auto", "4", "w", "none"):
        raise InputError(f"--weights-from must be auto, 4, w or none, got {args.weights_from!r}")


def _weights(args: argparse.Namespace, cloud) -> np.ndarray | None:
    mode = args.weights_from.lower()
    has_column = cloud.weights is not None and not np.all(cloud.weights == 1.0)
    if mode == "none":
        return None
    if mode in ("4", "w"):
        raw = _column_count(Path(args.map), args.weight_property)
        if raw is not None and raw < 4:
            raise InputError(
                f"{args.map}: --weights-from {args.weights_from} needs a weight column (a 4th column, or one named "
                "weight or w in a header row); the map has none"
            )
        return cloud.weights  # as stored: the optimizer reads only the retained rows
    return cloud.weights if has_column else None


def _column_count(path: Path, weight_property: str | None) -> int | None:
    """Columns of a .npy map; 4 or 3 for a text map with or without a weight column (None when the format
    does not say)."""
    suffix = path.suffix.lower()
    if suffix == ".npy":
        try:
            return int(np.load(path, mmap_mode="r").shape[1])
        except (ValueError, OSError, IndexError):
            return None
    if suffix in TEXT_SUFFIXES:
        has_weight = text_map_weight_column(path, weight_property)
        return None if has_weight is None else 4 if has_weight else 3
    return None


def _uses_map_filters(args: argparse.Namespace) -> bool:
    return any(v is not None for v in (args.min_range, args.max_range, args.max_view_angle_deg, args.occlusion_voxel))


def load_filtered(args: argparse.Namespace, waypoints: np.ndarray):
    """Landmarks and per-waypoint retained index arrays from the map store (range, view, occlusion filters).

    Returns (points (M, 3), weights (M,), retained list of N index arrays in the store's spatial order
    (pivotd.maps.store.spatial_cell_order), seconds spent in the retained-set query); points are in the
    store's order.
    """
    from pivotd.maps.filters import RetainedFilter
    from pivotd.maps.store import load_map_store

    store = load_map_store(args.map, weight_property=args.weight_property, occlusion_voxel=args.occlusion_voxel,
                           occupancy_file=args.occupancy)
    snap = store.snapshot()
    if args.max_view_angle_deg is not None and snap.directions is None:
        raise InputError(f"{args.map}: --max-view-angle-deg needs observation directions (a COLMAP model "
                         "with images.bin/images.txt beside points3D)")
    flt = RetainedFilter(min_range=args.min_range or 0.0,
                         max_range=math.inf if args.max_range is None else args.max_range,
                         max_view_angle_deg=args.max_view_angle_deg, occlusion=args.occlusion_voxel is not None)
    t0 = time.perf_counter()
    # the store's rows are in a spatial order fixed by the landmarks: the plan does not depend on their file order
    retained = snap.retained(waypoints, flt)
    return snap.points, snap.weights, retained, time.perf_counter() - t0


def run(args: argparse.Namespace) -> int:
    if args.config is not None:
        from pivotd.cli.plan_config import run_config

        return run_config(args)
    from pivotd.maps.formats import LandmarkCloud, load_landmarks
    from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory
    from pivotd.robot_path import load_path

    paper = TrajectoryOptions.paper()
    _paper_defaults(args, paper.smooth_knee_deg)
    _check_args(args)
    path = load_path(args.path)
    waypoints = path.positions
    if _uses_map_filters(args):
        points, cloud_weights, retained, filter_s = load_filtered(args, waypoints)
        cloud = LandmarkCloud(points=points, weights=cloud_weights)
    else:
        cloud = load_landmarks(args.map, weight_property=args.weight_property)
        points, retained, filter_s = cloud.points, None, 0.0
    weights = _weights(args, cloud)
    alpha = math.radians(args.fov_deg) / 2.0

    t0 = time.perf_counter()
    # The paper's settings, but the plan is judged by hard visible counts, so landmarks are weighted by their
    # feature weight only (the paper's distance weights favour near landmarks over the count).
    max_step = None if args.max_step_deg is None else math.radians(args.max_step_deg)
    result = optimize_trajectory(
        points, waypoints, alpha, args.lam, weights=weights, retained=retained, max_step=max_step,
        options=replace(paper, distance_weights=False, smooth_knee_deg=args.smooth_knee_deg),
    )
    optimize_s = time.perf_counter() - t0 + filter_s

    C = result.directions
    steps = np.degrees(np.arctan2(np.linalg.norm(np.cross(C[1:], C[:-1]), axis=1), np.sum(C[1:] * C[:-1], axis=1)))
    largest = float(steps.max()) if steps.size else 0.0
    if args.out:
        write_csv(Path(args.out), waypoints, C, result.visible)
    summary = {
        "waypoints": int(waypoints.shape[0]),
        "landmarks": int(points.shape[0]),
        "fov_deg": float(args.fov_deg),
        "lambda": float(args.lam),
        "smooth_knee_deg": float(args.smooth_knee_deg),
        "optimize_s": round(optimize_s, 6),
        "visible_mean": float(np.mean(result.visible)),
        "visible_min": int(np.min(result.visible)),
        "visible_max": int(np.max(result.visible)),
        "max_step_deg": round(largest, 4),
        "max_step_limit_deg": args.max_step_deg,
        "iterations": int(result.iterations),
        "out": args.out,
        **filter_settings(args),
    }
    if args.json:
        sys.stdout.write(json.dumps(summary) + "\n")
    else:
        print(
            f"planned {summary['waypoints']} waypoints against {summary['landmarks']} landmarks "
            f"(FoV {args.fov_deg:g} deg, lambda {args.lam:g}) in {optimize_s * 1e3:.1f} ms\n"
            f"visible per waypoint: mean {summary['visible_mean']:.1f}, min {summary['visible_min']}, "
            f"max {summary['visible_max']}; largest step between directions {largest:.2f} deg"
            + (f"\nwrote {args.out}" if args.out else "")
        )
    return 0


def filter_settings(args: argparse.Namespace) -> dict:
    """The paper mode's landmark filter settings as given (None: not set): ranges [m], view angle [deg], occlusion
    voxel [m], occupancy file, where weights come from and the weight property (``plan --json``, docs/CLI.md)."""
    return {"min_range": args.min_range, "max_range": args.max_range, "max_view_angle_deg": args.max_view_angle_deg,
            "occlusion_voxel": args.occlusion_voxel,
            "occupancy": None if args.occupancy is None else str(args.occupancy),
            "weights_from": args.weights_from.lower(), "weight_property": args.weight_property}


def write_csv(out: Path, waypoints: np.ndarray, dirs: np.ndarray, visible: np.ndarray,
              joints_deg: np.ndarray | None = None) -> None:
    """Rows ``i,x,y,z,dx,dy,dz,visible`` of positions (N, 3) [m], directions (N, 3) and counts (N,), with
    ``pan_deg,tilt_deg`` after them when ``joints_deg`` (N, 2) is given."""
    try:
        with out.open("w") as fh:
            fh.write("i,x,y,z,dx,dy,dz,visible" + (",pan_deg,tilt_deg" if joints_deg is not None else "") + "\n")
            for i, (p, d, v) in enumerate(zip(waypoints, dirs, visible, strict=True)):
                row = f"{i},{p[0]:.6f},{p[1]:.6f},{p[2]:.6f},{d[0]:.9f},{d[1]:.9f},{d[2]:.9f},{int(v)}"
                if joints_deg is not None:
                    row += f",{joints_deg[i, 0]:.6f},{joints_deg[i, 1]:.6f}"
                fh.write(row + "\n")
    except OSError as exc:
        raise InputError(f"{out}: cannot write ({exc.strerror or exc})") from None
