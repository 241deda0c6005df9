"""The status document's ``last_error``: the latest error of each source, when it happened, and whether the
condition that caused it has cleared since."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, replace
from typing import Any


@dataclass(frozen=True)
class ErrorRecord:
    """One error: its one-line ``message``, its ``source`` (the text before the first colon: ``planner``,
    ``control``, ``reload`` …), when it happened and when its condition cleared (wall clock [s], None: not yet)."""

    message: str
    source: str
    time: float
    resolved_time: float | None = None


class LastErrors:
    """The latest error per source; thread-safe. :meth:`set` records one, :meth:`resolve` marks a source's error
    resolved once that source works again (a replan, a control tick, a reload succeeded)."""

    def __init__(self, clock: Callable[[], float] = time.time) -> None:
        self._clock = clock
        self._by_source: dict[str, ErrorRecord] = {}
        self._lock = threading.Lock()

    def set(self, message: str) -> None:
        """Record ``message`` (``"source: text"``; without a colon the source is ``daemon``); empty: ignored."""
        if not message:
            return
        source = message.split(":", 1)[0].strip() if ":" in message else "daemon"
        with self._lock:
            self._by_source[source] = ErrorRecord(message, source, self._clock())

    def resolve(self, source: str) -> None:
        """Mark ``source``'s error resolved (no-op if it has none or it is resolved already)."""
        rec = self._by_source.get(source)
        if rec is None or rec.resolved_time is not None:
            return
        with self._lock:
            rec = self._by_source.get(source)
            if rec is not None and rec.resolved_time is None:
                self._by_source[source] = replace(rec, resolved_time=self._clock())

    @property
    def current(self) -> ErrorRecord | None:
        """The newest unresolved error, else the newest resolved one, else None."""
        with self._lock:
            records = list(self._by_source.values())
        open_ = [r for r in records if r.resolved_time is None]
        pool = open_ or records
        return max(pool, key=lambda r: r.time) if pool else None

    @property
    def message(self) -> str:
        """The :attr:`current` error's message ("" without one)."""
        rec = self.current
        return "" if rec is None else rec.message

    def status(self) -> dict[str, Any] | None:
        """``{"message", "source", "time", "resolved_time"}`` of :attr:`current` (times: Unix [s]), or None."""
        rec = self.current
        if rec is None:
            return None
        return {"message": rec.message, "source": rec.source, "time": round(rec.time, 3),
                "resolved_time": None if rec.resolved_time is None else round(rec.resolved_time, 3)}
