"""One set of defaults for the optimizer's options: the TrajectoryOptions fields a config key sets have no default
(the daemon's come from the config dataclasses through pivotd.daemon.wiring.trajectory_options, the paper's are the
preset TrajectoryOptions.paper()); the preset and the daemon's defaults agree on every other field and differ only
where the table of docs/design/optimizer.md says, with the values it gives; the optimizer does not import the
config."""

from __future__ import annotations

import ast
import math
from dataclasses import MISSING, fields, replace
from enum import Enum
from pathlib import Path

import numpy as np
import pytest

from pivotd.cli import build_parser
from pivotd.cli import plan as plan_cli
from pivotd.config import Config
from pivotd.daemon.wiring import trajectory_options
from pivotd.maps.formats import load_landmarks
from pivotd.pivot.normalise import Normalisation
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory
from pivotd.pivot.view import ViewOptions
from pivotd.robot_path import load_path

ROOT = Path(__file__).resolve().parents[1]
OPTIMIZER_DOC = ROOT / "docs" / "design" / "optimizer.md"
TABLE_HEADER = "| `TrajectoryOptions` field | config key |"

#: TrajectoryOptions field -> (config section, config field, another value of it, the option it gives)
MIRRORED = {
    "width_deg": ("pivot", "transition_width", math.radians(2.5), 2.5),
    "max_iterations": ("pivot", "iterations", 33, 33),
    "distance_weights": ("pivot", "distance_weights", True, True),
    "smooth_knee_deg": ("pivot", "smooth_knee", math.radians(2.0), 2.0),
    "normalise": ("planner", "normalise", Normalisation.ATTAINABLE, Normalisation.ATTAINABLE),
}


def _has_default(f) -> bool:
    return f.default is not MISSING or f.default_factory is not MISSING


def test_the_fields_a_config_key_sets_have_no_default_and_the_others_keep_theirs():
    required = {f.name for f in fields(TrajectoryOptions) if not _has_default(f)}
    assert required == set(MIRRORED), "a TrajectoryOptions field a config key sets must have no default"
    with pytest.raises(TypeError, match="missing 5 required keyword-only arguments"):
        TrajectoryOptions()
    with pytest.raises(TypeError):
        TrajectoryOptions(3.0, 60, True, 0.0, Normalisation.TOTAL)  # keyword fields only
    assert all(_has_default(f) for f in fields(ViewOptions))  # no config key sets any of the single view's


@pytest.mark.parametrize("option", sorted(MIRRORED))
def test_each_field_without_a_default_follows_its_config_key_alone(option):
    section, key, value, expected = MIRRORED[option]
    cfg = Config()
    changed = replace(cfg, **{section: replace(getattr(cfg, section), **{key: value})})
    before, after = trajectory_options(cfg), trajectory_options(changed)
    assert getattr(before, option) != expected
    assert getattr(after, option) == pytest.approx(expected, rel=1e-12) if isinstance(expected, float) \
        else getattr(after, option) == expected
    others = {f.name for f in fields(TrajectoryOptions)} - {option}
    assert all(getattr(after, n) == getattr(before, n) for n in others)


def _cell(value) -> str:
    """A value as the doc table writes it."""
    if isinstance(value, bool):
        return str(value).lower()
    if isinstance(value, Enum):
        return str(value.value)
    if isinstance(value, float):
        return f"{value:g}"
    return str(value)


def _doc_table() -> list[list[str]]:
    """The rows of the table of the paper's and the daemon's settings in docs/design/optimizer.md (cells without
    backticks)."""
    lines = OPTIMIZER_DOC.read_text(encoding="utf-8").splitlines()
    start = next(i for i, line in enumerate(lines) if line.startswith(TABLE_HEADER))
    rows = []
    for line in lines[start + 2:]:
        if not line.startswith("|"):
            break
        rows.append([c.strip().replace("`", "") for c in line.strip().strip("|").split("|")])
    return rows


