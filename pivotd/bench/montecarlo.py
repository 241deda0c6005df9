"""``pivotd bench montecarlo``: the paper's Monte Carlo evaluation (§V-A.2), the FIF y-corridor plan and
(``--scenes hard|all``) single pose on the hard scene families against the refined reference.

Per feature-count level: PIVOT (single-pose optimizer) and the 2° brute force on the same bearings of
each pose, timed back to back in alternating order (median ms per pose), the ratio of the medians, and
the retained visibility 100·V_PIVOT/V_BF (mean, 5th percentile, min), next to the paper's figures. The
FIF section times the whole-trajectory optimisation of tests/data/fif/ycorridor (30° FoV, λ = 0.6) and
compares it with the λ = 0 plan and with the exact best plans on a 2° direction grid with and without a
step limit (the visibility any plan with that largest step can reach, up to the grid's resolution).
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import time
from collections.abc import Callable
from dataclasses import replace
from pathlib import Path
from typing import Any

import numpy as np

from pivotd.bench._stats import best_of, median, percentile, quality_stats, steady_heap, timed
from pivotd.progress import with_progress

log = logging.getLogger(__name__)

PAPER = {
    "pivot_ms": (1.9, 15.2),
    "brute_ms": (144.2, 1289.7),
    "speedup": (76, 85),
    "retained_pct": (98.1, 99.6),
}
FIF_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "fif"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="3 levels × 40 poses (under a minute on 2 cores)")
    parser.add_argument("--json", metavar="FILE", help="write the result table as JSON")
    parser.add_argument("--plot", metavar="FILE", help="draw the figure-4 equivalents (matplotlib)")
    parser.add_argument("--poses", type=int, default=None, help="poses per level (a fixed spread subset; default 400)")
    parser.add_argument("--fov-deg", type=float, default=30.0, help="full FoV opening angle (default 30)")
    parser.add_argument("--resolution-deg", type=float, default=2.0, help="brute-force grid resolution")
    parser.add_argument(
        "--pareto", action="store_true",
        help="only the trajectory plans against the exact step-limited grid plan (FIF, competing clusters, a "
             "path through each hard family): own largest step and hard step limits 5 and 10 deg",
    )
    parser.add_argument(
        "--scenes", choices=("paper", "hard", "all"), default="paper",
        help="paper: the Monte Carlo levels and the FIF plan (default); hard: single pose on every hard scene "
        "family against the refined reference; all: both",
    )
    parser.add_argument(
        "--scene-seeds", type=int, default=None, help="hard scenes: seeded instances per family (default 3, quick 2)"
    )
    parser.add_argument(
        "--scene-poses", type=int, default=None, help="hard scenes: sensor poses per instance (default 20, quick 6)"
    )
    parser.add_argument(
        "--compare-with", metavar="PKG",
        help="also time optimize_view of PKG (a renamed copy of another pivotd version on PYTHONPATH) "
             "next to this tree's on the same poses (Monte Carlo levels and hard scenes) and report both; "
             "with --pareto, PKG's optimize_trajectory is timed in the same interleaved run",
    )
    parser.add_argument(
        "--narrow", action="store_true",
        help="only narrow cones (half-angles 0.5-5 deg): quality against the exact optimum on small instances "
             "of every hard family, and the cost per pose at full size (pivotd.bench.narrow)",
    )
    parser.add_argument(
        "--normalise", choices=("total", "attainable"), default="total",
        help="--pareto and --fov-carry: each waypoint's visible weight over its total (default) or attainable "
             "weight (TrajectoryOptions.normalise)",
    )
    parser.add_argument(
        "--fov-carry", action="store_true",
        help="only: does lambda mean the same across FoVs? Smooth plans with a 2 and a 30 deg cone on the same "
             "paths, visible sum as %% of the lambda 0 plan's, with total and attainable normalisation",
    )
    parser.add_argument(
        "--replan", action="store_true",
        help="only the warm-started replanning regime: 40 waypoints, 20k landmarks, anchor + pan/tilt limits",
    )


def _other_view(compare_with: str | None, alpha: float | None = None) -> Callable[..., Any] | None:
    """optimize_view of ``compare_with`` (a renamed copy of another pivotd version on the path), or None. With
    ``alpha`` (every call uses that half-angle) and a version that takes a prebuilt cone kernel, its own kernel
    of α is built once here, as this tree's is (:func:`_solvers`), so neither side pays it per call."""
    if not compare_with:
        return None
    import inspect
    from functools import partial

    from pivotd.bench.horizon import _module

    view = _module(compare_with, "pivot.view").optimize_view
    if alpha is not None and "kernel" in inspect.signature(view).parameters:
        return partial(view, kernel=_module(compare_with, "pivot.cone_kernel").cone_kernel(alpha))
    return view


