"""``pivotd bench achievable RUN.mcap``: the daemon's view against the best view the configured gimbal can execute.

From a recording (``pivotd --record``), at frames of ``--rate`` Hz over the time the robot had fresh poses (the
last pose at most ``control.pose_timeout_s`` old), landmarks inside the cone (``pivot.half_angle``, distances in
``map.filters``' range; :func:`pivotd.sim.analysis.visible_counts`) are counted for:

* **daemon**: the measured joints, interpolated at the frame;
* **forward**: the camera fixed at pan = tilt = 0;
* **teleport**: the best cell of a pan/tilt grid inside the joint limits at every frame (no motion limits);
* **achievable**: the best execution found (:func:`best_executed`): candidate cell paths over the same grid —
  the exact optimum of the whole route with each step within the axis velocity limits × the frame interval
  (:func:`pivotd.pivot.joint_dp.best_joint_path`, starting where the gimbal stood at the first frame), the same
  under lower velocity limits, and the exact optimum with the move also changing by at most the acceleration
  limit × dt² per step in a corridor around the best execution (:func:`pivotd.pivot.joint_dp.
  best_smooth_joint_path`) — each executed through :class:`pivotd.gimbal.motion.MotionGenerator` with the
  configured velocity, acceleration and jerk limits at the control rate; the executed positions at the frames are
  counted and the best execution is kept. The velocity-limited DP's own (unexecuted) path is reported beside it,
  the winning candidate is named, and the executed stream is checked against every limit.

Landmarks within ``map.filters.max_range`` of each frame come from a k-d tree, so the cost follows the landmarks
near the route.
"""

from __future__ import annotations

import argparse
import json
import math
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pivotd.compat import StrEnum
from pivotd.config import Config
from pivotd.errors import InputError
from pivotd.geometry import pan_tilt_to_direction
from pivotd.gimbal.kinematics import base_from_world, camera_position
from pivotd.gimbal.motion import MotionGenerator
from pivotd.pivot.joint_dp import JointGrid, JointPath, best_joint_path, best_smooth_joint_path, cell_counts
from pivotd.sim.analysis import setpoint_dynamics, visible_counts
from pivotd.viz.recording import Recording, read_recording

_LIMIT_TOL = 1e-9  # [rad] slack of the joint-limit check on the executed positions


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", metavar="RUN.mcap", help="an MCAP file written by `pivotd --record`")
    parser.add_argument("--config", default=None, metavar="CFG", help="the run's config, if not the recorded one")
    parser.add_argument("--rate", type=float, default=10.0, help="frames per second that are counted (default 10)")
    parser.add_argument("--grid-deg", type=float, default=2.0,
                        help="largest pan/tilt spacing of the joint grid [deg] (default 2)")
    parser.add_argument("--json", action="store_true", help="print the report as JSON instead of text")


@dataclass(frozen=True)
class AchievableSeries:
    """Per frame (F,): times t [s], counts of the daemon, forward camera, teleport, DP path and executed path;
    joint angles (F, 2) [rad] of the daemon (measured), the DP cells and the executed setpoints."""

    t: np.ndarray
    n_daemon: np.ndarray
    n_forward: np.ndarray
    n_teleport: np.ndarray
    n_dp: np.ndarray
    n_achievable: np.ndarray
    daemon_joints: np.ndarray
    dp_joints: np.ndarray
    executed_joints: np.ndarray


@dataclass(frozen=True)
class Achievable:
    """:func:`achievable`'s result: the report (JSON-friendly dict), the per-frame series and the achievable
    path's whole setpoint stream."""

    report: dict
    series: AchievableSeries
    executed: Executed | None = None


def _frames(run: Recording, rate_hz: float) -> tuple[np.ndarray, np.ndarray]:
    """Frame times (F,) [s] on a regular clock at ``rate_hz`` where the last pose is fresh and joints were measured,
    and the index (F,) of that pose."""
    cfg = run.cfg
    lo = max(run.pose_t[0], run.measured.t[0])
    hi = min(run.pose_t[-1] + cfg.control.pose_timeout_s, run.measured.t[-1])
    if hi < lo:
        return np.zeros(0), np.zeros(0, int)
    t = lo + np.arange(math.floor((hi - lo) * rate_hz + 1e-9) + 1) / rate_hz
    i = np.searchsorted(run.pose_t, t, side="right") - 1
    fresh = (i >= 0) & (t - run.pose_t[np.maximum(i, 0)] <= cfg.control.pose_timeout_s)
    return t[fresh], i[fresh]


