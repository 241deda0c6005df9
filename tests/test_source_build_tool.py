"""tools/check_source_build (ruckig from its sdist, as on aarch64): its interface, without building anything.

The build itself (a few minutes) runs in CI as a leg of .ci/run, not in the test suite.
"""

from __future__ import annotations

import os
import re
import shutil
import subprocess
from pathlib import Path

import pytest
from support import REPO

TOOL = REPO / "tools" / "check_source_build"


def run_tool(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run([str(TOOL), *args], capture_output=True, text=True, timeout=30, cwd=REPO, check=False)


def test_the_tool_is_an_executable_file():
    assert TOOL.is_file()
    assert os.access(TOOL, os.X_OK)


def test_help_names_every_option_and_the_no_binary_install():
    result = run_tool("--help")
    assert result.returncode == 0, result.stderr
    assert result.stdout.startswith("usage: tools/check_source_build")
    assert "pip install --no-binary ruckig" in result.stdout
    for option in ("--python", "--keep", "--system-cmake", "--help"):
        assert re.search(rf"^\s+(?:-\w, )?{re.escape(option)}\b", result.stdout, re.MULTILINE), option
    assert run_tool("-h").stdout == result.stdout


def test_an_unknown_argument_is_a_usage_error_naming_it():
    result = run_tool("--fast")
    assert result.returncode == 2
    assert "unknown argument '--fast'" in result.stderr
    assert len(result.stderr.strip().splitlines()) == 1


def test_a_missing_interpreter_is_a_usage_error_before_any_venv_is_made():
    result = run_tool("--python", "/nonexistent/python3.10")
    assert result.returncode == 2
    assert "no interpreter '/nonexistent/python3.10'" in result.stderr
    assert "== source build" not in result.stdout


def python_older_than_the_project() -> str | None:
    """A Python 3.9 that runs (python3.9 on PATH, else pyenv's), or None."""
    pyenv = Path(os.environ.get("PYENV_ROOT", Path.home() / ".pyenv"))
    for candidate in [shutil.which("python3.9"), *map(str, sorted(pyenv.glob("versions/3.9.*/bin/python3.9")))]:
        runs = candidate and subprocess.run([candidate, "-c", "import venv"], capture_output=True, check=False)
        if runs and runs.returncode == 0:
            return candidate
    return None


@pytest.mark.slow
def test_a_failed_install_fails_the_run_with_pips_error():
    """What makes the CI leg fail: pip refusing the checkout (requires-python >= 3.10) is exit 1, never 0."""
    python = python_older_than_the_project()
    if python is None:
        pytest.skip("no Python 3.9 here to make pip refuse the checkout")
    result = subprocess.run([str(TOOL), "--python", python], capture_output=True, text=True, timeout=600, cwd=REPO,
                            check=False)
    assert result.returncode == 1
    assert "requires a different Python" in result.stderr
    assert "source build: FAILED: pip install --no-binary ruckig" in result.stderr
    assert "== source build: passed" not in result.stdout


def test_the_tests_it_runs_exist_and_import_the_motion_generator():
    tests = sorted(REPO.glob("tests/test_motion*.py")) + sorted(REPO.glob("tests/test_control*.py"))
    assert len(tests) >= 4
    assert any("pivotd.gimbal.motion" in path.read_text() for path in tests)


def test_ci_runs_it_after_the_other_legs():
    ci = (REPO / ".ci" / "run").read_text().splitlines()
    legs = [i for i, line in enumerate(ci) if line.startswith("leg ")]
    build = [i for i in legs if "tools/check_source_build" in ci[i]]
    assert build == [legs[-1]]


def test_install_doc_is_linked_from_the_readme():
    assert (REPO / "docs" / "INSTALL.md").is_file()
    assert "(docs/INSTALL.md)" in (REPO / "README.md").read_text()