def _level_rows(
    levels: list[int], pose_idx: np.ndarray, alpha: float, res: float, compare_with: str | None = None
) -> tuple[list[dict], dict]:
    from pivotd.pivot.lattice import sphere_grid
    from pivotd.pivot.scenes import monte_carlo_levels, monte_carlo_map, monte_carlo_poses

    optimize_view, brute_force_view = _solvers(alpha, sphere_grid(res))
    other_view = _other_view(compare_with, alpha)
    poses = monte_carlo_poses()[pose_idx]
    counts = monte_carlo_levels()
    rows, detail = [], {}
    for level in with_progress(levels, "Monte Carlo map sizes"):
        pts = monte_carlo_map(level)
        t_piv, t_bf, ratio, d_piv, d_bf, t_other, other_ratio = [], [], [], [], [], [], []
        for t in poses:
            diff = pts - t
            bearings = diff / np.linalg.norm(diff, axis=1, keepdims=True)
            if len(t_piv) % 2 == 0:  # alternate which side runs first
                r, dt = timed(optimize_view, bearings, None, alpha)
                (d, best), db = timed(brute_force_view, bearings, None, alpha, res)
                if other_view is not None:
                    ro, do = timed(other_view, bearings, None, alpha)
            else:
                if other_view is not None:
                    ro, do = timed(other_view, bearings, None, alpha)
                (d, best), db = timed(brute_force_view, bearings, None, alpha, res)
                r, dt = timed(optimize_view, bearings, None, alpha)
            t_piv.append(dt)
            t_bf.append(db)
            if other_view is not None:
                t_other.append(do)
                other_ratio.append(100.0 * ro.visible / best if best > 0 else 100.0)
            ratio.append(100.0 * r.visible / best if best > 0 else 100.0)
            d_piv.append(r.direction)
            d_bf.append(d)
        row = {
            "level": level,
            "features": counts[level],
            "poses": len(poses),
            "pivot_ms": 1e3 * median(t_piv),
            "brute_ms": 1e3 * median(t_bf),
            "speedup": median(t_bf) / median(t_piv),
            "retained_mean_pct": float(np.mean(ratio)),
            "retained_p5_pct": percentile(ratio, 5),
            "retained_min_pct": float(np.min(ratio)),
        }
        if other_view is not None:
            row.update({"other_ms": 1e3 * median(t_other), "other_speedup": median(t_bf) / median(t_other),
                        "other_retained_mean_pct": float(np.mean(other_ratio)),
                        "other_retained_min_pct": float(np.min(other_ratio))})
        rows.append(row)
        detail[level] = {"ratio": np.array(ratio), "pivot": np.array(d_piv), "brute": np.array(d_bf)}
        log.info("level %d (%d features) done", level, counts[level])
        _print_row(row)
        if other_view is not None:
            print(f"{'':>8} {compare_with}: {row['other_ms']:.3f} ms, {row['other_speedup']:.0f}x the brute force; "
                  f"retained mean {row['other_retained_mean_pct']:.2f} %, min {row['other_retained_min_pct']:.2f} %",
                  flush=True)
    return rows, detail


def _solvers(alpha: float, grid: np.ndarray) -> tuple[Callable[..., Any], Callable[..., Any]]:
    """optimize_view with the cone kernel of α and brute_force_view with ``grid``, both built once (each is
    data-independent set-up per half-angle / resolution, kept out of the timed calls alike)."""
    from functools import partial

    from pivotd.pivot.brute import brute_force_view
    from pivotd.pivot.cone_kernel import cone_kernel
    from pivotd.pivot.view import optimize_view

    return partial(optimize_view, kernel=cone_kernel(alpha)), partial(brute_force_view, grid=grid)


