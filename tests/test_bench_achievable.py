"""``pivotd bench achievable``: a recording written with the daemon's recorder (a robot passing a rich wall to its
side with the gimbal looking ahead) against the best view the configured gimbal can execute on that route."""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import pytest
from support import REPO

from pivotd.bench.achievable import (
    EXECUTIONS,
    FeedForward,
    achievable,
    achievable_report,
    check_limits,
    execute,
    summary_line,
)
from pivotd.bus.messages import JOINT_STATE, ODOMETRY, encode_joint_state, encode_odometry
from pivotd.cli import main
from pivotd.config import load_config
from pivotd.daemon.recorder import METADATA_NAME, Recorder
from pivotd.gimbal.kinematics import camera_position, joints_to_world_direction
from pivotd.sim.analysis import visible_counts
from pivotd.sim.launch import derive_config
from pivotd.viz.recording import read_recording

T0_NS = 1_700_000_000_000_000_000
SPEED = 1.0  # [m/s] along +y
DURATION = 6.0  # [s]


def alternating_clusters() -> np.ndarray:
    """Landmarks (L, 3) [m]: clusters every 1.2 m along the route, alternating between x = +1 m (the robot's
    right) and x = −1 m (its left); with a short range (1.6 m) the best view swings the pan from side to side at
    full speed."""
    rng = np.random.default_rng(6)
    clusters = [np.column_stack([np.full(200, 1.0 if k % 2 == 0 else -1.0), rng.uniform(-0.2, 0.2, 200) + 1.2 * k,
                                 rng.uniform(-0.2, 0.4, 200)]) for k in range(7)]
    return np.concatenate(clusters)


def write_run(tmp: Path, overrides: dict | None = None, pan: float = 0.0, landmarks: np.ndarray | None = None) -> Path:
    """A robot driving along +y past a wall of landmarks at x = +2.5 m (its right), or past ``landmarks``
    (L, 3) [m]; the gimbal holds ``pan``."""
    rng = np.random.default_rng(4)
    wall = np.column_stack([np.full(1500, 2.5), rng.uniform(1.0, 8.0, 1500), rng.uniform(-0.3, 0.7, 1500)])
    wall = wall if landmarks is None else landmarks
    far = np.column_stack([rng.uniform(-60, -50, 100), rng.uniform(-60, -50, 100), np.zeros(100)])
    map_file = tmp / "wall.txt"
    np.savetxt(map_file, np.concatenate([wall, far]))
    config = derive_config(REPO / "config" / "demo.yaml", tmp / "run.yaml",
                           {"name": "wall", "map.file": str(map_file), **(overrides or {})})
    rec_path = tmp / "run.mcap"
    rec = Recorder(rec_path)
    rec.add_metadata(METADATA_NAME, {"name": "wall", "config": str(config)})
    yaw = math.pi / 2
    quat = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])
    for k in range(int(DURATION * 20) + 1):
        t = k / 20
        rec.write("/odom", ODOMETRY, encode_odometry(t, "map", "base_link", np.array([0.0, SPEED * t, 0.0]), quat),
                  log_time_ns=T0_NS + round(t * 1e9))
    for k in range(int(DURATION * 50) + 1):
        t = k / 50
        rec.write("/pivot/joint_states", JOINT_STATE, encode_joint_state(t, ["pan", "tilt"], [pan, 0.0], [0.0, 0.0]),
                  log_time_ns=T0_NS + round(t * 1e9) + 1000)
    rec.close()
    return rec_path


def test_achievable_beats_forward_beside_a_rich_wall(tmp_path):
    rec = write_run(tmp_path)
    res = achievable(read_recording(rec), rate_hz=10.0, grid_deg=2.0)
    r, s = res.report, res.series
    assert r["frames"] == int(DURATION * 10) + 1
    # the gimbal looked ahead the whole time: the daemon is the forward camera
    np.testing.assert_array_equal(s.n_daemon, s.n_forward)
    assert r["frames_daemon_below_forward"] == 0 and r["frames_daemon_below_90pct_forward"] == 0
    assert r["frames_achievable_below_90pct_forward"] == int((s.n_achievable < 0.9 * s.n_forward).sum())
    # turning towards the wall sees far more, and the executed path keeps most of what the DP planned
    assert r["achievable_mean"] > 2.0 * r["forward_mean"]
    assert r["achievable_mean"] >= 0.8 * r["dp_mean"]
    assert r["share_daemon_achievable"] == pytest.approx(r["daemon_mean"] / r["achievable_mean"])
    assert r["share_achievable_teleport"] == pytest.approx(r["achievable_mean"] / r["teleport_mean"])
    assert np.all(s.n_teleport >= s.n_dp)  # the best cell of every frame bounds any cell path
    assert r["teleport_mean"] >= r["achievable_mean"]
    # pan turns right (negative pan looks to the right of the heading: base +y is the robot's left)
    assert np.median(s.dp_joints[:, 0]) < -math.radians(30)
    assert r["executed"]["within_limits"]
    # the DP starts where the gimbal stood and each step stays within the velocity limit × frame interval
    cfg = load_config(tmp_path / "run.yaml")
    np.testing.assert_allclose(s.dp_joints[0], [0.0, 0.0], atol=math.radians(1.0) + 1e-9)
    assert np.all(np.abs(np.diff(s.dp_joints[:, 0])) <= cfg.motion.pan.max_velocity * 0.1 + 1e-9)
    assert np.all(np.abs(np.diff(s.dp_joints[:, 1])) <= cfg.motion.tilt.max_velocity * 0.1 + 1e-9)
    np.testing.assert_allclose(s.executed_joints[0], [0.0, 0.0])


