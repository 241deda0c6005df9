"""``pivotd plot``: a recording written with the daemon's recorder (known motion, known landmarks) is read back,
the views are checked against a brute-force count, and every figure is rendered headless with its axes checked.
"""

from __future__ import annotations

import datetime
import json
import math
import struct
import subprocess
from pathlib import Path

import numpy as np
import pytest
from support import PYTHON, REPO, child_env

from pivotd.bench.achievable import achievable
from pivotd.bus.messages import JOINT_STATE, ODOMETRY, encode_joint_state, encode_odometry
from pivotd.daemon.recorder import JOINT_COMMAND_TOPIC, METADATA_NAME, STATE_TOPIC, Recorder
from pivotd.daemon.timeline import STRING, encode_text
from pivotd.gimbal.kinematics import camera_position, joints_to_world_direction
from pivotd.sim.analysis import visible_counts
from pivotd.sim.launch import derive_config
from pivotd.viz.figures import FIGURES, SIZES, build_figure, fault_marks, max_envelope, save_figure, state_steps
from pivotd.viz.recording import read_recording
from pivotd.viz.views import camera_views

T0_NS = 1_700_000_000_000_000_000
SPEED = 1.0  # m/s along +y
AMPLITUDE = math.radians(60.0)  # commanded pan = A sin(ω t)
OMEGA = 1.0  # rad/s
DURATION = 8.0
#: the run's state timeline as the daemon records it: (t [s], kind, value, previous, extra)
EVENTS = [(0.0, "state", "starting", None, {}), (0.0, "state", "waiting", "starting", {}),
          (0.2, "link", "up", None, {}), (0.2, "faults", 0, None, {"names": [], "mode": "enabled"}),
          (0.5, "state", "holding", "waiting", {}), (1.0, "state", "tracking", "holding", {}),
          (4.0, "faults", 4, 0, {"names": ["overcurrent"], "mode": "fault"}), (4.0, "state", "fault", "tracking", {}),
          (5.0, "faults", 0, 4, {"names": [], "mode": "enabled"}), (5.0, "state", "tracking", "fault", {}),
          (7.5, "state", "parking", "tracking", {}), (8.0, "state", "stopped", "parking", {})]


def pan_at(t: np.ndarray) -> np.ndarray:
    return AMPLITUDE * np.sin(OMEGA * t)


def write_run(tmp: Path, with_commands: bool = True) -> tuple[Path, Path]:
    """A recording of a robot driving along +y between two walls while the gimbal sweeps its pan."""
    rng = np.random.default_rng(3)
    walls = np.concatenate([
        np.column_stack([np.full(400, 3.0), rng.uniform(-2, 12, 400), rng.uniform(0, 2, 400)]),
        np.column_stack([np.full(400, -3.0), rng.uniform(-2, 12, 400), rng.uniform(0, 2, 400)]),
        np.column_stack([rng.uniform(-50, -40, 50), rng.uniform(-50, -40, 50), np.zeros(50)]),  # far away
    ])
    map_file = tmp / "walls.txt"
    np.savetxt(map_file, walls)
    config = derive_config(REPO / "config" / "demo.yaml", tmp / "run.yaml", {"name": "synthetic",
                                                                            "map.file": str(map_file)})
    rec_path = tmp / "run.mcap"
    rec = Recorder(rec_path)
    rec.add_metadata(METADATA_NAME, {"name": "synthetic", "config": str(config)})
    for t, kind, value, previous, extra in EVENTS:  # first: a recording cut short still has its setpoints cut
        rec.write(STATE_TOPIC, STRING, encode_text(json.dumps({
            "kind": kind, "value": value, "previous": previous, "wall_time": T0_NS * 1e-9 + t,
            "monotonic": 100.0 + t, **extra})), log_time_ns=T0_NS + round(t * 1e9))
    yaw = math.pi / 2  # heading +y
    quat = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])
    for k in range(int(DURATION * 20) + 1):  # poses at 20 Hz
        t = k / 20
        rec.write("/odom", ODOMETRY, encode_odometry(t, "map", "base_link", np.array([0.0, SPEED * t, 0.0]), quat),
                  log_time_ns=T0_NS + round(t * 1e9))
    for k in range(int(DURATION * 50) + 1):  # measured joints at 50 Hz
        t = k / 50
        rec.write("/pivot/joint_states", JOINT_STATE, encode_joint_state(
            t, ["pan", "tilt"], [float(pan_at(np.array(t))), 0.0], [AMPLITUDE * OMEGA * math.cos(OMEGA * t), 0.0]),
            log_time_ns=T0_NS + round(t * 1e9) + 1000)
    if with_commands:
        for k in range(int(DURATION * 100) + 1):  # setpoints at the control rate, 100 Hz
            t = k / 100
            rec.write(JOINT_COMMAND_TOPIC, JOINT_STATE, encode_joint_state(
                t, ["pan", "tilt"], [float(pan_at(np.array(t))), 0.0],
                [AMPLITUDE * OMEGA * math.cos(OMEGA * t), 0.0]), log_time_ns=T0_NS + round(t * 1e9) + 500)
    rec.close()
    return rec_path, config