def hard_rows(
    seeds: int, poses: int, alpha: float, res: float, repeats: int = 3, compare_with: str | None = None
) -> list[dict]:
    """Single pose on every hard scene family (pivotd.pivot.scenes.HARD_FAMILIES): ``seeds`` instances of
    ``poses`` random sensor positions each. Per pose: the refined reference (pivotd.pivot.brute.refined_view,
    not timed) first, then ``repeats`` rounds of PIVOT and the ``res`` grid timed back to back on the same
    bearings, in alternating order (neither side always runs right after the reference or after the other);
    each side's time for the pose is the median of its rounds. Both answers are scored against the
    reference. Speedup: the ratio of the median times, and the median of the per-pose ratios (less exposed
    to the host's load drifting during the run). ``compare_with``: a renamed copy of another pivotd version
    on the path whose optimize_view is timed in the same rounds (its speedup and quality are reported too)."""
    from pivotd.pivot.brute import refined_view
    from pivotd.pivot.lattice import sphere_grid
    from pivotd.pivot.scenes import HARD_FAMILIES, hard_scene

    optimize_view, brute_force_view = _solvers(alpha, sphere_grid(res))
    other_view = _other_view(compare_with, alpha)
    rows = []
    for family in with_progress(HARD_FAMILIES, "hard scene families"):
        t_piv, t_grid, ratio, grid_ratio, gap, exact, sizes = [], [], [], [], [], 0, []
        t_other, other_ratio = [], []
        for seed in range(seeds):
            scene = hard_scene(family, seed, poses)
            sizes.append(scene.points.shape[0])
            for t in scene.path:
                diff = scene.points - t
                bearings = diff / np.linalg.norm(diff, axis=1, keepdims=True)
                ref = refined_view(bearings, None, alpha, res)
                dts, dgs, dos = [], [], []
                for k in range(max(1, repeats)):
                    if (len(t_piv) + k) % 2 == 0:
                        r, dt = timed(optimize_view, bearings, None, alpha)
                        (_, grid_best), dg = timed(brute_force_view, bearings, None, alpha, res)
                        if other_view is not None:
                            ro, do = timed(other_view, bearings, None, alpha)
                    else:
                        if other_view is not None:
                            ro, do = timed(other_view, bearings, None, alpha)
                        (_, grid_best), dg = timed(brute_force_view, bearings, None, alpha, res)
                        r, dt = timed(optimize_view, bearings, None, alpha)
                    dts.append(dt)
                    dgs.append(dg)
                    if other_view is not None:
                        dos.append(do)
                t_piv.append(median(dts))
                t_grid.append(median(dgs))
                if other_view is not None:
                    t_other.append(median(dos))
                    other_ratio.append(100.0 * ro.visible / ref.value if ref.value > 0 else 100.0)
                ratio.append(100.0 * r.visible / ref.value if ref.value > 0 else 100.0)
                grid_ratio.append(100.0 * grid_best / ref.value if ref.value > 0 else 100.0)
                gap.append(100.0 * (ref.bound - ref.value) / ref.value if ref.value > 0 else 0.0)
                exact += int(ref.exact)
        row = {
            "family": family,
            "landmarks": int(np.median(sizes)),
            "poses": len(ratio),
            "pivot_ms": 1e3 * median(t_piv),
            "grid_ms": 1e3 * median(t_grid),
            "speedup": median(t_grid) / median(t_piv),
            "speedup_per_pose": median(list(np.array(t_grid) / np.array(t_piv))),
            **quality_stats("ref", ratio),
            "grid_mean_pct": float(np.mean(grid_ratio)),
            "grid_min_pct": float(np.min(grid_ratio)),
            "ref_bound_gap_max_pct": float(np.max(gap)),
            "ref_exact": exact,
        }
        if other_view is not None:
            row.update({
                "other_ms": 1e3 * median(t_other),
                "other_speedup": median(t_grid) / median(t_other),
                "other_over_pivot": median(list(np.array(t_other) / np.array(t_piv))),
                **quality_stats("other", other_ratio),
            })
        rows.append(row)
        _print_hard_row(row)
        if other_view is not None:
            print(f"{'':>9} {compare_with}: {row['other_ms']:.3f} ms, {row['other_speedup']:.0f}x the grid, "
                  f"{row['other_over_pivot']:.2f}x this tree's time (per pose median); % of ref mean "
                  f"{row['other_mean_pct']:.2f}, p5 {row['other_p5_pct']:.2f}, min {row['other_min_pct']:.2f}",
                  flush=True)
    return rows


def _print_hard_header() -> None:
    print(
        f"{'family':>9} {'lmks':>6} {'poses':>5} {'PIVOT ms':>9} {'grid ms':>8} {'speedup':>8} {'per pose':>8} "
        f"{'ref mean%':>9} {'ref p5%':>8} {'ref min%':>8} {'grid mean%':>10} {'grid min%':>9} {'bound gap%':>10}"
    )


def _print_hard_row(r: dict) -> None:
    print(
        f"{r['family']:>9} {r['landmarks']:>6} {r['poses']:>5} {r['pivot_ms']:>9.3f} {r['grid_ms']:>8.1f} "
        f"{r['speedup']:>7.0f}x {r['speedup_per_pose']:>7.0f}x "
        f"{r['ref_mean_pct']:>9.2f} {r['ref_p5_pct']:>8.2f} {r['ref_min_pct']:>8.2f} "
        f"{r['grid_mean_pct']:>10.2f} {r['grid_min_pct']:>9.2f} {r['ref_bound_gap_max_pct']:>10.2f}",
        flush=True,
    )


