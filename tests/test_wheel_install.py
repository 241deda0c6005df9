"""The wheel as docs/SYSTEMD.md installs it: built from the tree, installed with its dependencies into a new venv
outside the checkout (no PYTHONPATH, no system site-packages), its commands run from an empty directory.

Needs pip to reach the package index (the dependencies) or its cache; about two minutes the first time.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import pytest
from support import REPO

pytestmark = pytest.mark.slow


def _clean_env() -> dict[str, str]:
    """The environment without anything that points Python at the checkout."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("PYTHON", "VIRTUAL_ENV", "PIP_"))}
    env.pop("NOTIFY_SOCKET", None)
    return env


def _run(cmd: list[str], cwd: Path, timeout: float = 120) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, cwd=cwd, env=_clean_env(), capture_output=True, text=True, timeout=timeout)


@pytest.fixture(scope="module")
def wheel(tmp_path_factory) -> Path:
    """The wheel built from a copy of the checkout's files (git's list: the build leaves nothing in the tree)."""
    if shutil.which("git") is None:
        pytest.skip("git is needed to list the checkout's files")
    tmp = tmp_path_factory.mktemp("wheel")
    listed = subprocess.run(["git", "ls-files", "-z", "--cached", "--others", "--exclude-standard"], cwd=REPO,
                            capture_output=True, check=True, timeout=60).stdout.decode().split("\0")
    src = tmp / "src"
    for name in filter(None, listed):
        if (REPO / name).is_file():
            (src / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(REPO / name, src / name)
    res = _run([sys.executable, "-m", "pip", "wheel", "--no-deps", "-w", str(tmp / "dist"), str(src)], tmp,
               timeout=600)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    assert "Warning" not in res.stderr, res.stderr  # setuptools' deprecation and packaging warnings
    (built,) = (tmp / "dist").glob("pivotd-*.whl")
    return built


@pytest.fixture(scope="module")
def venv_bin(wheel, tmp_path_factory) -> Path:
    """A new venv (no system site-packages) with the wheel and its dependencies; its bin directory."""
    venv = tmp_path_factory.mktemp("venv") / "pivotd venv"  # a blank in the path, as /opt paths may have
    res = _run([sys.executable, "-m", "venv", str(venv)], venv.parent)
    assert res.returncode == 0, res.stderr
    res = _run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", str(wheel)], venv.parent,
               timeout=900)
    assert res.returncode == 0, res.stdout[-3000:] + res.stderr[-3000:]
    return venv / "bin"


def test_the_wheel_holds_pivotd_only_with_its_data_and_license(wheel):
    names = zipfile.ZipFile(wheel).namelist()
    version = wheel.name.split("-")[1]
    assert {n.split("/")[0] for n in names} == {"pivotd", f"pivotd-{version}.dist-info"}
    shipped = {n.removeprefix("pivotd/data/") for n in names if n.startswith("pivotd/data/") and
               not n.endswith(".py")}
    tracked = {str(p.relative_to(REPO)) for d in ("config", "systemd") for p in (REPO / d).rglob("*") if p.is_file()}
    assert shipped == tracked
    assert f"pivotd-{version}.dist-info/licenses/LICENSE" in names


def test_installed_commands_work_outside_the_checkout(wheel, venv_bin, tmp_path):
    version = wheel.name.split("-")[1]
    work = tmp_path / "empty"
    work.mkdir()
    res = _run([str(venv_bin / "python"), "-c", "import pivotd; print(pivotd.__file__)"], work)
    assert Path(res.stdout.strip()).is_relative_to(venv_bin.parent), res.stdout + res.stderr

    res = _run([str(venv_bin / "pivotd"), "--version"], work)
    assert (res.returncode, res.stdout.strip()) == (0, f"pivotd {version}"), res.stderr

    config = tmp_path / "etc" / "pivotd.yaml"
    res = _run([str(venv_bin / "pivotd"), "init", "--template", "spot", "--config", str(config)], work)
    assert res.returncode == 0, res.stderr
    assert config.read_bytes() == (REPO / "config" / "spot.yaml").read_bytes()
    res = _run([str(venv_bin / "pivotd"), "init", "--template", "spot", "--config", str(config)], work)
    assert res.returncode == 2 and "exists (--force overwrites)" in res.stderr
    # offline, as the unit runs it: spot's serial adapter is not on this machine (a warning, not an error)
    res = _run([str(venv_bin / "pivotd"), "check", "--offline", "--config", str(config)], work)
    assert res.returncode == 0, res.stderr
    assert res.stdout.startswith(f"config: {config} OK\n")

    demo = tmp_path / "demo" / "pivotd.yaml"
    assert _run([str(venv_bin / "pivotd"), "init", "--template", "demo", "--config", str(demo)], work).returncode == 0
    res = _run([str(venv_bin / "pivotd"), "check", "--config", str(demo)], work)
    assert res.returncode == 0, res.stderr
    assert f"map: {demo.parent / 'demo_hallway_map.txt'} (3150 landmarks" in res.stdout

    res = _run([str(venv_bin / "pivotd"), "install-service", "--config", str(config)], work)
    assert res.returncode == 0, res.stderr
    assert f'\nExecStart="{venv_bin / "pivotd"}" run --config {config}\n' in res.stdout
    assert f'\nExecStartPre="{venv_bin / "pivotd"}" check --offline --config {config}\n' in res.stdout
    assert "\nu pivotd - " in res.stdout

    for script, usage in (("pivotd-mock-gimbal", "usage: mock_gimbal"), ("pivotd-sim-pose", "usage: sim_pose")):
        res = _run([str(venv_bin / script), "--help"], work)
        assert res.returncode == 0 and res.stdout.startswith(usage), script + res.stdout + res.stderr
