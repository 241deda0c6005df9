"""Progress of long work (map loading, occupancy grids, benchmarks) as one line on a terminal.

The line goes to stderr, rewritten in place, and only when stderr is a terminal: never in a pipe or a log
file, never under systemd (``JOURNAL_STREAM`` is set there) and never after :func:`silence` (the CLI calls it
for ``--json``, so machine-readable runs stay clean). Nothing is drawn for work that ends within ``delay``
seconds, and redraws are at most every ``interval`` seconds, so short calls cost a clock read per update.
"""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable, Iterable, Iterator
from typing import TextIO, TypeVar

T = TypeVar("T")

_silenced = False  # set by the CLI for machine-readable output; read by every Progress


def silence(quiet: bool = True) -> None:
    """Turn progress lines off (``quiet``) or back on for the rest of the process."""
    global _silenced
    _silenced = quiet


def shows_progress(stream: TextIO) -> bool:
    """Whether progress lines may be drawn on ``stream``: a terminal, not systemd's journal, not silenced."""
    if _silenced or os.environ.get("JOURNAL_STREAM"):
        return False
    isatty = getattr(stream, "isatty", None)
    try:
        return bool(isatty and isatty())
    except (ValueError, OSError):  # closed stream
        return False


def _amount(value: float, unit: str) -> str:
    if unit == "B":
        return f"{value / 1e6:.1f}"
    return f"{value:,.0f}" if value == int(value) else f"{value:,.1f}"


class Progress:
    """One task's progress: ``label: 42% 4.2/10.0 MB 3.1 s``, or ``label: 1,234 items 3.1 s`` without a total.

    Use as a context manager; :meth:`update` sets the amount done, :meth:`advance` adds to it. ``unit`` ``"B"``
    shows megabytes. ``clock`` [s] is injectable for tests.
    """

    def __init__(self, label: str, total: float | None = None, unit: str = "", stream: TextIO | None = None,
                 delay: float = 0.5, interval: float = 0.1, clock: Callable[[], float] = time.monotonic) -> None:
        self.label = label
        self.total = total if total is None or total > 0 else None
        self.unit = "MB" if unit == "B" else unit
        self._bytes = unit == "B"
        self.stream = sys.stderr if stream is None else stream
        self.enabled = shows_progress(self.stream)
        self.done = 0.0
        self._clock = clock
        self._start = clock()
        self._delay, self._interval = delay, interval
        self._last_draw: float | None = None
        self._width = 0

    def update(self, done: float) -> None:
        """Set the amount done (same unit as ``total``) and redraw when due."""
        self.done = done
        if not self.enabled:
            return
        now = self._clock()
        if now - self._start < self._delay:
            return
        if self._last_draw is not None and now - self._last_draw < self._interval:
            return
        self._draw(now)

    def advance(self, amount: float = 1) -> None:
        """Add ``amount`` to the amount done."""
        self.update(self.done + amount)

    def line(self, now: float | None = None) -> str:
        """The text of the progress line (without the carriage return)."""
        elapsed = (self._clock() if now is None else now) - self._start
        kind = "B" if self._bytes else ""
        unit = f" {self.unit}" if self.unit else ""
        done = _amount(self.done, kind)
        if self.total is not None:
            pct = min(100.0, 100.0 * self.done / self.total)
            return f"{self.label}: {pct:3.0f}% {done}/{_amount(self.total, kind)}{unit} {elapsed:.1f} s"
        return f"{self.label}: {done}{unit} {elapsed:.1f} s"

    def _draw(self, now: float) -> None:
        text = self.line(now)
        pad = max(0, self._width - len(text))
        try:
            self.stream.write("\r" + text + " " * pad)
            self.stream.flush()
        except (ValueError, OSError):  # the terminal went away: stop drawing
            self.enabled = False
            return
        self._width = len(text)
        self._last_draw = now

    def close(self) -> None:
        """Draw the final state and end the line (only if a line was drawn)."""
        if self.enabled and self._last_draw is not None:
            self._draw(self._clock())
            try:
                self.stream.write("\n")
                self.stream.flush()
            except (ValueError, OSError):
                pass
        self.enabled = False

    def __enter__(self) -> Progress:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def with_progress(items: Iterable[T], label: str, total: int | None = None, unit: str = "",
          stream: TextIO | None = None) -> Iterator[T]:
    """Iterate ``items`` with a progress line counting them (``total`` defaults to ``len(items)`` if known)."""
    if total is None and hasattr(items, "__len__"):
        total = len(items)  # type: ignore[arg-type]
    with Progress(label, total, unit, stream) as progress:
        for item in items:
            yield item
            progress.advance()
