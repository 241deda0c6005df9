"""A wake-up flag that a signal handler may set: a self-pipe instead of a lock.

A Python signal handler runs in the main thread between two bytecodes of whatever it interrupted, and a second
signal can interrupt the handler itself. ``threading.Event.set`` takes a lock: a handler interrupted while it
holds that lock, by a handler that asks for the same lock, deadlocks the main thread (a storm of SIGHUPs did,
ending in a RecursionError). Writing a byte to a non-blocking pipe takes no lock and cannot block.
"""

from __future__ import annotations

import contextlib
import os
import select


class Wakeup:
    """``set()`` from anywhere; ``wait(timeout)`` and ``clear()`` from one thread. A signal handler writes a byte to
    :attr:`write_fd` itself (``os.write`` in a ``try``): a Python call in a handler is one more place where the next
    signal can interrupt it."""

    def __init__(self) -> None:
        self._r, self._w = os.pipe()
        os.set_blocking(self._r, False)
        os.set_blocking(self._w, False)

    @property
    def write_fd(self) -> int:
        return self._w

    def set(self) -> None:
        """Wake :meth:`wait` (and every later one until :meth:`clear`)."""
        with contextlib.suppress(BlockingIOError, OSError):  # full: already set; closed: shutting down
            os.write(self._w, b"\0")

    def wait(self, timeout: float) -> bool:
        """Block up to ``timeout`` [s] until set; True if set."""
        try:
            return bool(select.select([self._r], [], [], max(0.0, timeout))[0])
        except (OSError, ValueError):  # closed
            return True

    def clear(self) -> None:
        with contextlib.suppress(BlockingIOError, OSError):
            while os.read(self._r, 4096):
                pass

    def close(self) -> None:
        for fd in (self._r, self._w):
            with contextlib.suppress(OSError):
                os.close(fd)


class StopFlag:
    """A flag that is set once and never cleared, which a signal handler may set (SIGTERM): ``set()`` assigns a
    bool and writes one byte to a self-pipe, taking no lock, so a handler that interrupted a thread inside
    ``wait`` or another handler cannot deadlock on it. Any number of threads may ``wait``: once set, the pipe stays
    readable for all of them. The same ``is_set`` / ``wait`` / ``set`` calls as ``threading.Event``."""

    def __init__(self) -> None:
        self._flag = False
        self._pipe = Wakeup()

    def set(self) -> None:
        self._flag = True
        self._pipe.set()

    def is_set(self) -> bool:
        return self._flag

    def wait(self, timeout: float | None = None) -> bool:
        """Block up to ``timeout`` [s] (None: until set); True once set."""
        if self._flag:
            return True
        self._pipe.wait(1e9 if timeout is None else timeout)
        return self._flag