def test_counts_equal_a_direct_count_over_the_whole_map(tmp_path):
    rec = write_run(tmp_path, pan=-1.0)
    run = read_recording(rec)
    s = achievable(run).series
    cfg = run.cfg
    i = np.searchsorted(run.pose_t, s.t, side="right") - 1
    cams = np.array([camera_position(run.pose_pos[k], run.pose_quat[k], cfg.gimbal.mount) for k in i])
    for joints, counts in ((s.daemon_joints, s.n_daemon), (s.executed_joints, s.n_achievable)):
        dirs = np.array([joints_to_world_direction(p, t, run.pose_quat[k], cfg.gimbal.mount)
                         for (p, t), k in zip(joints, i, strict=True)])
        flt = cfg.map.filters
        direct = visible_counts(run.landmarks, cams, dirs, cfg.pivot.half_angle, flt.min_range, flt.max_range)
        np.testing.assert_array_equal(counts, direct)
    np.testing.assert_allclose(s.daemon_joints[:, 0], -1.0)
    assert s.n_daemon.mean() > 0


def assert_within_limits(cfg, ex, t=None) -> None:
    """Every setpoint of ``ex`` within the velocity, acceleration, jerk and joint limits, checked from the raw
    stream; with frame times ``t`` the frame positions are the stream's samples at those times."""
    lim, mo, dt = cfg.gimbal.limits, cfg.motion, cfg.control.dt
    p, v = ex.positions, ex.velocities
    tol = 1e-9
    vmax = np.array([mo.pan.max_velocity, mo.tilt.max_velocity])
    amax = np.array([mo.pan.max_acceleration, mo.tilt.max_acceleration])
    jmax = np.array([mo.pan.max_jerk, mo.tilt.max_jerk])
    assert np.all(np.abs(np.diff(p, axis=0)) / dt <= vmax * (1 + 1e-9) + tol)
    assert np.all(np.abs(v) <= vmax * (1 + 1e-9))
    acc = np.diff(v, axis=0) / dt
    assert np.all(np.abs(acc) <= amax * (1 + 1e-9) + tol)
    assert np.all(np.abs(np.diff(acc, axis=0)) / dt <= jmax * (1 + 1e-9) + tol / dt)
    if not lim.continuous_pan:
        assert np.all(p[:, 0] >= lim.pan_min - tol) and np.all(p[:, 0] <= lim.pan_max + tol)
    assert np.all(p[:, 1] >= lim.tilt_min - tol) and np.all(p[:, 1] <= lim.tilt_max + tol)
    verdict = check_limits(cfg, ex)
    assert verdict["within_limits"] and verdict["within_joint_limits"]
    if t is not None:
        np.testing.assert_array_equal(ex.at_frames, p[np.round((t - t[0]) / dt).astype(int)])


