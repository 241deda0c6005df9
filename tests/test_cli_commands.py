"""The ``pivotd`` command line as a whole: help, version, unknown commands, ``make lint``, ``plan --json``."""

from __future__ import annotations

import json
import os
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest
from support import PYTHON, REPO

import pivotd
from pivotd.cli import COMMANDS, main
from pivotd.version import version

TWO_WALLS = REPO / "tests" / "data" / "fif" / "two_walls_points_w.txt"


def test_help_names_every_command(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--help"])
    assert exc.value.code == 0
    out = capsys.readouterr().out
    description = " ".join(out.split("\n\n")[1].split())  # the paragraph after the usage line
    for name in COMMANDS:
        assert name in description, name
        help_text = " ".join(COMMANDS[name][1].split())
        assert re.search(rf"\n    {re.escape(name)}\s+{re.escape(help_text[:20])}", out), name  # and its help


def test_version_from_the_package_metadata(capsys):
    with pytest.raises(SystemExit) as exc:
        main(["--version"])
    assert exc.value.code == 0
    assert capsys.readouterr().out.strip() == f"pivotd {version()}"
    assert version() == pivotd.__version__  # the metadata of this tree's install, and the source fallback agree


@pytest.mark.parametrize(("typed", "message"), [
    ("chek", "unknown command 'chek' (did you mean check?)"),
    ("stauts", "unknown command 'stauts' (did you mean status?)"),
    ("frobnicate", "unknown command 'frobnicate' (commands: run, check, plan, bench, status, plot, gimbal, init, "
                   "install-service)"),
])
def test_unknown_command_is_one_line_and_exit_2(capsys, typed, message):
    assert main([typed, "--config", "x.yaml"]) == 2
    err = capsys.readouterr().err
    assert err == f"pivotd: error: {message}\n"


@pytest.mark.skipif(shutil.which("make") is None, reason="needs make")
def test_make_lint_runs_ruff(tmp_path):
    # -o: the venv counts as installed (this interpreter's), so the target runs ruff and nothing else
    bin_dir = Path(PYTHON).parent
    if not (bin_dir / "ruff").exists():
        pytest.skip("ruff is not installed beside this interpreter")
    env = {k: v for k, v in os.environ.items() if k not in ("MAKEFLAGS", "MFLAGS", "MAKELEVEL")}  # not a sub-make
    dry = subprocess.run(["make", "-n", "-o", ".venv/.installed", "lint", f"BIN={bin_dir}"], cwd=REPO,
                         capture_output=True, text=True, timeout=60, env=env)
    assert dry.returncode == 0, dry.stderr
    assert dry.stdout.strip() == f"{bin_dir}/ruff check ."
    res = subprocess.run(["make", "-s", "-o", ".venv/.installed", "lint", f"BIN={bin_dir}"], cwd=REPO,
                         capture_output=True, text=True, timeout=300, env=env)
    assert res.returncode == 0, res.stdout + res.stderr
    assert "All checks passed" in res.stdout


def test_plan_json_has_the_filter_settings(tmp_path, capsys):
    path = tmp_path / "path.csv"
    path.write_text("".join(f"4.5,{y:.3f},0.0\n" for y in np.linspace(-2.0, 2.0, 5)))
    assert main(["plan", "--map", str(TWO_WALLS), "--path", str(path), "--lambda", "0", "--max-range", "6",
                 "--occlusion-voxel", "0.5", "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["waypoints"] == 5
    assert {k: summary[k] for k in ("min_range", "max_range", "max_view_angle_deg", "occlusion_voxel", "occupancy",
                                    "weights_from", "weight_property", "max_step_limit_deg")} == {
        "min_range": None, "max_range": 6.0, "max_view_angle_deg": None, "occlusion_voxel": 0.5, "occupancy": None,
        "weights_from": "auto", "weight_property": None, "max_step_limit_deg": None}


def test_cli_doc_lists_every_plan_json_key(tmp_path, capsys):
    """Every key ``plan --json`` prints is named in docs/CLI.md's paragraph on it."""
    path = tmp_path / "path.csv"
    path.write_text("4.5,0,0\n4.5,1,0\n")
    assert main(["plan", "--map", str(TWO_WALLS), "--path", str(path), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    doc = (REPO / "docs" / "CLI.md").read_text()
    paragraph = doc[doc.index("- `--json` prints exactly one JSON object"):]
    paragraph = paragraph[:paragraph.index("\n\n")]
    missing = [k for k in summary if f"`{k}`" not in paragraph]
    assert not missing
