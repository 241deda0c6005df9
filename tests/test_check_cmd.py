"""`pivotd check`: exit 0 with a summary on every shipped config, exit 2 with one line on broken ones."""

import os
import subprocess
import sys
from pathlib import Path

import pytest

from pivotd.config import load_config

pytestmark = pytest.mark.slow  # subprocesses / real time

REPO = Path(__file__).resolve().parent.parent
SHIPPED = sorted((REPO / "config").glob("*.yaml"))


def run_check(config: Path, cwd: Path | None = None, *options: str) -> subprocess.CompletedProcess:
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.run(
        [sys.executable, "-m", "pivotd.cli", "check", "--config", str(config), *options],
        capture_output=True,
        text=True,
        env=env,
        cwd=cwd or REPO,
        timeout=60,
    )


def test_every_shipped_config_is_found():
    assert {p.name for p in SHIPPED} >= {"spot.yaml", "demo.yaml"}


@pytest.mark.parametrize("config", SHIPPED, ids=lambda p: p.name)
def test_shipped_configs_pass_without_warnings(config, tmp_path):
    """Offline (spot.yaml's router is not up here), strict, and with a device that exists (a pty) where the
    config names a serial adapter this machine does not have."""
    master, slave = os.openpty()
    try:
        port = ["--port", os.ttyname(slave)] if load_config(config).gimbal.port.startswith("/dev/") else []
        # another working directory: relative paths follow the file
        result = run_check(config, tmp_path, "--offline", "--strict", *port)
    finally:
        os.close(slave)
        os.close(master)
    assert result.returncode == 0, result.stderr
    assert result.stderr == ""
    out = result.stdout
    assert f"config: {config.resolve()} OK" in out
    assert "node: " in out and "gimbal: port " in out and "motion: pan " in out and "zenoh: " in out
    assert "mount: xyz [" in out and "observation directions: no" in out


def test_demo_passes_the_live_probes_without_warnings():
    result = run_check(REPO / "config" / "demo.yaml", None, "--strict")
    assert (result.returncode, result.stderr) == (0, "")


def test_demo_summary_reports_the_map():
    result = run_check(REPO / "config" / "demo.yaml")
    assert result.returncode == 0, result.stderr
    assert "node: demo (status key pivot/demo/status)" in result.stdout
    assert "(3150 landmarks, bounds x y z [" in result.stdout
    assert "pivot: fov 60° (α 30°)" in result.stdout
    assert "gimbal: port mock://" in result.stdout
    assert "listen ['tcp/127.0.0.1:7457']" in result.stdout


@pytest.mark.parametrize(
    ("text", "expected"),
    [
        ("map: {allow_empty: true}\ngimbal:\n  limits: {tilt_min_deg: 5, tilt_max_deg: 0}\n",
         "broken.yaml:3: gimbal.limits.tilt_max_deg: must be > tilt_min_deg (5)"),
        ("map: {allow_empty: true}\ncontrol: {rate_hz: 1000}\n", "broken.yaml:2: control.rate_hz: must be ≤ 200"),
        ("map: {file: absent.txt}\n", "broken.yaml:1: map.file: file not found"),
        ("map: {file: bad_map.txt}\n", "bad_map.txt:2: expected 3 columns, got 2"),
        # the map is loaded as the daemon loads it: its weight property too
        ("map: {file: named.csv, weight_property: score}\n", "named.csv:1: header row has no weight column 'score'"),
        ("map: {file: empty.txt}\n", "empty.txt: map is empty"),
        ("map: {file: plain.txt, weight_property: w}\n",
         "broken.yaml:1: map.weight_property: {tmp}/plain.txt: weight property 'w' needs a header row"),
    ],
)
def test_broken_configs_exit_2_with_one_line(tmp_path, text, expected):
    (tmp_path / "bad_map.txt").write_text("0 0 0\n1 2\n")
    (tmp_path / "named.csv").write_text("x,y,z,intensity\n0,0,0,1\n")
    (tmp_path / "empty.txt").write_text("# no landmarks yet\n")
    (tmp_path / "plain.txt").write_text("0 0 0 1\n")
    expected = expected.replace("{tmp}", str(tmp_path))
    config = tmp_path / "broken.yaml"
    config.write_text(text)
    result = run_check(config)
    assert result.returncode == 2
    lines = result.stderr.strip().splitlines()
    assert len(lines) == 1, result.stderr
    assert lines[0].startswith("pivotd check: error: ")
    assert expected in lines[0]
    assert result.stdout == ""


def test_map_settings_reach_the_map_reader(tmp_path):
    (tmp_path / "named.csv").write_text("x,y,z,intensity\n0,0,0,1\n1,2,3,4\n")
    (tmp_path / "empty.txt").write_text("# no landmarks yet\n")
    for text, expected in (("map: {file: named.csv, weight_property: intensity}\n", "(2 landmarks"),
                           ("map: {file: empty.txt, allow_empty: true}\n", "empty.txt (empty; landmarks from")):
        config = tmp_path / "ok.yaml"
        config.write_text(text)
        result = run_check(config)
        assert result.returncode == 0, result.stderr
        assert expected in result.stdout


def test_missing_config_exits_2(tmp_path):
    result = run_check(tmp_path / "nope.yaml")
    assert result.returncode == 2
    assert result.stderr.strip().splitlines() == [f"pivotd check: error: {tmp_path / 'nope.yaml'}: no such config file"]