def _interp_joints(run: Recording, t: np.ndarray) -> np.ndarray:
    """Measured joints (F, 2) [rad] linearly interpolated at ``t`` (pan unwrapped on a continuous-pan gimbal)."""
    js = run.measured
    pan = np.unwrap(js.angles[:, 0]) if run.cfg.gimbal.limits.continuous_pan else js.angles[:, 0]
    return np.column_stack([np.interp(t, js.t, pan), np.interp(t, js.t, js.angles[:, 1])])


def _directions(R: np.ndarray, joints: np.ndarray) -> np.ndarray:
    """World optical axes (F, 3) for base orientations R (F, 3, 3) (world → base) and joints (F, 2)."""
    return np.einsum("fji,fj->fi", R, pan_tilt_to_direction(joints[:, 0], joints[:, 1]))


def _count(points: np.ndarray, cams: np.ndarray, cand: list[np.ndarray], dirs: np.ndarray, cfg: Config) -> np.ndarray:
    """visible_counts (F,) of each frame's candidates only (``cand``: landmark indices within the maximum range)."""
    flt = cfg.map.filters
    out = np.zeros(cams.shape[0], np.int64)
    for f, idx in enumerate(cand):
        if idx.size:
            out[f] = visible_counts(points[idx], cams[f:f + 1], dirs[f:f + 1], cfg.pivot.half_angle,
                                    flt.min_range, flt.max_range)[0]
    return out


@dataclass(frozen=True)
class Executed:
    """A joint path run through the motion generator: positions at the frames (F, 2) [rad], and the whole
    setpoint stream at the control period: positions (S, 2) [rad] and velocities (S, 2) [rad/s]."""

    at_frames: np.ndarray
    positions: np.ndarray
    velocities: np.ndarray


class FeedForward(StrEnum):
    """What :func:`execute` passes with each frame's target: ``forward`` the velocity towards the next frame's
    target, ``central`` the path's central-difference velocity and acceleration."""

    FORWARD = "forward"
    CENTRAL = "central"


def execute(cfg: Config, t: np.ndarray, targets: np.ndarray, start: np.ndarray,
            end_time: float | None = None, lead: float = 0.0,
            feed: FeedForward = FeedForward.FORWARD) -> Executed:
    """Run joint ``targets`` (F, 2) [rad] at frame times ``t`` (F,) [s] through the configured motion generator.

    At each frame the target is the path ``lead`` frames ahead (linear between frames, held after the last one)
    with the feed-forward ``feed`` (velocity towards the next target, or the path's central-difference velocity
    and acceleration); the generator steps at the control period from ``start`` (2,) at rest, as the daemon's
    control loop does, from ``t[0]`` to the last frame (or to ``end_time`` [s] when later)."""
    dt = cfg.control.dt
    targets = np.asarray(targets, dtype=float)
    if lead:
        dtf = np.diff(t)
        ahead = t + lead * np.append(dtf, dtf[-1] if dtf.size else 0.0)
        targets = np.column_stack([np.interp(ahead, t, targets[:, 0]), np.interp(ahead, t, targets[:, 1])])
    vel = np.zeros_like(targets)
    acc = np.zeros_like(targets)
    if t.size > 1 and feed is FeedForward.CENTRAL:
        vel = np.gradient(targets, t, axis=0)
        acc = np.gradient(vel, t, axis=0)
    elif t.size > 1:
        vel[:-1] = np.diff(targets, axis=0) / np.diff(t)[:, None]
    gen = MotionGenerator(dt, cfg.motion.pan, cfg.motion.tilt, cfg.gimbal.limits, deadband=cfg.motion.deadband)
    gen.reset(start)
    steps = np.round((t - t[0]) / dt).astype(int)
    last = steps[-1] if end_time is None else max(steps[-1], math.floor((end_time - t[0]) / dt + 1e-9))
    pos = [gen.state.position]
    rates = [gen.state.velocity]
    at_frames = np.empty_like(targets)
    step = 0
    for f in range(t.size):
        while step < steps[f]:
            s = gen.step()
            pos.append(s.position)
            rates.append(s.velocity)
            step += 1
        at_frames[f] = pos[-1]
        gen.set_target(targets[f], vel[f], acc[f])
    while step < last:
        s = gen.step()
        pos.append(s.position)
        rates.append(s.velocity)
        step += 1
    return Executed(at_frames, np.asarray(pos), np.asarray(rates))


