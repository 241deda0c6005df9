"""Bounded hand-off of raw payloads from Zenoh's callback threads to a decoding thread.

Zenoh's callbacks only check a payload's size and drop it into an :class:`Inbox`; a :class:`Decoder`
thread takes payloads out and decodes them, so a large or slow message never blocks Zenoh's threads and
never piles up: each topic holds at most ``capacity`` payloads and a new one evicts the oldest
(``capacity`` 1 is latest-wins). Evictions are reported to the caller, which counts them as ``superseded``:
a newer state replacing an undecoded one is normal under load, not a lost message.
"""

from __future__ import annotations

import logging
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class Inbox:
    """Per-topic bounded FIFO queues behind one condition variable; topics are served in insertion order of
    their first :meth:`add_topic` (earlier topics first when several hold payloads)."""

    def __init__(self) -> None:
        self._queues: dict[str, deque] = {}
        self._cond = threading.Condition()
        self._closed = False

    def add_topic(self, topic: str, capacity: int) -> None:
        """Declare ``topic`` with room for ``capacity`` ≥ 1 payloads."""
        if capacity < 1:
            raise ValueError(f"inbox capacity must be >= 1, got {capacity}")
        with self._cond:
            self._queues[topic] = deque(maxlen=capacity)

    def put(self, topic: str, item: Any) -> bool:
        """Queue ``item`` for ``topic``; False when that evicted the oldest queued item (or the inbox is closed)."""
        with self._cond:
            if self._closed:
                return False
            q = self._queues[topic]
            evicted = len(q) == q.maxlen
            q.append(item)
            self._cond.notify()
        return not evicted

    def get(self, timeout: float | None = None) -> tuple[str, Any] | None:
        """The next (topic, item), waiting up to ``timeout`` s; None on timeout or once closed."""
        with self._cond:
            while not self._closed:
                for topic, q in self._queues.items():
                    if q:
                        return topic, q.popleft()
                if not self._cond.wait(timeout):
                    return None
            return None

    def pending(self) -> int:
        """Number of queued items over all topics."""
        with self._cond:
            return sum(len(q) for q in self._queues.values())

    def close(self) -> None:
        """Drop everything queued and wake the waiting decoder (it then stops)."""
        with self._cond:
            self._closed = True
            for q in self._queues.values():
                q.clear()
            self._cond.notify_all()


class Decoder:
    """A daemon thread that hands each (topic, item) of an :class:`Inbox` to ``handle`` until closed."""

    def __init__(self, inbox: Inbox, handle: Callable[[str, Any], None], name: str) -> None:
        self.inbox = inbox
        self._handle = handle
        self._thread = threading.Thread(target=self._run, name=name, daemon=True)
        self._thread.start()

    def _run(self) -> None:
        while True:
            got = self.inbox.get()
            if got is None:
                return
            try:
                self._handle(*got)
            except Exception:  # the handler counts its own failures; this thread must survive anything
                log.exception("decoder %s: handler failed", self._thread.name)

    def close(self, timeout: float = 1.0) -> None:
        """Close the inbox and wait up to ``timeout`` s for a decode in progress to finish."""
        self.inbox.close()
        if self._thread is not threading.current_thread():
            self._thread.join(timeout)