def test_the_paper_preset_and_the_daemons_defaults_differ_only_as_documented():
    paper, daemon = TrajectoryOptions.paper(), trajectory_options(Config())
    rows = _doc_table()
    named = {r[0]: r for r in rows if r[0] != "every other field"}
    assert set(MIRRORED) <= set(named), "every field a config key sets has a row"
    defaults = {f.name: f.default for f in fields(TrajectoryOptions) if _has_default(f)}
    for name, (_, key, paper_cell, daemon_cell, agree) in named.items():
        assert (_cell(getattr(paper, name)), _cell(getattr(daemon, name))) == (paper_cell, daemon_cell), name
        assert agree == ("yes" if getattr(paper, name) == getattr(daemon, name) else "no"), name
        if name in MIRRORED:
            section, config_field = MIRRORED[name][:2]
            assert key.split(".")[0] == section and key.split(".")[1].startswith(config_field), (name, key)
    assert any(r[0] == "every other field" and r[-1] == "yes" for r in rows)
    for name in set(defaults) - set(named):  # the optimizer's own tuning: one default, shared
        assert getattr(paper, name) == getattr(daemon, name) == defaults[name], name


def test_optimize_trajectory_without_options_is_the_paper_preset():
    rng = np.random.default_rng(2)
    way = np.column_stack([np.linspace(0.0, 4.0, 9), np.zeros(9), np.zeros(9)])
    pts = way[rng.integers(0, 9, 400)] + rng.normal(scale=3.0, size=(400, 3))
    alpha = math.radians(20.0)
    bare = optimize_trajectory(pts, way, alpha, 0.6)
    paper = optimize_trajectory(pts, way, alpha, 0.6, options=TrajectoryOptions.paper())
    other = optimize_trajectory(pts, way, alpha, 0.6, options=TrajectoryOptions.paper(distance_weights=False))
    assert np.array_equal(bare.directions, paper.directions) and bare.objective == paper.objective
    assert other.objective != paper.objective  # the options reach the solve


def test_pivotd_plan_without_config_plans_with_the_paper_preset_without_distance_weights(tmp_path, capsys):
    data = ROOT / "tests" / "data" / "fif"
    map_file, path_file, out = data / "two_walls_points_w.txt", data / "test_traj.csv", tmp_path / "plan.csv"
    args = build_parser().parse_args(["plan", "--map", str(map_file), "--path", str(path_file), "--out", str(out)])
    assert plan_cli.run(args) == 0
    capsys.readouterr()
    planned = np.loadtxt(out, delimiter=",", skiprows=1)
    cloud = load_landmarks(map_file)
    assert np.all(cloud.weights == 1.0)  # its weight column is all ones: uniform weights (--weights-from auto)
    alpha = math.radians(plan_cli.PAPER_FOV_DEG) / 2.0
    expected = optimize_trajectory(cloud.points, load_path(path_file).positions, alpha, plan_cli.PAPER_LAMBDA,
                                   options=TrajectoryOptions.paper(distance_weights=False))
    np.testing.assert_allclose(planned[:, 4:7], expected.directions, atol=1e-9)  # written with 9 decimals
    assert np.array_equal(planned[:, 7].astype(int), expected.visible)


def test_the_optimizer_imports_nothing_of_the_config_or_the_daemon():
    found = []
    for p in sorted((ROOT / "pivotd" / "pivot").glob("*.py")):
        for node in ast.walk(ast.parse(p.read_text(encoding="utf-8"))):
            if isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            elif isinstance(node, ast.ImportFrom):  # from pivotd import config: pivotd.config
                names = [f"{node.module}.{a.name}" for a in node.names]
            else:
                continue
            found += [f"{p.name}:{node.lineno}: {n}" for n in names
                      if n.split(".")[:2] in (["pivotd", "config"], ["pivotd", "daemon"], ["pivotd", "cli"])]
    assert not found, found