VELOCITY_FRACTIONS = (1.0, 0.8, 0.6)  # velocity-only DP candidates: shares of the velocity limits
SMOOTH_ROUNDS = 3  # re-centrings of the acceleration-limited DP on the best execution (while it improves)
SCREEN = (FeedForward.CENTRAL, 0.25)  # how every candidate path is executed first (feed-forward, lead [frames])
EXECUTIONS = tuple((feed, lead) for feed in FeedForward for lead in (0.0, 0.25, 0.5, 0.75))  # then the best path

Judge = Callable[[np.ndarray], np.ndarray]  # joints (F, 2) [rad] → landmarks seen per frame (F,)


@dataclass(frozen=True)
class Search:
    """:func:`best_executed`'s result: the velocity-only DP path (F, 2) [rad], the best execution found, its
    candidate's name and the judged mean of every executed candidate (name → mean, in the order tried)."""

    dp_joints: np.ndarray
    executed: Executed
    winner: str
    means: dict[str, float]


def _unwrapped(path: JointPath, grid: JointGrid, start: np.ndarray) -> np.ndarray:
    """Joint angles (F, 2) [rad] of a cell path, pan unwrapped next to ``start`` on a continuous-pan grid."""
    joints = path.joints(grid)
    if grid.continuous_pan:
        joints[:, 0] = np.unwrap(joints[:, 0])
        joints[:, 0] += 2 * math.pi * round((start[0] - joints[0, 0]) / (2 * math.pi))
    return joints


def grid_judge(scores: np.ndarray, grid: JointGrid) -> Judge:
    """A judge from per-frame cell scores (F, P, T): the score of the cell nearest each frame's joints."""
    def judge(joints: np.ndarray) -> np.ndarray:
        cells = np.array([grid.nearest(p, q) for p, q in joints]).reshape(-1, 2)
        return scores[np.arange(cells.shape[0]), cells[:, 0], cells[:, 1]]
    return judge


def _change_limits(dtf: np.ndarray, acc: float) -> np.ndarray:
    """Per-step limit (F − 1,) [rad] on the change of move for an acceleration ``acc`` [rad/s²]: acc·dt² on a
    regular clock (the first step from rest), no limit where the frame interval changes."""
    out = acc * dtf**2
    out[1:][np.abs(np.diff(dtf)) > 1e-9] = np.inf
    return out


def corridor_cells(cfg: Config, grid: JointGrid) -> tuple[int, int]:
    """Half-widths (pan, tilt) [cells] of the acceleration-limited DP's corridor: per axis the overshoot
    v²/2a [rad] of a full-speed reversal at the acceleration limit over the instant one, plus one cell."""
    mo = cfg.motion
    out = []
    for ax, step in ((mo.pan, grid.pan_step), (mo.tilt, grid.tilt_step)):
        reach = ax.max_velocity**2 / (2.0 * ax.max_acceleration)
        out.append(math.ceil(reach / step - 1e-9) + 1 if step > 0 else 0)
    return out[0], out[1]