@pytest.mark.parametrize(("feed", "lead"), [(FeedForward.FORWARD, 0.0), *EXECUTIONS[-3:]])
def test_executed_path_keeps_every_limit_under_a_bang_bang_reference(feed, lead):
    cfg = load_config(REPO / "config" / "demo.yaml")
    mo = cfg.motion
    lim = cfg.gimbal.limits
    t = np.arange(80) * 0.1
    targets = np.where((np.arange(80) // 3 % 2 == 0)[:, None], [[lim.pan_max, lim.tilt_max]],
                       [[lim.pan_min, lim.tilt_min]])
    ex = execute(cfg, t, targets, np.zeros(2), lead=lead, feed=feed)
    assert ex.positions.shape[0] == round(t[-1] / cfg.control.dt) + 1
    assert_within_limits(cfg, ex, t)
    assert np.ptp(ex.positions[:, 0]) > math.radians(60)  # it did move hard
    assert np.abs(ex.velocities[:, 0]).max() > 0.9 * mo.pan.max_velocity  # ... up to the velocity limit


def test_the_reference_beats_the_executed_velocity_dp_where_the_view_swings_side_to_side(tmp_path):
    """Clusters alternating left and right of a short-range camera: full-speed reversals, where the
    velocity-limited DP path executed as it is loses most. The reference is the best of the executed candidates,
    never below that execution, and its setpoints keep every limit."""
    rec = write_run(tmp_path, {"map.filters.max_range": 1.6}, landmarks=alternating_clusters())
    run = read_recording(rec)
    cfg = run.cfg
    res = achievable(run)
    r, s = res.report, res.series
    # the velocity-limited optimum reverses within 0.3 s of moving at full speed
    rate = np.diff(s.dp_joints[:, 0]) / 0.1
    fast = np.nonzero(np.abs(rate) > 0.9 * cfg.motion.pan.max_velocity)[0]
    assert any(np.any(rate[k + 1:k + 4] * rate[k] < 0) for k in fast)
    # the old reference: that path executed with forward feed-forward at the frames, counted directly
    old = execute(cfg, s.t, s.dp_joints, s.daemon_joints[0])
    i = np.searchsorted(run.pose_t, s.t, side="right") - 1
    cams = np.array([camera_position(run.pose_pos[k], run.pose_quat[k], cfg.gimbal.mount) for k in i])
    flt = cfg.map.filters

    def seen(joints: np.ndarray) -> np.ndarray:
        dirs = np.array([joints_to_world_direction(p, t, run.pose_quat[k], cfg.gimbal.mount)
                         for (p, t), k in zip(joints, i, strict=True)])
        return visible_counts(run.landmarks, cams, dirs, cfg.pivot.half_angle, flt.min_range, flt.max_range)

    old_mean = seen(old.at_frames).mean()
    assert r["candidates"]["velocity DP ×1; forward feed-forward, lead 0"] == pytest.approx(old_mean, abs=1e-3)
    assert r["achievable_mean"] >= old_mean + 2.0  # measured: 158.4 against 153.9 landmarks per frame
    assert r["achievable_mean"] == pytest.approx(seen(s.executed_joints).mean())
    assert r["candidates"][r["winner"]] == pytest.approx(r["achievable_mean"], abs=1e-3)
    assert max(r["candidates"].values()) == r["candidates"][r["winner"]]
    assert r["dp_mean"] == pytest.approx(seen(s.dp_joints).mean()) and r["dp_mean"] > r["achievable_mean"]
    assert r["teleport_mean"] >= r["dp_mean"]
    assert_within_limits(cfg, res.executed, s.t)
    np.testing.assert_array_equal(res.executed.at_frames, s.executed_joints)
    assert r["executed"]["within_limits"]


def test_a_continuous_pan_gimbal_wraps(tmp_path):
    rec = write_run(tmp_path, {"gimbal.limits.continuous_pan": True})
    r = achievable_report(rec, grid_deg=4.0)
    assert r["grid_cells"][0] == 90
    assert r["executed"]["within_limits"]
    assert r["achievable_mean"] > 2.0 * r["forward_mean"]
    assert "achievable" in summary_line(r) and f"/{r['frames']}" in summary_line(r)


def test_cli_prints_text_or_json_and_names_bad_input(tmp_path, capsys):
    rec = write_run(tmp_path)
    assert main(["bench", "achievable", str(rec), "--rate", "5", "--grid-deg", "3"]) == 0
    out = capsys.readouterr().out
    assert "daemon / achievable" in out and "teleport" in out and "within every limit: yes" in out
    assert "executed candidates" in out and "velocity-limited DP path" in out
    assert main(["bench", "achievable", str(rec), "--rate", "5", "--grid-deg", "3", "--json"]) == 0
    doc = json.loads(capsys.readouterr().out)
    assert doc["frames"] == int(DURATION * 5) + 1 and doc["grid_deg"] == 3.0
    assert doc["winner"] in doc["candidates"] and doc["achievable_mean"] <= doc["teleport_mean"]
    assert main(["bench", "achievable", str(rec), "--rate", "0"]) == 2
    assert "--rate" in capsys.readouterr().err
    assert main(["bench", "achievable", str(tmp_path / "missing.mcap")]) == 2
    assert "missing.mcap" in capsys.readouterr().err