def png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    return struct.unpack(">II", head[16:24])


def test_recording_reads_back_and_views_match_a_brute_force_count(tmp_path):
    rec_path, _ = write_run(tmp_path)
    run = read_recording(rec_path)
    assert run.cfg.name == "synthetic"
    assert len(run.measured) == 401 and len(run.commanded) == 801 and run.pose_t.shape == (161,)
    assert run.pose_t[0] == 0.0 and run.pose_t[-1] == pytest.approx(DURATION)
    np.testing.assert_allclose(run.commanded.angles[:, 0], pan_at(run.commanded.t), atol=1e-5)
    views = camera_views(run)
    assert views.t.size == 401  # every joint state has a pose at most 50 ms old
    # reference: the whole map, every frame, the analysis' brute-force count
    i = np.searchsorted(run.pose_t, views.t, side="right") - 1
    mount = run.cfg.gimbal.mount
    cams = np.array([camera_position(run.pose_pos[k], run.pose_quat[k], mount) for k in i])
    dirs = np.array([joints_to_world_direction(p, 0.0, run.pose_quat[k], mount)
                     for p, k in zip(run.measured.angles[:, 0], i, strict=True)])
    flt = run.cfg.map.filters
    expected = visible_counts(run.landmarks, cams, dirs, run.cfg.pivot.half_angle, flt.min_range, flt.max_range)
    np.testing.assert_array_equal(views.n_pivot, expected)
    fwd = np.array([joints_to_world_direction(0.0, 0.0, run.pose_quat[k], mount) for k in i])
    np.testing.assert_array_equal(views.n_forward, visible_counts(run.landmarks, cams, fwd, run.cfg.pivot.half_angle,
                                                                  flt.min_range, flt.max_range))
    np.testing.assert_allclose(views.cameras, cams, atol=1e-12)
    assert views.n_pivot.max() > 50 and views.n_forward.max() > 0
    # the sweep looks at both walls; the far cluster is never seen
    seen = run.landmarks[views.seen]
    assert (seen[:, 0] > 2).any() and (seen[:, 0] < -2).any() and not (seen[:, 0] < -30).any()