def best_executed(cfg: Config, t: np.ndarray, scores: np.ndarray, grid: JointGrid, start: np.ndarray,
                  judge: Judge | None = None, end_time: float | None = None) -> Search:
    """The best executed camera path found for per-frame ``scores`` (F, P, T) at frame times ``t`` (F,) [s]
    from ``start`` (2,) [rad] at rest: candidate cell paths are executed through the motion generator
    (:func:`execute`) and the execution with the highest mean of ``judge`` (default :func:`grid_judge`) is kept.

    Candidate paths, each executed as :data:`SCREEN` says:

    * the exact velocity-limited optimum (:func:`best_joint_path`, steps within the axis velocity limits × the
      frame interval; also executed with forward feed-forward and no lead) and the same under
      :data:`VELOCITY_FRACTIONS` of those limits;
    * the exact optimum with each step's move also changing by at most the axis acceleration limit × dt² in
      cells (at least one; and one cell more) inside a corridor (:func:`corridor_cells`) around the best
      execution so far (:func:`best_smooth_joint_path`), re-centred on the new best up to :data:`SMOOTH_ROUNDS` times;

    then the best path under every feed-forward and lead of :data:`EXECUTIONS`. Every candidate is a real
    execution, so the result keeps every limit the generator keeps."""
    judge = grid_judge(scores, grid) if judge is None else judge
    dtf = np.diff(t)
    mo = cfg.motion
    s0 = (float(start[0]), float(start[1]))
    means: dict[str, float] = {}
    best: dict = {"mean": -np.inf}

    def run(name: str, joints: np.ndarray, feed: FeedForward, lead: float) -> None:
        key = f"{name}; {feed.value} feed-forward, lead {lead:g}"
        if key in means:
            return
        ex = execute(cfg, t, joints, start, end_time, lead, feed)
        means[key] = float(np.mean(judge(ex.at_frames)))
        if means[key] > best["mean"]:
            best.update(mean=means[key], executed=ex, name=key, path=name, joints=joints)

    dp = None
    for frac in VELOCITY_FRACTIONS:
        path = best_joint_path(scores, frac * mo.pan.max_velocity * dtf, frac * mo.tilt.max_velocity * dtf, grid,
                               start=s0)
        if dp is None:  # the full-speed optimum, also executed as it always was: the reference never falls below it
            dp = path
            run(f"velocity DP ×{frac:g}", _unwrapped(path, grid, start), FeedForward.FORWARD, 0.0)
        run(f"velocity DP ×{frac:g}", _unwrapped(path, grid, start), *SCREEN)
    radius = corridor_cells(cfg, grid)
    dt2 = float(np.median(dtf)) ** 2
    base = (max(grid.pan_cells(mo.pan.max_acceleration * dt2), 1),
            max(grid.tilt_cells(mo.tilt.max_acceleration * dt2), 1))
    for extra in (0, 1):
        cells = (base[0] + extra, base[1] + extra)
        # the change limits in cells as accelerations on this clock (half a cell of slack against rounding)
        ddpan = _change_limits(dtf, (cells[0] + 0.5) * grid.pan_step / dt2)
        ddtilt = _change_limits(dtf, (cells[1] + 0.5) * grid.tilt_step / dt2)
        previous = None
        for r in range(SMOOTH_ROUNDS):
            before = best["mean"]
            centre = np.array([grid.nearest(p, q) for p, q in best["executed"].at_frames])
            try:
                path = best_smooth_joint_path(scores, mo.pan.max_velocity * dtf, mo.tilt.max_velocity * dtf, ddpan,
                                              ddtilt, grid, centre, radius)
            except ValueError:  # the corridor holds no path within the change limits
                break
            if previous is not None and np.array_equal(path.cells, previous):
                break  # re-centred on its own execution, the optimum stayed
            previous = path.cells
            run(f"acceleration DP ±{cells[0]}/{cells[1]} cells, round {r + 1}", _unwrapped(path, grid, start),
                *SCREEN)
            if best["mean"] <= before:
                break
    name, joints = best["path"], best["joints"]
    for feed, lead in EXECUTIONS:
        run(name, joints, feed, lead)
    return Search(_unwrapped(dp, grid, start), best["executed"], best["name"], means)


def achievable_path(cfg: Config, t: np.ndarray, scores: np.ndarray, grid: JointGrid, start: np.ndarray,
                    end_time: float | None = None, judge: Judge | None = None) -> tuple[np.ndarray, Executed]:
    """The velocity-limited optimum over ``grid`` for per-frame ``scores`` (F, P, T) at frame times ``t`` (F,)
    [s] (each step within the axis velocity limits × the frame interval, from the cell nearest ``start`` (2,)
    [rad]) and the best execution found from ``start`` (:func:`best_executed`, judged by ``judge``).
    Returns the DP's joint angles (F, 2) [rad] (pan unwrapped next to ``start`` on a continuous-pan gimbal) and
    the execution."""
    found = best_executed(cfg, t, scores, grid, start, judge, end_time)
    return found.dp_joints, found.executed