def _print_header() -> None:
    print(
        f"{'features':>8} {'poses':>5} {'PIVOT ms':>9} {'brute ms':>9} {'speedup':>8} "
        f"{'ret mean%':>9} {'ret p5%':>8} {'ret min%':>8}"
    )


def _print_row(r: dict) -> None:
    print(
        f"{r['features']:>8} {r['poses']:>5} {r['pivot_ms']:>9.3f} {r['brute_ms']:>9.1f} {r['speedup']:>7.0f}x "
        f"{r['retained_mean_pct']:>9.2f} {r['retained_p5_pct']:>8.2f} {r['retained_min_pct']:>8.2f}",
        flush=True,
    )


def _paper_options(options_type: type, **changes):
    """The paper's settings with ``changes`` of a pivotd version's ``TrajectoryOptions`` (``paper()``, or the
    defaults of a version older than it)."""
    paper = getattr(options_type, "paper", None)
    return paper(**changes) if paper is not None else options_type(**changes)


def fif_section(repeats: int = 5) -> dict | None:
    """Whole-trajectory plan on the FIF y-corridor: time (median of ``repeats``), max step, visible vs λ = 0."""
    from pivotd.maps.formats import load_landmarks
    from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory
    from pivotd.robot_path import load_path

    map_file, path_file = FIF_DIR / "ycorridor_6x20_points_w.txt", FIF_DIR / "ycorridor_6x20.csv"
    if not (map_file.exists() and path_file.exists()):
        log.warning("FIF data not found under %s; skipping the FIF section", FIF_DIR)
        return None
    pts = load_landmarks(map_file).points
    way = load_path(path_file).positions
    alpha = math.radians(15.0)
    opts = TrajectoryOptions.paper(distance_weights=False)  # as `pivotd plan`
    smooth, times = best_of(lambda: optimize_trajectory(pts, way, alpha, 0.6, options=opts), repeats)
    free, times0 = best_of(lambda: optimize_trajectory(pts, way, alpha, 0.0, options=opts), max(1, repeats // 2))
    C = smooth.directions
    steps = np.degrees(np.arctan2(np.linalg.norm(np.cross(C[1:], C[:-1]), axis=1), np.sum(C[1:] * C[:-1], axis=1)))
    return {
        **_grid_reference(pts, way, alpha, float(steps.max())),
        "landmarks": int(pts.shape[0]),
        "waypoints": int(way.shape[0]),
        "optimize_ms": 1e3 * median(times),
        "optimize_ms_lambda0": 1e3 * median(times0),
        "max_step_deg": float(steps.max()),
        "visible_mean": float(smooth.visible.mean()),
        "visible_mean_lambda0": float(free.visible.mean()),
        "visible_ratio_pct": 100.0 * float(smooth.visible.mean()) / max(float(free.visible.mean()), 1e-12),
    }


def _steps_deg(C: np.ndarray) -> np.ndarray:
    return np.degrees(np.arctan2(np.linalg.norm(np.cross(C[1:], C[:-1]), axis=1), np.sum(C[1:] * C[:-1], axis=1)))


def interleaved_grid_speed(
    points: np.ndarray, waypoints: np.ndarray, alpha: float, grid: np.ndarray,
    plans: dict[str, Callable[[], Any]], chunks: int = 8,
) -> tuple[np.ndarray, float, dict[str, float], dict[str, Any]]:
    """Scoring the grid at every waypoint against plans, side by side on a shared machine.

    The grid is scored in ``chunks`` slices of waypoints, and every plan in ``plans`` runs once after each
    slice (after one warm-up call), so both see the same load; the plans' order is reversed after every other
    slice, so none is always the first to run after the grid has filled the caches. Times are CPU seconds of
    this process.
    Returns (V (N, G) grid visibility, total grid seconds, median seconds per plan, last result per plan).
    """
    from pivotd.pivot.brute import grid_visibility

    results = {name: fn() for name, fn in plans.items()}  # warm-up
    times: dict[str, list[float]] = {name: [] for name in plans}
    parts, grid_s = [], 0.0
    names = list(plans)
    for i, sl in enumerate(np.array_split(np.arange(waypoints.shape[0]), chunks)):
        if sl.size == 0:
            continue
        t0 = time.process_time()
        parts.append(grid_visibility(points, waypoints[sl], alpha, grid))
        grid_s += time.process_time() - t0
        for name in names if i % 2 == 0 else names[::-1]:
            fn = plans[name]
            t0 = time.process_time()
            results[name] = fn()
            times[name].append(time.process_time() - t0)
    return np.concatenate(parts), grid_s, {k: median(v) for k, v in times.items()}, results


def pareto_rows(
    limits_deg: tuple[float, ...] = (5.0, 10.0), families: bool = True, compare_with: str | None = None,
    only: tuple[str, ...] | None = None, normalise: str = "total",
) -> list[dict]:
    """Trajectory plans against the exact step-limited plan on the 2° grid (hard counts, `pivotd plan`'s
    objective): the λ = 0.6 plan against the best grid plan with its own largest step, and plans with a hard
    step limit S (``max_step``) against the best grid plan with steps ≤ S. Scenes: the FIF corridor (30°
    FoV), the competing-clusters path (60° FoV) and a 40-waypoint path through each hard scene family
    (30° FoV). Also the CPU time of the λ = 0.6 plan, with and without the step-limited polish, next to
    scoring the 2° grid at every waypoint, interleaved (:func:`interleaved_grid_speed`). ``compare_with``: a
    renamed copy of another pivotd version whose λ = 0.6 plan (its paper settings, no distance weights) is
    timed in the same interleaved run and judged the same way. ``only``: just the scenes with these names."""
    from pivotd.maps.formats import load_landmarks
    from pivotd.pivot.brute import best_grid_chain
    from pivotd.pivot.lattice import sphere_grid
    from pivotd.pivot.scenes import HARD_FAMILIES, competing_clusters_path, hard_path
    from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory
    from pivotd.robot_path import load_path

    scenes = []
    map_file, path_file = FIF_DIR / "ycorridor_6x20_points_w.txt", FIF_DIR / "ycorridor_6x20.csv"
    if map_file.exists() and path_file.exists():
        scenes.append(("fif", load_landmarks(map_file).points, load_path(path_file).positions, 15.0))
    cc = competing_clusters_path()
    scenes.append(("competing_clusters", cc.points, cc.path, 30.0))
    if families:
        for fam in HARD_FAMILIES:
            hp = hard_path(fam, 0)
            scenes.append((f"path_{fam}", hp.points, hp.path, 15.0))
    if only is not None:
        scenes = [sc for sc in scenes if sc[0] in only]
    grid = sphere_grid(2.0)
    opts = TrajectoryOptions.paper(distance_weights=False, normalise=normalise)
    other = None
    if compare_with:
        from pivotd.bench.horizon import _module

        other = _module(compare_with, "pivot.trajectory")
    rows = []
    for name, pts, way, half_deg in with_progress(scenes, "trajectory scenes"):
        alpha = math.radians(half_deg)
        variants = {
            "polish": lambda pts=pts, way=way, alpha=alpha: optimize_trajectory(pts, way, alpha, 0.6, options=opts),
            "bare": lambda pts=pts, way=way, alpha=alpha: optimize_trajectory(
                pts, way, alpha, 0.6, options=replace(opts, step_polish_deg=0.0)),
        }
        if other is not None:
            variants["other"] = lambda pts=pts, way=way, alpha=alpha: other.optimize_trajectory(
                pts, way, alpha, 0.6, options=_paper_options(other.TrajectoryOptions, distance_weights=False))
        V, grid_s, plan_s, plans = interleaved_grid_speed(pts, way, alpha, grid, variants)
        plan, bare = plans["polish"], plans["bare"]
        idx = np.arange(V.shape[0])
        own = float(_steps_deg(plan.directions).max()) if len(way) > 1 else 0.0
        row = {
            "scene": name, "landmarks": int(pts.shape[0]), "waypoints": int(way.shape[0]),
            "optimize_ms": 1e3 * plan_s["polish"], "grid_scoring_ms": 1e3 * grid_s,
            "speedup_vs_grid": grid_s / plan_s["polish"],
            "max_step_deg": own, "visible_sum": int(plan.visible.sum()),
            "grid_own_step_sum": float(V[idx, best_grid_chain(V, grid, own)].sum()),
        }
        row["own_step_pct"] = 100.0 * row["visible_sum"] / max(row["grid_own_step_sum"], 1e-12)
        # the same plan without the step-limited polish: what the polish costs and buys
        bare_step = float(_steps_deg(bare.directions).max()) if len(way) > 1 else 0.0
        row["no_polish_ms"] = 1e3 * plan_s["bare"]
        row["no_polish_speedup_vs_grid"] = grid_s / plan_s["bare"]
        row["no_polish_max_step_deg"] = bare_step
        row["no_polish_own_step_pct"] = 100.0 * float(bare.visible.sum()) / max(
            float(V[idx, best_grid_chain(V, grid, bare_step)].sum()), 1e-12)
        if other is not None:
            prev = plans["other"]
            prev_step = float(_steps_deg(prev.directions).max()) if len(way) > 1 else 0.0
            row["other"] = compare_with
            row["other_ms"] = 1e3 * plan_s["other"]
            row["other_speedup_vs_grid"] = grid_s / plan_s["other"]
            row["other_max_step_deg"] = prev_step
            row["other_own_step_pct"] = 100.0 * float(prev.visible.sum()) / max(
                float(V[idx, best_grid_chain(V, grid, prev_step)].sum()), 1e-12)
            row["speedup_vs_other"] = plan_s["other"] / plan_s["polish"]
        for lim in limits_deg:
            hard = optimize_trajectory(pts, way, alpha, 0.6, max_step=math.radians(lim), options=opts)
            ref = float(V[idx, best_grid_chain(V, grid, lim)].sum())
            row[f"limit_{lim:g}_max_step_deg"] = float(_steps_deg(hard.directions).max()) if len(way) > 1 else 0.0
            row[f"limit_{lim:g}_pct"] = 100.0 * float(hard.visible.sum()) / max(ref, 1e-12)
        rows.append(row)
        lims = "  ".join(f"S={lim:g}: {row[f'limit_{lim:g}_pct']:.2f} % (max {row[f'limit_{lim:g}_max_step_deg']:.2f})"
                         for lim in limits_deg)
        print(f"{name:>20} {row['landmarks']:>6} lm {row['waypoints']:>4} wp  lambda 0.6: "
              f"{row['optimize_ms']:8.1f} CPU ms ({row['speedup_vs_grid']:5.1f}x scoring the 2 deg grid at every "
              f"waypoint, interleaved), max step {own:5.2f} deg, "
              f"{row['own_step_pct']:.2f} % of the grid optimum at that step;  {lims};  without the polish "
              f"{row['no_polish_ms']:.1f} ms ({row['no_polish_speedup_vs_grid']:.1f}x), "
              f"{row['no_polish_own_step_pct']:.2f} % at {row['no_polish_max_step_deg']:.2f} deg", flush=True)
        if other is not None:
            print(f"{'':>20} {compare_with}: {row['other_ms']:.1f} CPU ms ({row['other_speedup_vs_grid']:.1f}x the "
                  f"grid), max step {row['other_max_step_deg']:.2f} deg, {row['other_own_step_pct']:.2f} % at that "
                  f"step; this tree is {row['speedup_vs_other']:.2f}x faster", flush=True)
    return rows


def _grid_reference(points: np.ndarray, waypoints: np.ndarray, alpha: float, plan_step_deg: float) -> dict:
    """Exact best plans on the 2° direction grid (pivotd.pivot.brute.best_grid_chain): without a step limit,
    with the λ = 0.6 plan's own largest step, and with the 10° goal; visible means."""
    from pivotd.pivot.brute import best_grid_chain, grid_visibility
    from pivotd.pivot.lattice import sphere_grid

    grid = sphere_grid(2.0)
    V = grid_visibility(points, waypoints, alpha, grid)
    rows = np.arange(V.shape[0])

    def best(limit: float | None) -> float:
        return float(V[rows, best_grid_chain(V, grid, limit)].mean())

    return {
        "grid_free_mean": best(None),
        "grid_plan_step_mean": best(plan_step_deg),
        "grid_10deg_mean": best(10.0),
    }


def replan_section(replans: int = 200, nearest: int | None = None) -> dict:
    """Warm-started trajectory replans as a receding-horizon planner issues them: a 40-waypoint window
    slides one waypoint per replan along a 2 m-spaced path over the 18k Monte Carlo map plus 2k more
    features (20k), warm start from the previous plan shifted by one, anchor = the previous first
    direction, tilt limited to ±60° (continuous pan). With ``nearest``, each waypoint retains only its
    ``nearest`` closest landmarks (index lists computed outside the timed call, as a spatial index would
    deliver them). Returns latency statistics [ms]."""
    from pivotd.pivot.constraints import PanTiltConstraint
    from pivotd.pivot.scenes import monte_carlo_map
    from pivotd.pivot.trajectory import optimize_trajectory

    pts = np.concatenate([monte_carlo_map(), monte_carlo_map(seed=1)[:2000]])
    n = 40
    x = np.linspace(-300.0, 300.0, replans + n + 1)
    path = np.column_stack([x, 50.0 + 40.0 * np.sin(x / 60.0), np.full_like(x, 20.0)])
    alpha = math.radians(15.0)
    con = PanTiltConstraint(np.tile(np.eye(3), (n, 1, 1)), -np.inf, np.inf, -math.radians(60), math.radians(60))
    prev = optimize_trajectory(pts, path[:n], alpha, 0.6, constraint=con).directions
    times, iters, steps = [], [], []
    for k in range(1, replans + 1):
        init = np.vstack([prev[1:], prev[-1:]])
        window = path[k : k + n]
        retained = None
        if nearest:
            d2 = np.sum((pts[None, :, :] - window[:, None, :]) ** 2, axis=2)
            retained = list(np.argpartition(d2, nearest - 1, axis=1)[:, :nearest])
        r, dt = timed(optimize_trajectory, pts, window, alpha, 0.6, init_directions=init,
                      anchor=prev[0], constraint=con, retained=retained)
        times.append(dt)
        iters.append(r.iterations)
        steps.append(float(np.degrees(np.arccos(np.clip(prev[1] @ r.directions[0], -1.0, 1.0)))))
        prev = r.directions
    return {
        "landmarks": int(pts.shape[0]),
        "retained_per_waypoint": int(nearest) if nearest else int(pts.shape[0]),
        "waypoints": n,
        "replans": replans,
        "median_ms": 1e3 * median(times),
        "p99_ms": 1e3 * percentile(times, 99),
        "max_ms": 1e3 * float(np.max(times)),
        "iterations_mean": float(np.mean(iters)),
        "first_direction_change_deg_max": float(np.max(steps)),
    }


def run(args: argparse.Namespace) -> int:
    from pivotd.errors import InputError

    if not steady_heap():
        log.warning("could not fix the allocator's thresholds (not glibc?): timings include page faults")
    if args.pareto:
        rows = pareto_rows(families=not args.quick, compare_with=args.compare_with, normalise=args.normalise)
        if args.json:
            Path(args.json).write_text(json.dumps({"pareto": rows}, indent=2) + "\n")
        return 0
    if args.fov_carry:
        from pivotd.bench.narrow import run_fov_carry

        carry = run_fov_carry(args.quick)
        if args.json:
            Path(args.json).write_text(json.dumps({"fov_carry": carry}, indent=2) + "\n")
        return 0
    if args.narrow:
        from pivotd.bench.narrow import run_narrow

        narrow = run_narrow(args.quick, args.compare_with)
        if args.json:
            Path(args.json).write_text(json.dumps({"narrow": narrow}, indent=2) + "\n")
        return 0
    if args.replan:
        out = []
        for nearest in (None, 5000):
            rp = replan_section(60 if args.quick else 200, nearest)
            out.append(rp)
            print(
                f"warm replans ({rp['waypoints']} waypoints, {rp['landmarks']} landmarks, "
                f"{rp['retained_per_waypoint']} retained per waypoint, {rp['replans']} replans): "
                f"median {rp['median_ms']:.2f} ms, p99 {rp['p99_ms']:.2f} ms, max {rp['max_ms']:.2f} ms, "
                f"{rp['iterations_mean']:.1f} iterations",
                flush=True,
            )
        if args.json:
            Path(args.json).write_text(json.dumps({"replan": out}, indent=2) + "\n")
        return 0

    if not (0 < args.fov_deg < 180):
        raise InputError(f"--fov-deg must be in (0, 180), got {args.fov_deg}")
    alpha = math.radians(args.fov_deg) / 2
    hard = _hard_section(args, alpha) if args.scenes != "paper" else None
    if args.scenes == "hard":
        if args.json:
            Path(args.json).write_text(json.dumps({"fov_deg": args.fov_deg, "hard": hard}, indent=2) + "\n")
        return 0
    levels = [0, 4, 9] if args.quick else list(range(10))
    n_poses = args.poses if args.poses else (40 if args.quick else 400)
    if n_poses < 1:
        raise InputError(f"--poses must be ≥ 1, got {n_poses}")
    # a fixed, spatially spread subset of the 20 × 20 grid (all 400 when n_poses ≥ 400)
    pose_idx = np.sort(np.random.default_rng(0).permutation(400)[: min(n_poses, 400)])
    print(f"Monte Carlo: 9 clusters, FoV {args.fov_deg:g} deg, brute force at {args.resolution_deg:g} deg, "
          f"{len(pose_idx)} poses per level, single thread")
    _print_header()
    rows, detail = _level_rows(levels, pose_idx, alpha, args.resolution_deg, args.compare_with)
    p = PAPER
    print(
        f"paper (C++, i9-14900K): PIVOT {p['pivot_ms'][0]}–{p['pivot_ms'][1]} ms, brute {p['brute_ms'][0]}–"
        f"{p['brute_ms'][1]} ms, speedup {p['speedup'][0]}–{p['speedup'][1]}x, retained "
        f"{p['retained_pct'][0]}–{p['retained_pct'][1]} %"
    )
    fif = fif_section(3 if args.quick else 7)
    if fif:
        print(
            f"FIF ycorridor ({fif['landmarks']} landmarks, {fif['waypoints']} waypoints, 30 deg, lambda 0.6): "
            f"{fif['optimize_ms']:.1f} ms, max step {fif['max_step_deg']:.2f} deg, visible mean "
            f"{fif['visible_mean']:.1f} = {fif['visible_ratio_pct']:.1f} % of the lambda 0 plan's "
            f"{fif['visible_mean_lambda0']:.1f} ({fif['optimize_ms_lambda0']:.1f} ms)"
        )
        print(
            f"FIF exact best plans on the 2 deg grid: {fif['grid_free_mean']:.1f} without a step limit, "
            f"{fif['grid_plan_step_mean']:.1f} with steps <= {fif['max_step_deg']:.2f} deg (the lambda 0.6 plan "
            f"reaches {100 * fif['visible_mean'] / fif['grid_plan_step_mean']:.1f} % of it), "
            f"{fif['grid_10deg_mean']:.1f} = {100 * fif['grid_10deg_mean'] / fif['grid_free_mean']:.1f} % "
            f"with steps <= 10 deg"
        )
    result = {"fov_deg": args.fov_deg, "resolution_deg": args.resolution_deg, "levels": rows, "paper": PAPER,
              "fif": fif, "hard": hard}
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    if args.plot:
        _plot(Path(args.plot), rows, detail, pose_idx)
    return 0


def _hard_section(args: argparse.Namespace, alpha: float) -> list[dict]:
    """The hard-scene table (``--scenes hard|all``), printed; returns its rows."""
    from pivotd.errors import InputError

    seeds = args.scene_seeds if args.scene_seeds is not None else (2 if args.quick else 3)
    poses = args.scene_poses if args.scene_poses is not None else (6 if args.quick else 20)
    if seeds < 1 or poses < 1:
        raise InputError(f"--scene-seeds and --scene-poses must be ≥ 1, got {seeds} and {poses}")
    print(f"Hard scenes: {seeds} instances x {poses} poses per family, FoV {args.fov_deg:g} deg; % of the refined "
          f"reference ({args.resolution_deg:g} deg grid + branch and bound to 0.25 deg), speedup vs scoring the "
          f"{args.resolution_deg:g} deg grid, single thread")
    _print_hard_header()
    return hard_rows(seeds, poses, alpha, args.resolution_deg, compare_with=args.compare_with)


def _plot(out: Path, rows: list[dict], detail: dict, pose_idx: np.ndarray) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from pivotd.pivot.scenes import monte_carlo_map, monte_carlo_poses

    top = rows[-1]["level"]
    poses = monte_carlo_poses()[pose_idx]
    pts = monte_carlo_map(top)
    fig, ax = plt.subplots(1, 3, figsize=(16, 5))
    ax[0].scatter(pts[:, 0], pts[:, 1], s=0.3, c="0.7")
    d_p, d_b = detail[top]["pivot"], detail[top]["brute"]
    ax[0].quiver(poses[:, 0], poses[:, 1], d_b[:, 0], d_b[:, 1], color="tab:blue", label="brute force", width=0.004)
    ax[0].quiver(poses[:, 0], poses[:, 1], d_p[:, 0], d_p[:, 1], color="tab:red", label="PIVOT", width=0.002)
    ax[0].set_title(f"viewing directions ({rows[-1]['features']} features)")
    ax[0].set_aspect("equal")
    ax[0].legend(loc="upper right", fontsize=8)
    gap = (100.0 - detail[top]["ratio"]) / 100.0
    sc = ax[1].scatter(poses[:, 0], poses[:, 1], c=gap, cmap="viridis", s=60, marker="s")
    fig.colorbar(sc, ax=ax[1], label="(V_BF − V_PIVOT) / V_BF")
    ax[1].set_title("normalised visibility gap")
    ax[1].set_aspect("equal")
    f = [r["features"] for r in rows]
    ax[2].semilogy(f, [r["pivot_ms"] for r in rows], "o-", label="PIVOT ms/pose")
    ax[2].semilogy(f, [r["brute_ms"] for r in rows], "s-", label="brute force ms/pose")
    ax[2].set_xlabel("features")
    ax2 = ax[2].twinx()
    ax2.plot(f, [r["retained_mean_pct"] for r in rows], "g^--", label="retained % (mean)")
    ax2.set_ylim(90, 101)
    ax2.set_ylabel("retained visibility %")
    ax[2].legend(loc="center left", fontsize=8)
    ax[2].set_title("scaling with feature count")
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
