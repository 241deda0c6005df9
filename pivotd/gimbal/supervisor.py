"""Connection supervision shared by the gimbal backends: one background thread that opens the device,
runs the backend's handshake, watches the link until it is lost, and reconnects with exponential backoff.

A backend subclasses :class:`SupervisedLink` and supplies the hooks ``_open`` (a connection handle or None),
``_handshake`` (UP, DOWN or INCOMPATIBLE), ``_monitor`` (returns when the link is lost or stopping), ``_close``
and ``_loss_reason``. Backends that talk through a port with a reader and a writer thread keep them in a
:class:`Connection`.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
from collections.abc import Callable, Iterable
from dataclasses import dataclass, field
from typing import Any

from pivotd.gimbal.device_clock import DeviceClock
from pivotd.gimbal.interface import GimbalState, LinkState

log = logging.getLogger(__name__)

TX_QUEUE = 64  # items waiting for the writer thread; beyond this they are dropped (port stalled), counted


@dataclass
class Connection:
    """One open port, its bounded outgoing queue and its reader/writer threads."""

    port: Any
    tx: queue.Queue = field(default_factory=lambda: queue.Queue(TX_QUEUE))
    closing: threading.Event = field(default_factory=threading.Event)
    error: str | None = None
    threads: list = field(default_factory=list)

    @property
    def alive(self) -> bool:
        return self.error is None and not self.closing.is_set()

    def start_threads(self, workers: Iterable[tuple[Callable[[Connection], None], str]]) -> None:
        """Start one daemon thread per ``(target, name)``; each target gets this connection."""
        for target, name in workers:
            t = threading.Thread(target=target, args=(self,), name=name, daemon=True)
            self.threads.append(t)
            t.start()

    def stop_threads(self) -> None:
        """Signal ``closing``, wake the writer (a None item) and join the threads; the port stays open."""
        self.closing.set()
        with contextlib.suppress(queue.Full):
            self.tx.put_nowait(None)
        for t in self.threads:
            t.join(timeout=2.0)


class SilenceClock:
    """How long the device has been silent *while the host ran*: the time since its last state, less the host's own
    stalls since then. A stall is a gap of the watching thread's loop longer than ``stall_s`` (the process stopped,
    starved of CPU): while the host does not run, the device's states wait unread in the port, so their absence is
    no sign of a lost link. Each stall is counted (``stalls``). ``clock``: monotonic [s]."""

    def __init__(self, stall_s: float, clock: Callable[[], float] = time.monotonic) -> None:
        self.stall_s = float(stall_s)
        self._clock = clock
        self.stalls = 0
        self._last_tick: float | None = None
        self._last_rx: float | None = None
        self._stalled = 0.0  # [s] host stalls since the last state

    def silent(self, last_rx: float) -> float:
        """Call once per loop of the watching thread with the receive time of the latest state [s of ``clock``];
        returns the silence that counts against the state timeout [s]."""
        now = self._clock()
        if last_rx != self._last_rx:
            self._last_rx, self._stalled = last_rx, 0.0
        if self._last_tick is not None:
            gap = now - self._last_tick
            if gap > self.stall_s:
                self.stalls += 1
                self._stalled += gap
        self._last_tick = now
        return max(0.0, now - last_rx - self._stalled)


class SupervisedLink:
    """Reconnect loop, link-state transitions and the shared counters (``reconnects``, ``link_losses``) of a
    gimbal backend; see the module docstring for the hooks. Thread-safe."""

    _thread_name = "gimbal-link"

    def __init__(self, name: str, reconnect_backoff_s: tuple, counters: Iterable[str]) -> None:
        """``name`` labels log lines (URL or port); ``reconnect_backoff_s`` = (first, max) delay between
        connection attempts [s]; ``counters`` names the backend's counters (starting at 0)."""
        self._link_name = name
        self._backoff = reconnect_backoff_s
        self._changed = threading.Condition()
        self._link_state = LinkState.STOPPED
        self._state: GimbalState | None = None
        self._last_error: str | None = None
        self._stopping = threading.Event()
        self._supervisor: threading.Thread | None = None
        self._want_enabled = True
        self._ever_up = False
        # host_stalls: stalls of this process seen while the link was up (not judged as a silent device)
        self._n: dict[str, int] = dict.fromkeys((*counters, "host_stalls"), 0)
        self._device_clock = DeviceClock()  # when each state was measured (reset on every connection)

    def _silence_while_running(self, clock: SilenceClock, last_rx: float) -> float:
        """The device's silence [s] that counts against the state timeout (:meth:`SilenceClock.silent`, called once per
        loop of ``_monitor``), counting the host's stalls it saw in ``host_stalls``."""
        stalls = clock.stalls
        silent = clock.silent(last_rx)
        self._n["host_stalls"] += clock.stalls - stalls
        return silent

    # ------------------------------------------------------------------ GimbalInterface
    @property
    def link_state(self) -> LinkState:
        """The connection state (see :class:`~pivotd.gimbal.interface.LinkState`)."""
        return self._link_state

    @property
    def state(self) -> GimbalState | None:
        """The latest state received, or None before the first one (kept while the link is down: check
        ``link_state`` and ``rx_time`` before trusting it)."""
        return self._state

    @property
    def last_error(self) -> str | None:
        """One-line description of the last connection/handshake problem."""
        return self._last_error

    def start(self) -> None:
        """Connect, handshake and keep reconnecting on a background thread; returns immediately."""
        if self._supervisor is not None and self._supervisor.is_alive():
            return
        self._stopping.clear()
        self._set_link_state(LinkState.CONNECTING)
        self._supervisor = threading.Thread(target=self._run, name=self._thread_name, daemon=True)
        self._supervisor.start()

    def stop(self, disable: bool = True) -> None:
        """Disable the gimbal (if ``disable`` and the link is up), close the connection, stop all threads."""
        if disable and self._link_state == LinkState.UP:
            self.set_enabled(False)
        self._stopping.set()
        self._interrupt()
        if self._supervisor is not None:
            self._supervisor.join(timeout=5.0)
            self._supervisor = None
        self._set_link_state(LinkState.STOPPED)

    def wait_up(self, timeout: float) -> bool:
        """Block until the link is up (True) or ``timeout`` seconds passed / it became incompatible (False)."""
        deadline = time.monotonic() + timeout
        with self._changed:
            while self._link_state != LinkState.UP:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or self._link_state in (LinkState.INCOMPATIBLE, LinkState.STOPPED):
                    return False
                self._changed.wait(remaining)
            return True

    def set_enabled(self, on: bool, timeout: float | None = None) -> bool:
        raise NotImplementedError

    # ------------------------------------------------------------------ backend hooks
    def _open(self) -> Any | None:
        """Open the device; a connection handle, or None (with ``_last_error`` set)."""
        raise NotImplementedError

    def _handshake(self, conn: Any) -> LinkState:
        """Bring the opened device up: UP, DOWN (retry later) or INCOMPATIBLE (give up)."""
        raise NotImplementedError

    def _monitor(self, conn: Any) -> None:
        """Return when the link is lost or ``_stopping`` is set."""
        raise NotImplementedError

    def _close(self, conn: Any) -> None:
        raise NotImplementedError

    def _loss_reason(self, conn: Any) -> str:
        """Why the link was lost, for the log."""
        return self._last_error or "closed"

    def _interrupt(self) -> None:
        """Wake the backend's threads after ``_stopping`` was set (default: nothing to wake)."""

    def _on_down(self) -> None:
        """Called each time the link goes down, before the backoff wait (default: nothing)."""

    # ------------------------------------------------------------------ internals
    def _set_link_state(self, value: LinkState) -> None:
        with self._changed:
            if self._link_state != value:
                log.info("gimbal link %s: %s", self._link_name, value)
            self._link_state = value
            self._changed.notify_all()

    def _enqueue(self, conn: Connection, item: Any) -> bool:
        """Queue ``item`` for the writer without blocking; False (counted as ``tx_overflow``) when full."""
        try:
            conn.tx.put_nowait(item)
            return True
        except queue.Full:
            self._n["tx_overflow"] += 1
            return False

    def _run(self) -> None:
        first, maximum = self._backoff
        delay = first
        while not self._stopping.is_set():
            if self._link_state != LinkState.DOWN:
                self._set_link_state(LinkState.CONNECTING)
            conn = self._open()
            if conn is not None:
                self._device_clock.reset()
                result = self._handshake(conn)
                if result is LinkState.UP:
                    delay = first
                    if self._ever_up:
                        self._n["reconnects"] += 1
                    self._ever_up = True
                    self._set_link_state(LinkState.UP)
                    self._monitor(conn)
                    if not self._stopping.is_set():
                        self._n["link_losses"] += 1
                        log.warning("gimbal link %s lost: %s", self._link_name, self._loss_reason(conn))
                self._close(conn)
                if result is LinkState.INCOMPATIBLE:
                    self._set_link_state(LinkState.INCOMPATIBLE)
                    return
            if self._stopping.is_set():
                return
            self._set_link_state(LinkState.DOWN)
            self._on_down()
            self._stopping.wait(delay)
            delay = min(maximum, delay * 2)