def check_limits(cfg: Config, ex: Executed) -> dict:
    """Whether the executed stream keeps every velocity, acceleration and jerk limit (from the velocities, as the
    recorded setpoints are judged) and the joint limits; the worst share of each limit per axis."""
    lim = cfg.gimbal.limits
    p = ex.positions
    dyn = setpoint_dynamics(p, cfg.control.dt, cfg.motion.pan, cfg.motion.tilt, rates=ex.velocities,
                            resolution=_LIMIT_TOL)
    inside = bool(np.all((p[:, 1] >= lim.tilt_min - _LIMIT_TOL) & (p[:, 1] <= lim.tilt_max + _LIMIT_TOL)))
    if not lim.continuous_pan:
        inside &= bool(np.all((p[:, 0] >= lim.pan_min - _LIMIT_TOL) & (p[:, 0] <= lim.pan_max + _LIMIT_TOL)))
    ratios = {"velocity": dyn.velocity_ratio, "acceleration": dyn.acceleration_ratio, "jerk": dyn.jerk_ratio}
    return {
        "within_limits": bool(dyn.within_limits and inside),
        "within_joint_limits": inside,
        "worst_ratio": {k: np.round(v, 4).tolist() for k, v in ratios.items()},
        "setpoints": int(p.shape[0]),
    }


def achievable(run: Recording, rate_hz: float = 10.0, grid_deg: float = 2.0) -> Achievable:
    """The achievable view of a read recording (see the module docstring)."""
    if not (math.isfinite(rate_hz) and rate_hz > 0):
        raise InputError(f"--rate {rate_hz}: must be > 0")
    if not (math.isfinite(grid_deg) and 0.1 <= grid_deg <= 30.0):
        raise InputError(f"--grid-deg {grid_deg}: must be within 0.1..30")
    cfg = run.cfg
    t, ip = _frames(run, rate_hz)
    if t.size < 2:
        raise InputError(f"{run.path}: fewer than two frames with a fresh pose at {rate_hz:g} Hz")
    clock = {}
    t0 = time.perf_counter()
    mount, lim, flt = cfg.gimbal.mount, cfg.gimbal.limits, cfg.map.filters
    quats = run.pose_quat[ip]
    cams = camera_position(run.pose_pos[ip], quats, mount).reshape(-1, 3)
    R = base_from_world(quats, mount).reshape(-1, 3, 3)
    points = run.landmarks
    tree = cKDTree(points)
    cand = [np.asarray(c, dtype=np.int64) for c in tree.query_ball_point(cams, flt.max_range)]
    grid = JointGrid.inside(lim.pan_min, lim.pan_max, lim.tilt_min, lim.tilt_max, math.radians(grid_deg),
                            continuous_pan=lim.continuous_pan)
    scores = np.zeros((t.size, *grid.shape), dtype=np.float32)
    for f, idx in enumerate(cand):
        rel = points[idx] - cams[f]
        dist = np.linalg.norm(rel, axis=1)
        rel = rel[(dist >= flt.min_range) & (dist <= flt.max_range)]
        if rel.shape[0]:
            scores[f] = cell_counts(rel, None, grid, R[f], cfg.pivot.half_angle)
    clock["scores_s"] = time.perf_counter() - t0

    t1 = time.perf_counter()
    daemon_joints = _interp_joints(run, t)
    def judge(joints: np.ndarray) -> np.ndarray:
        return _count(points, cams, cand, _directions(R, joints), cfg)

    found = best_executed(cfg, t, scores, grid, daemon_joints[0], judge)
    dp_joints, ex = found.dp_joints, found.executed
    executed, check = ex.at_frames, check_limits(cfg, ex)
    best = np.argmax(scores.reshape(t.size, -1), axis=1)
    teleport_joints = grid.joints(np.column_stack(np.divmod(best, grid.shape[1])))
    clock["dp_and_execution_s"] = time.perf_counter() - t1

    t3 = time.perf_counter()
    n_daemon = _count(points, cams, cand, _directions(R, daemon_joints), cfg)
    n_forward = _count(points, cams, cand, _directions(R, np.zeros_like(daemon_joints)), cfg)
    n_teleport = _count(points, cams, cand, _directions(R, teleport_joints), cfg)
    n_dp = _count(points, cams, cand, _directions(R, dp_joints), cfg)
    n_ach = _count(points, cams, cand, _directions(R, executed), cfg)
    clock["count_s"] = time.perf_counter() - t3

    def mean(x: np.ndarray) -> float:
        return float(x.mean())

    report = {
        "recording": str(run.path),
        "frames": int(t.size),
        "rate_hz": float(rate_hz),
        "duration_s": round(float(t[-1] - t[0]), 3),
        "grid_deg": float(grid_deg),
        "grid_cells": [int(grid.shape[0]), int(grid.shape[1])],
        "daemon_mean": mean(n_daemon),
        "forward_mean": mean(n_forward),
        "achievable_mean": mean(n_ach),
        "teleport_mean": mean(n_teleport),
        "dp_mean": mean(n_dp),
        "share_daemon_achievable": mean(n_daemon) / max(mean(n_ach), 1e-12),
        "share_achievable_teleport": mean(n_ach) / max(mean(n_teleport), 1e-12),
        "frames_daemon_below_forward": int((n_daemon < n_forward).sum()),
        "frames_daemon_below_90pct_forward": int((n_daemon < 0.9 * n_forward).sum()),
        "frames_achievable_below_90pct_forward": int((n_ach < 0.9 * n_forward).sum()),
        "winner": found.winner,
        "candidates": {k: round(v, 3) for k, v in found.means.items()},
        "executed": check,
        "seconds": {k: round(v, 3) for k, v in clock.items()},
    }
    series = AchievableSeries(t, n_daemon, n_forward, n_teleport, n_dp, n_ach,
                              daemon_joints, dp_joints, executed)
    return Achievable(report, series, ex)


