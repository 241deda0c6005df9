"""``pivotd bench gap``: options, the figures it takes from a report, and one real end-to-end run on a
non-hallway scene family."""

from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import pytest

from pivotd.bench import gap
from pivotd.errors import InputError
from pivotd.sim.scene_families import FamilyScene, generate, write_scene

REPO = Path(__file__).resolve().parent.parent


def _args(*argv: str) -> argparse.Namespace:
    parser = argparse.ArgumentParser()
    gap.configure(parser)
    return parser.parse_args(list(argv))


@pytest.mark.parametrize(("argv", "message"), [
    (("--families", "turn,atrium"), "--families: unknown family 'atrium'"),
    (("--seeds", "1,x"), "--seeds: expected comma-separated integers"),
    (("--repeat", "0"), "--repeat: need at least 1"),
    (("--speed", "9"), "--speed: must be in"),
    (("--config", "/nonexistent.yaml"), "--config /nonexistent.yaml: no such file"),
])
def test_bad_options_are_input_errors(argv, message):
    with pytest.raises(InputError, match=message):
        gap._settings(_args(*argv))


def test_defaults_are_every_family_seed_1():
    families, seeds = gap._settings(_args())
    assert families == ["turn", "aisles", "clusters", "fif", "stop_turn"] and seeds == [1]


def test_figures_from_an_achievable_report_either_naming():
    brief = {"daemon_mean": 90.0, "forward_mean": 60.0, "achievable_mean": 100.0, "teleport_mean": 120.0,
             "share": 0.9, "frames_below_forward_90": 0.05}
    assert gap.from_achievable(brief) == brief | {"source": "achievable_report"}
    long = {"daemon_mean": 90.0, "forward_mean": 60.0, "achievable_mean": 100.0, "teleport_mean": 120.0,
            "share_daemon_achievable": 0.9, "frames_daemon_below_90pct_forward": 10, "frames": 200}
    out = gap.from_achievable(long)
    assert out["share"] == pytest.approx(0.9) and out["frames_below_forward_90"] == pytest.approx(0.05)


def test_summary_means_over_repeats_and_share_spread_in_points(capsys):
    runs = [{"daemon_mean": 80.0, "forward_mean": 40.0, "achievable_mean": 100.0, "teleport_mean": 110.0,
             "share": 0.80, "frames_below_forward_90": 0.1},
            {"daemon_mean": 90.0, "forward_mean": 40.0, "achievable_mean": 100.0, "teleport_mean": 110.0,
             "share": 0.90, "frames_below_forward_90": 0.0}]
    row = gap.summarise("turn-Lleft", "turn", 3, runs)
    assert row["share"] == pytest.approx(0.85) and row["share_spread_pts"] == pytest.approx(10.0)
    assert row["daemon_over_forward"] == pytest.approx(85.0 / 40.0)
    other = gap.summarise("aisles-2", "aisles", 1, [runs[1]])
    gap.print_table([row, other])
    out = capsys.readouterr().out.splitlines()
    assert out[1].split() == ["turn", "3", "turn-Lleft", "85.0", "40.0", "100.0", "85.0", "2.12", "5.0", "10.0", "-"]
    assert out[-1] == "mean share 87.5 %; worst scene turn seed 3 (turn-Lleft) at 85.0 %"


def _around_the_corner(scene: FamilyScene, before: float, after: float) -> FamilyScene:
    """The scene with its route cut to ``before`` m before the first corner and ``after`` m past it."""
    step = np.diff(scene.route, axis=0)
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(step, axis=1))])
    heading = np.arctan2(step[:, 1], step[:, 0])
    corner = arc[1:][int(np.flatnonzero(np.abs(np.diff(heading)) > 0.1)[0])]
    keep = (arc >= corner - before) & (arc <= corner + after)
    return FamilyScene(scene.name, scene.family, scene.seed, scene.landmarks, scene.route[keep])


#: daemon / achievable on the turn below must reach this: the daemon measured 0.986 there (0.90 before the seeds
#: pipeline, 0.83 before its joint-grid seed and plain-count objective); the floor leaves the margin a loaded
#: machine needs, so a fall below it is a regression
MIN_SHARE_TURN = 0.9


@pytest.fixture(scope="module")
def turn_run(tmp_path_factory):
    """pivotd + sim_pose + mock gimbal on the turn family, seed 1, about 24 m around the corner at 1.2 m/s (20 s)."""
    from pivotd.sim.stack import run_stack

    tmp = tmp_path_factory.mktemp("gap")
    scene = _around_the_corner(generate("turn", 1), 10.0, 14.0)
    assert 20.0 <= scene.length <= 24.5
    map_file, route = write_scene(scene, tmp / "scene")
    return scene, map_file, run_stack(gap.DEMO, tmp / "run", route=route, map_file=map_file, speed=1.2)


@pytest.mark.slow
def test_real_stack_on_a_turn_records_poses_and_joint_states(turn_run):
    scene, map_file, run = turn_run
    assert run.daemon_exit == 0
    assert run.cfg.map.file == map_file.resolve()
    rec = run.run
    assert rec.pose_t.size > 500 and rec.measured.t.size > 500  # 20 s of poses and joint states at 50 Hz
    np.testing.assert_allclose(rec.pose_pos[0], scene.route[0], atol=0.05)
    assert np.linalg.norm(rec.pose_pos[-1] - scene.route[-1]) < 0.5
    assert run.report["within_limits"]
    figures = gap.judge(run, None)  # from the run's own analysis
    assert figures["daemon_mean"] >= figures["forward_mean"], figures
    assert 0.0 <= figures["frames_below_forward_90"] < 0.5
    assert gap.host_stalls(run.report) == run.report["final_status"]["link_counters"]["host_stalls"]
    assert 0.005 < gap.longest_setpoint_gap(run) < 5.0  # at least the 10 ms control period


@pytest.mark.slow
def test_real_stack_on_a_turn_against_the_achievable_view(turn_run):
    _, _, run = turn_run
    figures = gap.judge(run, gap._achievable())
    assert figures["source"] == "achievable_report"
    assert figures["forward_mean"] < figures["achievable_mean"] <= figures["teleport_mean"], figures
    assert figures["daemon_mean"] > figures["forward_mean"], figures
    assert figures["share"] >= MIN_SHARE_TURN, figures
