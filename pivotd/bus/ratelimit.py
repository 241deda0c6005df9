"""Rate-limited logging for per-message problems (bad input must not flood the journal)."""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable


class RateLimitedLog:
    """Logs at most one message per key every ``interval`` seconds [s of ``clock``], reporting how many were
    suppressed."""

    def __init__(self, logger: logging.Logger, interval: float = 5.0,
                 clock: Callable[[], float] = time.monotonic) -> None:
        self.logger = logger
        self.clock = clock
        self.interval = float(interval)
        self._last: dict[str, float] = {}
        self._suppressed: dict[str, int] = {}
        self._lock = threading.Lock()

    def _admit(self, key: str) -> str | None:
        """The suffix to log with when ``key`` may log now, None while it is rate-limited."""
        now = self.clock()
        with self._lock:
            last = self._last.get(key)
            if last is not None and now - last < self.interval:
                self._suppressed[key] = self._suppressed.get(key, 0) + 1
                return None
            self._last[key] = now
            skipped = self._suppressed.pop(key, 0)
        return f" ({skipped} similar messages suppressed)" if skipped else ""

    def warning(self, key: str, message: str) -> bool:
        """Log ``message`` under ``key`` unless one was logged less than ``interval`` s ago; True if logged."""
        suffix = self._admit(key)
        if suffix is None:
            return False
        self.logger.warning("%s%s", message, suffix)
        return True

    def exception(self, key: str, message: str) -> bool:
        """Like :meth:`warning`, at ERROR with the traceback of the exception being handled."""
        suffix = self._admit(key)
        if suffix is None:
            return False
        self.logger.error("%s%s", message, suffix, exc_info=True)
        return True