def achievable_report(recording_path: str | Path, config_path: str | Path | None = None, rate_hz: float = 10.0,
                      grid_deg: float = 2.0) -> dict:
    """:func:`achievable`'s report for the recording at ``recording_path`` (its recorded config, or
    ``config_path``)."""
    return achievable(read_recording(recording_path, config_path), rate_hz, grid_deg).report


def summary_line(r: dict) -> str:
    """One line for a run summary: daemon / achievable share, achievable and teleport means, frames below
    forward."""
    return (f"  achievable view: daemon {r['share_daemon_achievable']:.1%} of achievable "
            f"(daemon {r['daemon_mean']:.1f}, achievable {r['achievable_mean']:.1f}, teleport "
            f"{r['teleport_mean']:.1f}); frames below forward {r['frames_daemon_below_forward']}/{r['frames']}")


def report_lines(r: dict) -> list[str]:
    """The bench's text report."""
    ex = r["executed"]
    worst = ", ".join(f"{k} {max(v):.1%}" for k, v in ex["worst_ratio"].items())
    sec = r["seconds"]
    return [
        f"pivotd bench achievable — {r['recording']}: {r['frames']} frames at {r['rate_hz']:g} Hz over "
        f"{r['duration_s']:.1f} s, grid {r['grid_cells'][0]}×{r['grid_cells'][1]} cells (≤ {r['grid_deg']:g}°)",
        f"  landmarks in the cone per frame (means): daemon {r['daemon_mean']:.2f}, forward {r['forward_mean']:.2f}, "
        f"achievable (executed) {r['achievable_mean']:.2f}, teleport {r['teleport_mean']:.2f}",
        f"  achievable: the best of {len(r['candidates'])} executed candidates: {r['winner']}",
        f"  velocity-limited DP path before execution (the grid's bound for paths held to the velocity limits "
        f"alone): {r['dp_mean']:.2f}",
        f"  daemon / achievable {r['share_daemon_achievable']:.1%}, achievable / teleport "
        f"{r['share_achievable_teleport']:.1%}",
        f"  frames where the daemon sees less than forward: {r['frames_daemon_below_forward']}, "
        f"below 90 % of forward: {r['frames_daemon_below_90pct_forward']} (the achievable path's own: "
        f"{r['frames_achievable_below_90pct_forward']})",
        f"  executed path within every limit: {'yes' if ex['within_limits'] else 'NO'} "
        f"(worst share of the limits: {worst}; joint limits {'kept' if ex['within_joint_limits'] else 'LEFT'})",
        f"  time: cell scores {sec['scores_s']:.2f} s, DP and executions {sec['dp_and_execution_s']:.2f} s, "
        f"counts {sec['count_s']:.2f} s",
    ]


def run(args: argparse.Namespace) -> int:
    result = achievable(read_recording(args.recording, args.config), args.rate, args.grid_deg)
    if args.json:
        print(json.dumps(result.report, indent=1))
    else:
        print("\n".join(report_lines(result.report)))
    return 0 if result.report["executed"]["within_limits"] else 1
