"""The benchmark: every policy on every scene for a set of seeds, metrics per run, intervals and goals.

A task is one scene with its seeds. Procedural scenes are generated anew for every seed; FIF scenes are
fixed, so their deterministic policies are simulated once and only the observations (and the random
policy) change with the seed. Tasks are independent and may run in worker processes.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path

import numpy as np

from pivotd.localization.camera import CameraModel
from pivotd.localization.estimator import require_poselib
from pivotd.localization.metrics import (
    PRIMARY,
    THRESHOLDS,
    RunMetrics,
    aggregate,
    run_metrics,
    threshold_label,
    turning_frames,
)
from pivotd.localization.policies import PolicyName, make_policy
from pivotd.localization.scenes import FIF_SCENES, LocScene, build_scene
from pivotd.localization.simulate import FRAME_HZ, Trajectory, localize, run_policy
from pivotd.localization.stack import Config
from pivotd.localization.world import World

QUICK_DURATION = 12.0  # [s] route length of --quick


@dataclass(frozen=True)
class BenchSettings:
    """What to run: scenes, policies, seeds, camera model, config, FIF data folder, route time cap [s]."""

    scenes: tuple[str, ...]
    policies: tuple[PolicyName, ...]
    seeds: tuple[int, ...]
    camera: CameraModel
    cfg: Config
    fif_dir: Path
    max_duration: float | None = None
    frame_hz: float = FRAME_HZ


@dataclass
class SceneResult:
    """Per policy: RunMetrics per seed; frames of the first seed for plotting (route, centres, success,
    errors, landmarks in view)."""

    scene: str
    runs: dict[str, list[RunMetrics]] = field(default_factory=dict)
    route: np.ndarray | None = None
    walls: np.ndarray | None = None
    centres: np.ndarray | None = None
    frame_ok: dict[str, np.ndarray] = field(default_factory=dict)
    errors: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    in_view: dict[str, np.ndarray] = field(default_factory=dict)
    times: np.ndarray | None = None


def truncate_scene(scene: LocScene, max_duration: float | None) -> LocScene:
    """``scene`` with its route cut after ``max_duration`` [s] (unchanged when None or shorter)."""
    if max_duration is None or scene.duration <= max_duration:
        return scene
    keep = int(np.searchsorted(scene.stamps, scene.stamps[0] + max_duration, side="right"))
    keep = max(keep, 2)
    quats = None if scene.route_quats is None else scene.route_quats[:keep]
    return replace(scene, route=scene.route[:keep], route_quats=quats, stamps=scene.stamps[:keep])


def run_scene(st: BenchSettings, scene_name: str) -> SceneResult:
    """All policies × seeds on one scene."""
    require_poselib()
    out = SceneResult(scene_name, {p.value: [] for p in st.policies})
    fixed = scene_name in FIF_SCENES
    cache: dict[str, Trajectory] = {}
    world = None
    for n, seed in enumerate(st.seeds):
        if world is None or not fixed:
            scene = truncate_scene(build_scene(scene_name, seed, st.fif_dir), st.max_duration)
            world = World(st.cfg, scene, st.camera)
        for p in st.policies:
            reuse = fixed and p != PolicyName.RANDOM
            traj = cache.get(p.value) if reuse else None
            if traj is None:
                traj = run_policy(world, make_policy(p, world, seed), st.frame_hz)
                if reuse:
                    cache[p.value] = traj
            err = localize(world, traj, seed)
            out.runs[p.value].append(run_metrics(err.translation, err.rotation, 1.0 / st.frame_hz, traj.compute_s,
                                                 traj.decisions, turning_frames(traj.times, traj.directions)))
            if n == 0:
                m, d = THRESHOLDS[PRIMARY]
                out.frame_ok[p.value] = (err.translation <= m) & (err.rotation <= d)
                out.errors[p.value] = (err.translation, err.rotation)
                out.in_view[p.value] = err.in_view
                out.times = traj.times
                out.centres = traj.centres
        if n == 0:
            out.route = world.scene.route
            occ = world.scene.occupancy
            out.walls = occ[np.abs(occ[:, 2] - 1.0) < 0.06] if world.scene.normals is not None else occ
    return out


def summarize(result: SceneResult) -> dict:
    """JSON-friendly intervals of every metric per policy."""
    return {p: {k: v.as_dict() for k, v in aggregate(runs).items()} | {"runs": len(runs)}
            for p, runs in result.runs.items()}


@dataclass(frozen=True)
class GoalCheck:
    """One goal on one scene: whether it applies, whether it is met, and the numbers behind it."""

    goal: str
    scene: str
    applies: bool
    met: bool
    detail: str


def check_goals(scene: str, summary: dict) -> list[GoalCheck]:
    """The three goals on one scene from its summary (means over seeds, shares in [0, 1])."""
    key = f"success_{threshold_label(PRIMARY)}"
    checks: list[GoalCheck] = []

    def mean(policy: str, metric: str) -> float:
        return summary[policy][metric]["mean"]

    if "pivot" in summary and "forward" in summary:
        f_fail, p_fail = mean("forward", "failure"), mean("pivot", "failure")
        applies = f_fail >= 0.05
        checks.append(GoalCheck("failure <= forward/2", scene, applies, (not applies) or p_fail <= 0.5 * f_fail,
                                f"pivot {100 * p_fail:.1f} % vs forward {100 * f_fail:.1f} %"))
    if "pivot" in summary and "fisher" in summary:
        gap = 100 * (mean("fisher", key) - mean("pivot", key))
        ratio = mean("fisher", "compute_ms_per_frame") / max(mean("pivot", "compute_ms_per_frame"), 1e-9)
        checks.append(GoalCheck("success >= fisher - 1 pt", scene, True, gap <= 1.0,
                                f"fisher − pivot = {gap:+.1f} pt"))
        per_frame = mean("fisher", "compute_ms_per_decision") / max(mean("pivot", "compute_ms_per_frame"), 1e-9)
        checks.append(GoalCheck("compute <= fisher/100", scene, True, ratio >= 100.0,
                                f"fisher/pivot compute per frame = {ratio:.1f}× as run "
                                f"({per_frame:.1f}× with one Fisher search per frame)"))
    if "pivot" in summary and "oracle" in summary:
        gap = 100 * (mean("oracle", key) - mean("pivot", key))
        detail = f"oracle (achievable) − pivot = {gap:+.1f} pt"
        if "teleport" in summary:
            detail += f"; teleport − pivot = {100 * (mean('teleport', key) - mean('pivot', key)):+.1f} pt"
        checks.append(GoalCheck("success >= oracle - 2 pt", scene, True, gap <= 2.0, detail))
    return checks
