"""Logging that never blocks the threads that log (the control loop, the planner, the bus, signal handling).

A log call only puts the record on a bounded queue (:data:`QUEUE_RECORDS`); when the queue is full the record is
dropped and counted (:attr:`LogQueue.dropped`, the status document's ``logging.dropped``). One listener thread
writes the queued records to the log stream (stderr, which is the journal under systemd) with ``os.write``: when
nobody reads that stream (a pipe nobody drains, a stalled journal) only the listener waits, holding no lock that a
logging thread, the signal handler or the interpreter's exit needs. When the stream drains again, the listener
reports how many records were dropped meanwhile.

When that stream is the journal (systemd's ``$JOURNAL_STREAM`` names it), every line starts with its syslog
priority as an sd-daemon prefix (``<3>`` error, ``<4>`` warning, ``<6>`` info, ``<7>`` debug: ``man sd-daemon``),
so ``journalctl -p warning`` filters them, and carries no timestamp: the journal stamps each line itself.
"""

from __future__ import annotations

import contextlib
import logging
import logging.handlers
import os
import queue
import sys
import threading
from typing import Any

from pivotd.daemon.systemd import is_journal_stream

#: records waiting for the listener; beyond this a record is dropped and counted
QUEUE_RECORDS = 10_000
FORMAT = "%(asctime)s %(levelname)s %(name)s: %(message)s"
#: sd-daemon priority of each logging level (a level between two takes the lower one's: ``priority``)
SYSLOG_PRIORITY = {logging.CRITICAL: 2, logging.ERROR: 3, logging.WARNING: 4, logging.INFO: 6, logging.DEBUG: 7}

log = logging.getLogger(__name__)

_STOP = object()


class _DroppingQueueHandler(logging.handlers.QueueHandler):
    """A QueueHandler whose ``enqueue`` never waits: a full queue drops the record and counts it."""

    def __init__(self, q: queue.Queue) -> None:
        super().__init__(q)
        self._drops_lock = threading.Lock()
        self.dropped = 0

    def enqueue(self, record: logging.LogRecord) -> None:
        try:
            self.queue.put_nowait(record)
        except queue.Full:
            with self._drops_lock:
                self.dropped += 1


def priority(levelno: int) -> int:
    """The syslog priority (0 emergency … 7 debug) of a logging level."""
    for level, prio in sorted(SYSLOG_PRIORITY.items(), reverse=True):
        if levelno >= level:
            return prio
    return 7


class JournalFormatter(logging.Formatter):
    """``fmt`` without its timestamp, each line (a traceback's too) prefixed with the record's ``<priority>``."""

    def __init__(self, fmt: str) -> None:
        super().__init__(fmt.replace("%(asctime)s ", "").replace("%(asctime)s", ""))

    def format(self, record: logging.LogRecord) -> str:
        prefix = f"<{priority(record.levelno)}>"
        return "\n".join(prefix + line for line in super().format(record).split("\n"))


class _FdHandler(logging.Handler):
    """Writes each formatted record as one line to a file descriptor with ``os.write``. Used by the listener thread
    only, so :meth:`handle` takes no handler lock: a write blocked on a full pipe must not hold the lock that
    ``logging.shutdown`` takes at exit."""

    def __init__(self, fd: int, fmt: str) -> None:
        super().__init__()
        self.fd = fd
        self.journal = is_journal_stream(fd)
        self.setFormatter(JournalFormatter(fmt) if self.journal else logging.Formatter(fmt))

    def handle(self, record: logging.LogRecord) -> bool:
        rv = self.filter(record)
        if rv:
            self.emit(record)
        return bool(rv)

    def emit(self, record: logging.LogRecord) -> None:
        with contextlib.suppress(Exception):  # nowhere to report a failing log stream: it is the report
            self.write((self.format(record) + "\n").encode("utf-8", "replace"))

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            try:
                n = os.write(self.fd, view)
            except InterruptedError:
                continue
            except OSError:  # the stream is gone (closed, EPIPE): drop silently
                return
            view = view[n:]

    def flush(self) -> None:  # os.write is unbuffered
        pass


class LogQueue:
    """The process's log path: root handler → bounded queue → listener thread → ``fd`` (default stderr)."""

    def __init__(self, fd: int | None = None, fmt: str = FORMAT, maxsize: int = QUEUE_RECORDS) -> None:
        self._queue: queue.Queue[Any] = queue.Queue(maxsize)
        self.handler = _DroppingQueueHandler(self._queue)
        self._out = _FdHandler(sys.stderr.fileno() if fd is None else fd, fmt)
        self._reported = 0
        self._thread = threading.Thread(target=self._run, name="pivotd-log", daemon=True)

    @property
    def dropped(self) -> int:
        """Records dropped because the queue was full (the log stream was not read fast enough)."""
        return self.handler.dropped

    def status(self) -> dict[str, int]:
        """The status document's ``logging`` block: records dropped, records waiting."""
        return {"dropped": self.dropped, "queued": self._queue.qsize()}

    def install(self, level: int | str | None = None) -> LogQueue:
        """Make this the root logger's only handler (``level``: the root level, default unchanged), route warnings
        and uncaught thread exceptions through it, and start the listener."""
        root = logging.getLogger()
        for h in list(root.handlers):
            root.removeHandler(h)
        root.addHandler(self.handler)
        if level is not None:
            root.setLevel(level)
        logging.captureWarnings(True)
        threading.excepthook = _log_thread_exception
        self.start()
        return self

    def start(self) -> None:
        """Start the listener thread (:meth:`install` does)."""
        self._thread.start()

    def _run(self) -> None:
        while True:
            record = self._queue.get()
            if record is _STOP:
                return
            self._out.handle(record)
            dropped = self.handler.dropped
            if dropped != self._reported and self._queue.empty():
                prefix = f"<{SYSLOG_PRIORITY[logging.WARNING]}>" if self._out.journal else ""
                self._out.write(f"{prefix}{dropped - self._reported} log records dropped: the log output was not read "
                                f"fast enough ({dropped} since start)\n".encode())
                self._reported = dropped

    def stop(self, timeout: float = 2.0) -> None:
        """Let the listener write what is queued, for at most ``timeout`` [s] (a stream nobody reads keeps the
        rest); logging goes on through the queue, unwritten."""
        if not self._thread.is_alive():
            return
        try:
            self._queue.put(_STOP, timeout=timeout)
        except queue.Full:
            return
        self._thread.join(timeout)


def _log_thread_exception(args: threading.ExceptHookArgs) -> None:
    """An exception that ended a thread, logged through the queue (the default hook writes to stderr directly)."""
    if args.exc_type is SystemExit:
        return
    name = args.thread.name if args.thread is not None else "?"
    logging.getLogger("pivotd").critical("thread %s ended by an uncaught exception", name,
                                         exc_info=(args.exc_type, args.exc_value, args.exc_traceback))


_installed: LogQueue | None = None


def install(level: int | str | None = None, fmt: str = FORMAT) -> LogQueue:
    """Install a :class:`LogQueue` on stderr for this process (once; later calls return it)."""
    global _installed
    if _installed is None:
        _installed = LogQueue(fmt=fmt).install(level)
    return _installed


def installed() -> LogQueue | None:
    """The process's :class:`LogQueue`, if :func:`install` ran."""
    return _installed
