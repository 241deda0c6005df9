"""``pivotd plan --config``: the daemon's replans along a path, with joint angles within the limits; the options of
the paper mode are errors with a config; the paper mode keeps its settings."""

from __future__ import annotations

import argparse
import json
import math

import numpy as np
import pytest

from pivotd.cli import build_parser
from pivotd.cli import plan as plan_cmd
from pivotd.config import load_config
from pivotd.daemon.offline import path_message, plan_along_path, robot_poses
from pivotd.daemon.wiring import build_map_store, build_planner, replan_anchor
from pivotd.errors import InputError
from pivotd.gimbal.kinematics import joints_to_world_direction
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import load_path
from pivotd.sim.launch import REPO, derive_config

DEMO = REPO / "config" / "demo.yaml"


@pytest.fixture(scope="module")
def demo(tmp_path_factory):
    """The demo config with narrow tilt limits (the plan must respect them) and a path through the first bend."""
    tmp = tmp_path_factory.mktemp("plan_config")
    config = derive_config(DEMO, tmp / "pivotd.yaml", {"gimbal.limits.tilt_min_deg": -5.0,
                                                        "gimbal.park": {"pan_deg": 10, "tilt_deg": 0}})
    path = tmp / "path.csv"
    np.savetxt(path, hallway().path[:30], delimiter=",", fmt="%.6f")
    return config, path, tmp


def _run(*argv: str) -> int:
    return plan_cmd.run(build_parser().parse_args(["plan", *argv]))


