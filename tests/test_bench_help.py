"""Every `pivotd bench NAME --help` prints its options (argparse formats every help text) and exits 0."""

import subprocess
import sys

import pytest

from pivotd.bench import BENCHES


@pytest.mark.slow  # one subprocess per bench
@pytest.mark.parametrize("name", sorted(BENCHES))
def test_every_bench_prints_its_help(name):
    out = subprocess.run([sys.executable, "-m", "pivotd.cli", "bench", name, "--help"], capture_output=True,
                         text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    assert f"pivotd bench {name}" in out.stdout and "--help" in out.stdout