@pytest.mark.slow
@pytest.mark.parametrize("which", [*FIGURES, "all"])
def test_each_figure_renders_with_its_axes_and_data(tmp_path, which):
    rec_path, _ = write_run(tmp_path)
    run = read_recording(rec_path)
    views = camera_views(run)
    fig = build_figure(run, which, views)
    titles = [ax.get_title() for ax in fig.axes]
    by_title = {t.split(":")[0].split(" (")[0]: ax for t, ax in zip(titles, fig.axes, strict=True)}

    if which in ("route", "all"):
        ax = next(a for a, t in zip(fig.axes, titles, strict=True) if t.startswith("route from above"))
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("x [m]", "y [m]")
        route = next(line for line in ax.get_lines() if line.get_label() == "route")
        np.testing.assert_allclose(route.get_ydata(), run.pose_pos[:, 1])
        assert ax.get_ylim()[0] <= -2 and ax.get_ylim()[1] >= DURATION * SPEED + 2
        assert "FoV 60°" in ax.get_title()
    if which in ("visibility", "all"):
        ax = by_title["visible landmarks over time"]
        assert (ax.get_xlabel(), ax.get_ylabel()) == ("time [s]", "landmarks in the FoV")
        lines = ax.get_lines()
        np.testing.assert_array_equal(lines[0].get_ydata(), views.n_pivot)
        np.testing.assert_array_equal(lines[1].get_ydata(), views.n_forward)
        ach = achievable(run).series  # the achievable view per frame beside them
        np.testing.assert_array_equal(lines[2].get_ydata(), ach.n_achievable)
        np.testing.assert_array_equal(lines[2].get_xdata(), ach.t)
        assert lines[2].get_label().startswith("achievable") and ach.n_achievable.mean() >= views.n_forward.mean()
    if which in ("joints", "all"):
        ax = by_title["commanded vs measured pan/tilt"]
        assert ax.get_ylabel() == "joint angle [deg]"
        labels = [line.get_label() for line in ax.get_lines()]
        assert labels == ["pan measured", "pan commanded", "tilt measured", "tilt commanded",
                          "pan limits -170°…170°", "_nolegend_", "tilt limits -45°…60°", "_nolegend_"]
        pan_cmd = ax.get_lines()[1].get_ydata()
        assert max(pan_cmd) == pytest.approx(60.0, abs=0.01) and min(pan_cmd) == pytest.approx(-60.0, abs=0.5)
        # the limits are the run's gimbal.limits, as horizontal lines at their angle
        assert [tuple(line.get_ydata()) for line in ax.get_lines()[4:]] == [(-170, -170), (170, 170), (-45, -45),
                                                                           (60, 60)]
        tl = by_title["daemon state and faults"]
        assert tl.get_title() == "daemon state and faults (recording started 2023-11-14 22:13:20 UTC)"
        steps = tl.get_lines()[0]
        names = ["starting", "waiting", "tracking", "holding", "fault", "parking", "stopped"]
        assert [t.get_text() for t in tl.get_yticklabels()] == names
        np.testing.assert_allclose(steps.get_xdata(), [0, 0, 0.5, 1, 4, 5, 7.5, 8, DURATION], atol=1e-5)
        assert [names[int(v)] for v in steps.get_ydata()] == [
            "starting", "waiting", "holding", "tracking", "fault", "tracking", "parking", "stopped", "stopped"]
        faults = [(tuple(line.get_xdata()), line.get_linestyle(), line.get_label()) for line in tl.get_lines()[1:]]
        assert faults == [((4.0, 4.0), "-", "fault 0x0004 (overcurrent)"), ((5.0, 5.0), ":", "faults cleared")]
        utc = tl.child_axes[0]  # the clock time on top: start + seconds
        assert utc.xaxis.get_major_formatter()(3.0, 0) == "22:13:23"
    if which in ("dynamics", "all"):
        rate_ax = next(a for a, t in zip(fig.axes, titles, strict=True) if t.startswith("setpoints sent: rate"))
        assert rate_ax.get_ylabel() == "rate [deg/s]"
        # commanded pan rate peaks at A·ω = 60 deg/s, acceleration A·ω² = 60 deg/s², jerk A·ω³ = 60 deg/s³
        assert max(rate_ax.get_lines()[0].get_ydata()) == pytest.approx(60.0, abs=0.01)
        assert "pan 50%" in rate_ax.get_title()  # of 120 deg/s
        acc_ax = next(a for a, t in zip(fig.axes, titles, strict=True) if t.startswith("acceleration"))
        jerk_ax = next(a for a, t in zip(fig.axes, titles, strict=True) if t.startswith("jerk"))
        assert max(acc_ax.get_lines()[0].get_ydata()) == pytest.approx(60.0, rel=0.01)
        assert max(jerk_ax.get_lines()[0].get_ydata()) == pytest.approx(60.0, rel=0.02)
        assert acc_ax.get_lines()[1].get_ydata()[0] == pytest.approx(360.0)  # the pan limit line
        assert jerk_ax.get_xlabel() == "time [s]" and jerk_ax.get_ylabel() == "jerk [deg/s³]"
    out = save_figure(fig, tmp_path / f"{which}.png", dpi=40)
    w, h = SIZES[which]
    assert png_size(out) == (round(w * 40), round(h * 40))


def test_the_state_timeline_reads_back_in_order_with_both_clocks(tmp_path):
    rec_path, _ = write_run(tmp_path)
    run = read_recording(rec_path)
    assert run.start == datetime.datetime.fromtimestamp(T0_NS * 1e-9, datetime.timezone.utc)
    assert [(e.t, e.kind, e.value, e.previous) for e in run.timeline] == [
        (pytest.approx(t), kind, value, previous) for t, kind, value, previous, _ in EVENTS]
    fault = run.states("faults")[1]
    assert fault.extra == {"names": ["overcurrent"], "mode": "fault"}
    assert fault.wall_time == pytest.approx(T0_NS * 1e-9 + 4.0) and fault.monotonic == pytest.approx(104.0)
    t, levels, names = state_steps(run)  # what the timeline panel draws
    assert names == ["starting", "waiting", "tracking", "holding", "fault", "parking", "stopped"]
    assert [names[i] for i in levels] == ["starting", "waiting", "holding", "tracking", "fault", "tracking",
                                          "parking", "stopped", "stopped"]
    assert t[-1] == pytest.approx(run.measured.t[-1])
    assert fault_marks(run) == [(pytest.approx(4.0), True, "fault 0x0004 (overcurrent)"),
                                (pytest.approx(5.0), False, "faults cleared")]


