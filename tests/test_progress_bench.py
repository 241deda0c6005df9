"""Progress lines of the long ``pivotd bench`` runs on a fake terminal: one line over each run's main loop,
counting to its end, and none with ``--json``."""

from __future__ import annotations

import json

import pytest
from test_progress import FakeTTY, frames, not_silenced, terminal  # noqa: F401 (autouse fixture)

from pivotd.bench import motion
from pivotd.cli import main


def counts(tty: FakeTTY, label: str) -> list[str]:
    """The ``done/total`` fields of the lines drawn for ``label``."""
    return [f.split()[-3] for f in frames(tty.getvalue()) if f.startswith(label + ":")]


def test_motion_counts_its_timing_loops(monkeypatch):
    tty = terminal(monkeypatch)
    report = motion.measure(cycles=40)
    assert len(report["results"]) == 7  # six timed loops and the speedup
    assert counts(tty, "motion timings") == ["1/6", "2/6", "3/6", "4/6", "5/6", "6/6", "6/6"]


def test_motion_with_json_stays_quiet(monkeypatch, tmp_path):
    tty = terminal(monkeypatch)
    real = motion.measure
    monkeypatch.setattr(motion, "measure", lambda cycles, seed=0: real(cycles=20, seed=seed))  # --quick is 2000
    assert main(["bench", "motion", "--quick", "--json", str(tmp_path / "m.json")]) == 0
    assert json.loads((tmp_path / "m.json").read_text())["cycles"] == 20
    assert tty.getvalue() == ""


def test_fuzz_counts_its_cases(monkeypatch, capsys):
    tty = terminal(monkeypatch)
    assert main(["bench", "fuzz", "--cases", "5", "--honest-landmarks", "0"]) == 0
    assert json.loads(capsys.readouterr().out)["cases"] == 5
    assert counts(tty, "fuzz cases")[-1] == "5/5"
    assert "1/5" in counts(tty, "fuzz cases")


@pytest.mark.slow
def test_proto_counts_its_stages(monkeypatch, capsys):
    tty = terminal(monkeypatch)
    assert main(["bench", "proto", "--frames", "2000", "--repeats", "1", "--link-seconds", "0.5"]) == 0
    assert "decode_frames_per_s" in capsys.readouterr().out
    assert counts(tty, "protocol benchmarks") == ["1/3", "2/3", "3/3", "3/3"]


@pytest.mark.slow
def test_bus_counts_its_stages(monkeypatch, capsys):
    tty = terminal(monkeypatch)
    assert main(["bench", "bus", "--quick"]) == 0
    assert "pose_to_callback" in capsys.readouterr().out
    assert counts(tty, "bus benchmarks") == ["1/2", "2/2", "2/2"]


@pytest.mark.slow
def test_localization_counts_its_scenes(monkeypatch, tmp_path):
    tty = terminal(monkeypatch)
    args = ["bench", "localization", "--scenes", "fif_two_walls,fif_four_walls", "--policies", "forward",
            "--seeds", "1"]
    assert main(args) == 0
    assert counts(tty, "localization scenes")[-1] == "2/2"
