"""Narrow cones (half-angles 0.5–5°): single-pose quality against the exact optimum, the cost per pose, and
smooth plans against the independent ones.

Quality: every hard scene family at a small scale (a few hundred landmarks, where
:func:`pivotd.pivot.brute.exact_view` enumerates every candidate axis), random sensor positions; PIVOT's hard
visible count as a percentage of the exact optimum. Cost: the same families at full size (≈ 12k landmarks),
PIVOT's time per pose next to a 15° cone on the same poses, alternating (CPU time, median).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from typing import Any

import numpy as np

from pivotd.bench._stats import quality_stats

HALF_ANGLES_DEG: tuple[float, ...] = (0.5, 1.0, 2.0, 3.0, 5.0)
WIDE_DEG = 15.0


def _visible(B: np.ndarray, d: np.ndarray, alpha: float) -> float:
    """Hard visible count of unit bearings B (n, 3) in the closed cone around d (3,) [float64]."""
    return float(np.count_nonzero(B @ np.asarray(d, float) >= math.cos(alpha) - 1e-12))


def quality_rows(half_angles: tuple[float, ...], seeds: int, poses: int, scale: float,
                 view: Callable[..., Any] | None = None) -> list[dict]:
    """% of the exact optimum per half-angle [deg] over all families × ``seeds`` × ``poses`` at ``scale``.
    ``view``: the optimize_view to judge (default this tree's)."""
    from pivotd.geometry import normalize
    from pivotd.pivot.brute import exact_view
    from pivotd.pivot.scenes import HARD_FAMILIES, hard_scene
    from pivotd.pivot.view import optimize_view

    view = view or optimize_view
    rows = []
    for h in half_angles:
        alpha = math.radians(h)
        pct, landmarks = [], []
        for family in HARD_FAMILIES:
            for seed in range(seeds):
                scene = hard_scene(family, seed=seed, poses=poses, scale=scale)
                landmarks.append(scene.points.shape[0])
                for p in scene.path:
                    B = normalize(scene.points - p)
                    best = exact_view(B, None, alpha)[1]
                    got = _visible(B, view(B, None, alpha).direction, alpha)
                    pct.append(100.0 * got / max(best, 1e-12))
        rows.append({"half_angle_deg": h, "poses": len(pct), "landmarks_median": int(np.median(landmarks)),
                     **quality_stats("exact", pct)})
    return rows


def cost_rows(half_angles: tuple[float, ...], poses: int, repeats: int = 3) -> list[dict]:
    """Median PIVOT CPU time per pose [ms] at full size for each half-angle, and at 15° on the same poses in
    the same loop (alternating), per half-angle."""
    from pivotd.geometry import normalize
    from pivotd.pivot.cone_kernel import cone_kernel
    from pivotd.pivot.scenes import HARD_FAMILIES, hard_scene
    from pivotd.pivot.view import optimize_view

    wide = math.radians(WIDE_DEG)
    wide_kernel = cone_kernel(wide)
    scenes = [hard_scene(f, seed=0, poses=poses) for f in HARD_FAMILIES]
    rows = []
    for h in half_angles:
        alpha = math.radians(h)
        narrow_t, wide_t = [], []
        for scene in scenes:
            for p in scene.path:
                B = normalize(scene.points - p)
                for r in range(repeats):
                    for which in ((0, 1) if r % 2 == 0 else (1, 0)):
                        t = time.process_time()
                        if which == 0:
                            optimize_view(B, None, alpha)
                            narrow_t.append(time.process_time() - t)
                        else:
                            optimize_view(B, None, wide, kernel=wide_kernel)
                            wide_t.append(time.process_time() - t)
        n_ms, w_ms = 1e3 * float(np.median(narrow_t)), 1e3 * float(np.median(wide_t))
        rows.append({"half_angle_deg": h, "landmarks_median": int(np.median([s.points.shape[0] for s in scenes])),
                     "pivot_ms": round(n_ms, 2), "wide_ms": round(w_ms, 2), "ratio_to_wide": round(n_ms / w_ms, 2)})
    return rows


def plan_rows(half_angles: tuple[float, ...], scale: float, waypoints: int = 40, normalise: str = "total",
              lam: float = 0.6) -> list[dict]:
    """Smooth plans (λ = ``lam``, no distance weights, ``TrajectoryOptions.normalise``) on a path through each hard
    family at ``scale``: the visible sum as a share [%] of the independent λ = 0 plan's, with and without the
    cold starts' extra candidates (the narrow-cone seed ``TrajectoryOptions.narrow_seed_nodes`` and the fixed
    direction ``fixed_nodes``), and the plan's largest step [deg]."""
    from dataclasses import replace

    from pivotd.pivot.scenes import HARD_FAMILIES, hard_path
    from pivotd.pivot.steps import step_angles
    from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory

    opts = TrajectoryOptions.paper(distance_weights=False, normalise=normalise)
    rows = []
    for h in half_angles:
        alpha = math.radians(h)
        for family in HARD_FAMILIES:
            hp = hard_path(family, 0, waypoints=waypoints, scale=scale)
            free = float(optimize_trajectory(hp.points, hp.path, alpha, 0.0, options=opts).visible.sum())
            plan = optimize_trajectory(hp.points, hp.path, alpha, lam, options=opts)
            bare = optimize_trajectory(hp.points, hp.path, alpha, lam,
                                       options=replace(opts, narrow_seed_nodes=0, fixed_nodes=0))
            rows.append({"half_angle_deg": h, "family": family,
                         "seeded_pct": round(100.0 * float(plan.visible.sum()) / max(free, 1.0), 1),
                         "unseeded_pct": round(100.0 * float(bare.visible.sum()) / max(free, 1.0), 1),
                         "max_step_deg": round(float(np.degrees(step_angles(plan.directions, None).max())), 2)})
    return rows


def run_narrow(quick: bool, compare_with: str | None = None) -> dict:
    """Print both tables; returns them (``compare_with``: also judge that package's optimize_view)."""
    from pivotd.bench.montecarlo import _other_view

    seeds, poses, scale = (1, 4, 0.05) if quick else (2, 8, 0.05)
    print(f"Narrow cones: {len(HALF_ANGLES_DEG)} half-angles, 6 hard families x {seeds} instances x {poses} poses at "
          f"scale {scale:g}; % of the exact optimum (every bearing and every two-bearing edge axis)")
    result: dict = {"quality": quality_rows(HALF_ANGLES_DEG, seeds, poses, scale)}
    other = _other_view(compare_with)
    if other is not None:
        result["quality_other"] = quality_rows(HALF_ANGLES_DEG, seeds, poses, scale, view=other)
    for key in ("quality", "quality_other"):
        for r in result.get(key, []):
            tag = "" if key == "quality" else f" ({compare_with})"
            print(f"  {r['half_angle_deg']:4.1f} deg{tag}: {r['poses']} poses, ~{r['landmarks_median']} landmarks: "
                  f"mean {r['exact_mean_pct']:.2f} %  p5 {r['exact_p5_pct']:.2f} %  min {r['exact_min_pct']:.2f} %")
    cost_poses = 2 if quick else 5
    print(f"Cost at full size (6 families x {cost_poses} poses, CPU time, alternating with a {WIDE_DEG:g} deg cone):")
    result["cost"] = cost_rows((1.0, 3.0, 5.0), cost_poses)
    for r in result["cost"]:
        print(f"  {r['half_angle_deg']:4.1f} deg: {r['pivot_ms']:.2f} ms per pose vs {r['wide_ms']:.2f} ms at "
              f"{WIDE_DEG:g} deg ({r['ratio_to_wide']:.1f}x), ~{r['landmarks_median']} landmarks")
    print("  goals: mean >= 99.5 %, p5 >= 98 %, min >= 95 % of the exact optimum at every half-angle")
    plan_scale = 0.1 if quick else 0.3
    print(f"Smooth plans (lambda 0.6, 40 waypoints through each family at scale {plan_scale:g}): visible sum as % of "
          "the independent lambda 0 plan, with / without the narrow-cone seed of cold starts; largest step")
    result["plans"] = plan_rows((2.0, 5.0), plan_scale)
    for r in result["plans"]:
        print(f"  {r['half_angle_deg']:4.1f} deg {r['family']:>9}: {r['seeded_pct']:5.1f} % / "
              f"{r['unseeded_pct']:5.1f} %, largest step {r['max_step_deg']:.2f} deg")
    return result


def run_fov_carry(quick: bool) -> dict:
    """Does λ mean the same across FoVs? λ = 0.6 plans with a 2° and a 30° cone (half-angles 1° and 15°) on the
    same path through each hard family, visible sum as % of the λ = 0 plan's and largest step, with each
    normalisation of the objective (``TrajectoryOptions.normalise``). Prints the table; returns its rows."""
    scale = 0.1 if quick else 0.3
    print(f"lambda 0.6 across FoVs (40 waypoints through each hard family at scale {scale:g}): visible sum as % of "
          "the lambda 0 plan's, largest step")
    out: dict = {}
    for normalise in ("total", "attainable"):
        out[normalise] = plan_rows((1.0, 15.0), scale, normalise=normalise)
        for r in out[normalise]:
            print(f"  {normalise:>10} {2 * r['half_angle_deg']:4.0f} deg cone {r['family']:>9}: "
                  f"{r['seeded_pct']:5.1f} %, largest step {r['max_step_deg']:6.2f} deg", flush=True)
    return out
