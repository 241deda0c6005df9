"""Progress lines: drawn on a terminal only, after a delay, throttled; silent in pipes, under systemd, for --json.

A fake terminal (a StringIO that says it is a TTY) and a fake clock make every case exact.
"""

from __future__ import annotations

import io

import numpy as np
import pytest

from pivotd import progress
from pivotd.maps.formats import read_numeric_text
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.progress import Progress, shows_progress, with_progress


class FakeTTY(io.StringIO):
    def isatty(self) -> bool:
        return True


class Clock:
    def __init__(self) -> None:
        self.now = 100.0

    def __call__(self) -> float:
        return self.now


@pytest.fixture(autouse=True)
def not_silenced(monkeypatch):
    monkeypatch.delenv("JOURNAL_STREAM", raising=False)
    progress.silence(False)
    yield
    progress.silence(False)


def frames(text: str) -> list[str]:
    """The successive states of a line rewritten with carriage returns (padding stripped)."""
    return [f.rstrip() for f in text.replace("\n", "").split("\r") if f]


def test_lines_appear_after_the_delay_and_at_most_every_interval():
    tty, clock = FakeTTY(), Clock()
    with Progress("reading map.txt", 4e6, "B", stream=tty, delay=0.5, interval=0.1, clock=clock) as p:
        p.update(1e6)  # t = 0: within the delay, nothing drawn
        assert tty.getvalue() == ""
        clock.now += 0.6
        p.update(2e6)
        clock.now += 0.05
        p.update(2.5e6)  # 50 ms after the last draw: throttled
        clock.now += 0.06
        p.update(3e6)
    out = tty.getvalue()
    assert frames(out) == ["reading map.txt:  50% 2.0/4.0 MB 0.6 s", "reading map.txt:  75% 3.0/4.0 MB 0.7 s",
                           "reading map.txt:  75% 3.0/4.0 MB 0.7 s"]
    assert out.endswith("\n") and out.count("\n") == 1


def test_short_work_draws_nothing_and_a_shorter_line_erases_the_longer():
    tty, clock = FakeTTY(), Clock()
    with Progress("x", None, "items", stream=tty, clock=clock) as p:
        p.update(5)
    assert tty.getvalue() == ""  # ended within the delay
    with Progress("x", None, "items", stream=tty, delay=0, interval=0, clock=clock) as p:
        p.update(123456)
        p.update(7)
    parts = tty.getvalue().split("\r")[1:]
    assert parts[0] == "x: 123,456 items 0.0 s"
    assert parts[1] == "x: 7 items 0.0 s" + " " * (len(parts[0]) - len(parts[1].rstrip()))


def test_no_lines_in_a_pipe_under_systemd_or_when_silenced(monkeypatch):
    assert not shows_progress(io.StringIO())
    assert shows_progress(FakeTTY())
    monkeypatch.setenv("JOURNAL_STREAM", "8:12345")
    assert not shows_progress(FakeTTY())
    monkeypatch.delenv("JOURNAL_STREAM")
    progress.silence()
    tty = FakeTTY()
    with Progress("x", 10, stream=tty, delay=0, interval=0) as p:
        p.update(5)
    assert tty.getvalue() == ""


def test_with_progress_counts_items():
    tty = FakeTTY()
    items = list(with_progress(range(3), "scenes", stream=tty))
    assert items == [0, 1, 2]


def test_map_reading_and_occupancy_grid_report_progress(tmp_path, monkeypatch):
    tty = FakeTTY()
    monkeypatch.setattr("sys.stderr", tty)
    monkeypatch.setattr(Progress, "__init__", _eager(Progress.__init__))
    rng = np.random.default_rng(0)
    pts = rng.uniform(-5, 5, (30_000, 3))
    path = tmp_path / "map.txt"
    np.savetxt(path, pts, fmt="%.4f")
    got = read_numeric_text(path, (3, 4), "landmark")
    assert got.shape == (30_000, 3)
    size = path.stat().st_size
    read_frames = [f for f in frames(tty.getvalue()) if f.startswith("reading map.txt:")]
    assert read_frames and read_frames[-1].startswith(f"reading map.txt: 100% {size / 1e6:.1f}/{size / 1e6:.1f} MB")
    grid = OccupancyGrid.from_points(pts, 0.5)
    grid_frames = [f for f in frames(tty.getvalue()) if f.startswith("occupancy grid:")]
    assert grid_frames[-1].startswith("occupancy grid: 100% 30,000/30,000 points")
    assert grid.is_occupied(pts[:100]).all()


def _eager(init):
    """Progress.__init__ with no delay and no throttling (so a fast test sees every line)."""

    def wrapped(self, *args, **kwargs):
        kwargs.update(delay=0.0, interval=0.0)
        init(self, *args, **kwargs)

    return wrapped


@pytest.mark.parametrize("as_json", [False, True])
def test_json_runs_stay_quiet_on_a_terminal(tmp_path, monkeypatch, capsys, as_json):
    """`pivotd plan` on a terminal shows the map being read; with --json it prints only the JSON object."""
    from pivotd.cli import main

    rng = np.random.default_rng(1)
    np.savetxt(tmp_path / "map.txt", rng.uniform(-5, 5, (2000, 3)), fmt="%.4f")
    np.savetxt(tmp_path / "path.txt", np.column_stack([np.linspace(0, 3, 4), np.zeros(4), np.zeros(4)]))
    tty = FakeTTY()
    monkeypatch.setattr("sys.stderr", tty)
    monkeypatch.setattr(Progress, "__init__", _eager(Progress.__init__))
    args = ["plan", "--map", str(tmp_path / "map.txt"), "--path", str(tmp_path / "path.txt")]
    assert main([*args, "--json"] if as_json else args) == 0
    drawn = [f for f in frames(tty.getvalue()) if f.startswith("reading map.txt:")]
    if as_json:
        assert drawn == [] and capsys.readouterr().out.lstrip().startswith("{")
    else:
        assert drawn and drawn[-1].startswith("reading map.txt: 100%")


def terminal(monkeypatch) -> FakeTTY:
    """stderr as a fake terminal (set in the test body: pytest's capture replaces stderr after fixtures)."""
    out = FakeTTY()
    monkeypatch.setattr("sys.stderr", out)
    monkeypatch.setattr(Progress, "__init__", _eager(Progress.__init__))
    return out