def test_a_recording_without_a_timeline_draws_the_joints_all_the_same(tmp_path):
    rec_path, _ = write_run(tmp_path)
    run = read_recording(rec_path)
    old = type(run)(**{**run.__dict__, "timeline": []})
    fig = build_figure(old, "joints")
    tl = fig.axes[1]
    assert tl.get_lines() == [] and tl.texts[0].get_text() == "no state timeline in this recording"
    save_figure(fig, tmp_path / "old.png", dpi=20)


def test_max_envelope_takes_the_maximum_per_window():
    t = np.arange(10) * 0.05
    y = np.array([1, 5, 2, 0, 7, 1, 1, 1, 9, 0], float)
    starts, peaks = max_envelope(t, y, 0.1)
    np.testing.assert_allclose(starts, [0.0, 0.1, 0.2, 0.3, 0.4])
    np.testing.assert_array_equal(peaks, [5, 2, 7, 1, 9])


def test_without_setpoints_the_measured_motion_is_shown(tmp_path):
    rec_path, _ = write_run(tmp_path, with_commands=False)
    run = read_recording(rec_path)
    fig = build_figure(run, "dynamics")
    assert fig.axes[0].get_title().startswith("measured joint states: rate")
    save_figure(fig, tmp_path / "d.png", dpi=20)


def plot_cli(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "pivotd.cli", "plot", *args], capture_output=True, text=True,
                          env=child_env(MPLBACKEND="Agg"), cwd=str(REPO), timeout=120)


@pytest.mark.slow
def test_cli_writes_the_png_and_names_bad_input(tmp_path):
    rec_path, config = write_run(tmp_path)
    out = plot_cli(str(rec_path), "--figure", "visibility", "--dpi", "30")
    assert out.returncode == 0, out.stderr
    assert out.stdout.strip() == str(rec_path.with_suffix(".png"))
    assert png_size(rec_path.with_suffix(".png")) == (270, 120)

    garbage = tmp_path / "garbage.mcap"
    garbage.write_bytes(b"not an mcap file at all")
    out = plot_cli(str(garbage), "-o", str(tmp_path / "x.png"))
    assert out.returncode == 2 and out.stderr.startswith(f"pivotd plot: error: {garbage}: not a readable MCAP")
    assert len(out.stderr.strip().splitlines()) == 1

    config.rename(tmp_path / "moved.yaml")  # the recorded config is gone: --config replaces it
    out = plot_cli(str(rec_path), "-o", str(tmp_path / "y.png"))
    assert out.returncode == 2 and out.stderr.strip() == (
        f"pivotd plot: error: {rec_path}: the run's config {config} is not there any more; pass --config FILE")
    out = plot_cli(str(rec_path), "-o", str(tmp_path / "y.png"), "--config", str(tmp_path / "moved.yaml"),
                   "--figure", "joints", "--dpi", "20")
    assert out.returncode == 0 and png_size(tmp_path / "y.png") == (180, 120)


def test_a_recording_cut_short_is_read_up_to_its_last_complete_chunk(tmp_path):
    """A daemon killed while recording leaves no summary and half a chunk; the complete chunks still plot."""
    rec_path, _ = write_run(tmp_path)
    full = read_recording(rec_path)
    data = rec_path.read_bytes()
    cut = tmp_path / "cut.mcap"
    cut.write_bytes(data[: int(len(data) * 0.8)])
    part = read_recording(cut)
    assert len(part.measured) == len(full.measured)  # written before the setpoints
    assert 0 < len(part.commanded) < len(full.commanded)  # the setpoints come last: cut
    np.testing.assert_array_equal(part.commanded.angles, full.commanded.angles[: len(part.commanded)])
    save_figure(build_figure(part, "joints"), tmp_path / "cut.png", dpi=20)