def test_csv_json_and_first_plan_are_the_daemons_replans(demo, capsys):
    config, path, tmp = demo
    out, first = tmp / "plan.csv", tmp / "first.json"
    assert _run("--config", str(config), "--path", str(path), "--out", str(out), "--first-plan-out", str(first),
                "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    cfg = load_config(config)
    steps = plan_along_path(cfg, build_map_store(cfg), load_path(path))
    rows = out.read_text().splitlines()
    assert rows[0] == "i,x,y,z,dx,dy,dz,visible,pan_deg,tilt_deg"
    table = np.loadtxt(out, delimiter=",", skiprows=1)
    assert table.shape == (len(steps), 10) and summary["replans"] == len(steps)
    chords = np.linalg.norm(np.diff(table[:, 1:4], axis=0), axis=1)  # one replan per waypoint spacing along it
    np.testing.assert_allclose(chords, 0.5, atol=0.01)
    np.testing.assert_allclose(table[:, 4:7], [st.direction for st in steps], atol=1e-8)
    np.testing.assert_array_equal(table[:, 7], [st.visible for st in steps])
    assert summary["visible_mean"] == pytest.approx(np.mean(table[:, 7])) and summary["visible_min"] > 100
    lim = cfg.gimbal.limits
    pans, tilts = np.radians(table[:, 8]), np.radians(table[:, 9])
    assert np.all((lim.pan_min <= pans) & (pans <= lim.pan_max))
    assert np.all((lim.tilt_min - 1e-7 <= tilts) & (tilts <= lim.tilt_max))
    assert summary["tilt_deg_min"] == pytest.approx(-5.0, abs=1e-3)  # the hallway's plan would look lower
    for st, pan, tilt in zip(steps, pans, tilts, strict=True):  # the joints point the camera along the plan
        if not st.clamped:
            np.testing.assert_allclose(joints_to_world_direction(pan, tilt, st.quat, cfg.gimbal.mount), st.direction,
                                       atol=1e-5)
    doc = json.loads(first.read_text())
    assert doc["path_mode"] == "on_path" and len(doc["directions"]) == cfg.planner.horizon
    np.testing.assert_allclose(doc["directions"], steps[0].plan.directions, atol=1e-12)


def test_the_first_replan_is_anchored_at_the_park_pose_then_at_the_previous_plan(demo):
    config, path, _ = demo
    cfg = load_config(config)
    store = build_map_store(cfg)
    poses = robot_poses(load_path(path), cfg.planner.waypoint_spacing)
    steps = plan_along_path(cfg, store, load_path(path))
    planner = build_planner(cfg)  # the same replans by hand, with the documented anchors
    planner.set_path(*path_message(load_path(path)), 1)
    first = planner.replan(store.snapshot(), poses.positions[0], poses.quats[0],
                           replan_anchor(cfg, None, poses.quats[0]))
    np.testing.assert_array_equal(first.directions, steps[0].plan.directions)
    second = planner.replan(store.snapshot(), poses.positions[1], poses.quats[1], first.directions[0])
    np.testing.assert_array_equal(second.directions, steps[1].plan.directions)
    park = joints_to_world_direction(math.radians(10), 0.0, poses.quats[0], cfg.gimbal.mount)
    np.testing.assert_allclose(replan_anchor(cfg, None, poses.quats[0]), park, atol=1e-12)


def test_the_map_defaults_to_the_configs_and_may_be_overridden(demo, tmp_path, capsys):
    config, path, _ = demo
    assert _run("--config", str(config), "--path", str(path), "--json") == 0
    assert json.loads(capsys.readouterr().out)["landmarks"] == 3150  # config/demo_hallway_map.txt
    small = tmp_path / "small.txt"
    small.write_text("".join(f"{x} 1.5 1.0\n" for x in range(20)))
    assert _run("--config", str(config), "--path", str(path), "--map", str(small), "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["landmarks"] == 20 and summary["map"] == str(small.resolve())


@pytest.mark.parametrize(("option", "value", "key"), [
    ("--fov-deg", "30", "pivot.fov_deg"), ("--lambda", "0.6", "pivot.lambda"),
    ("--smooth-knee-deg", "0", "pivot.smooth_knee_deg"), ("--max-range", "5", "map.filters.max_range"),
    ("--weights-from", "none", "map.weight_property"), ("--occlusion-voxel", "0.2", "map.filters.occlusion_voxel"),
])
def test_a_paper_option_with_a_config_is_a_one_line_error(demo, option, value, key):
    config, path, _ = demo
    with pytest.raises(InputError) as info:
        _run("--config", str(config), "--path", str(path), option, value)
    assert str(info.value) == f"{option} cannot be combined with --config: the config sets it ({key})"


def test_every_paper_option_is_checked_against_the_config():
    from pivotd.cli.plan_config import CONFLICTS

    parser = argparse.ArgumentParser()
    plan_cmd.configure(parser)
    args = parser.parse_args(["--path", "p.csv"])
    paper = {a.dest for a in parser._actions}
    paper -= {"help", "config", "map", "path", "out", "json", "first_plan_out"}
    assert {dest for dest, _ in CONFLICTS.values()} == paper
    assert all(getattr(args, dest) is None for dest in paper)  # so a given one is seen


def test_the_paper_mode_needs_a_map_and_has_no_first_plan(demo, tmp_path):
    _, path, _ = demo
    with pytest.raises(InputError, match="--map MAP is required"):
        _run("--path", str(path))
    with pytest.raises(InputError, match="--first-plan-out needs --config"):
        _run("--path", str(path), "--map", str(REPO / "config" / "demo_hallway_map.txt"), "--first-plan-out",
             str(tmp_path / "f.json"))


def test_the_paper_mode_keeps_its_settings(demo, capsys):
    _, path, _ = demo
    assert _run("--path", str(path), "--map", str(REPO / "config" / "demo_hallway_map.txt"), "--json") == 0
    summary = json.loads(capsys.readouterr().out)
    assert (summary["fov_deg"], summary["lambda"], summary["smooth_knee_deg"]) == (30.0, 0.6, 0.0)
    assert summary["waypoints"] == 30


def test_a_config_without_a_map_file_needs_map(tmp_path):
    config = tmp_path / "empty.yaml"
    config.write_text("map:\n  allow_empty: true\n")
    path = tmp_path / "p.csv"
    path.write_text("0,0,0\n1,0,0\n")
    with pytest.raises(InputError, match=r"map\.file is not set .*: give --map MAP"):
        _run("--config", str(config), "--path", str(path))


def test_a_removed_key_in_the_config_is_a_one_line_error(demo, tmp_path):
    from pivotd.errors import ConfigError

    config, path, _ = demo
    bad = derive_config(config, tmp_path / "bad.yaml", {"planner.spread_cell_deg": 10})
    with pytest.raises(ConfigError, match=r"planner\.spread_cell_deg: unknown key \(removed: measured and not kept"):
        _run("--config", str(bad), "--path", str(path))
