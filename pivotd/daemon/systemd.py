"""systemd service notifications (sd_notify) without libsystemd.

:class:`Notifier` sends state strings as datagrams to the unix socket named by ``$NOTIFY_SOCKET`` (a path,
or ``@name`` for the abstract namespace). Without ``$NOTIFY_SOCKET`` (not started by systemd with
``Type=notify``) every call is a no-op returning False. Send failures are logged, never raised: a lost
notification must not take the daemon down.

Protocol as used by pivotd.service: READY=1 once the map is loaded and Zenoh is open; WATCHDOG=1 from
a healthy control loop at half of :func:`watchdog_interval`; RELOADING=1 (with MONOTONIC_USEC, required by
systemd ≥ 253 for ``Type=notify-reload`` and harmless before) at the start of a SIGHUP reload, followed
by READY=1 when it is done; STOPPING=1 when shutdown begins; STATUS=<text> at any time.
"""

from __future__ import annotations

import logging
import os
import socket
import time

log = logging.getLogger(__name__)


def _socket_address(value: str) -> str | bytes | None:
    """The AF_UNIX address for a NOTIFY_SOCKET value (abstract namespace for a leading '@')."""
    if not value:
        return None
    if value.startswith("@"):
        return b"\0" + value[1:].encode()
    if value.startswith("/"):
        return value
    log.warning("NOTIFY_SOCKET=%r is neither a path nor an abstract socket name; notifications disabled", value)
    return None


class Notifier:
    """sd_notify client bound to ``$NOTIFY_SOCKET`` (or an explicit ``address`` for tests and tools)."""

    def __init__(self, address: str | None = None) -> None:
        raw = os.environ.get("NOTIFY_SOCKET", "") if address is None else address
        self._address = _socket_address(raw)
        self._sock: socket.socket | None = None
        self._failures = 0

    @property
    def enabled(self) -> bool:
        """True when notifications go to a socket (running under systemd with Type=notify)."""
        return self._address is not None

    def notify(self, message: str) -> bool:
        """Send one raw notification (``KEY=VALUE`` lines); True when it was delivered to the socket."""
        if self._address is None:
            return False
        try:
            if self._sock is None:
                self._sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM | socket.SOCK_CLOEXEC)
            self._sock.sendto(message.encode(), self._address)
        except OSError as exc:
            self._failures += 1
            if self._failures == 1 or self._failures % 100 == 0:
                log.warning("sd_notify failed (%d so far): %s", self._failures, exc)
            return False
        return True

    def ready(self, status: str | None = None) -> bool:
        """Startup (or a reload) finished: READY=1, with an optional STATUS."""
        return self.notify("READY=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def watchdog(self) -> bool:
        """Keep-alive ping: WATCHDOG=1."""
        return self.notify("WATCHDOG=1")

    def stopping(self, status: str | None = None) -> bool:
        """Shutdown began: STOPPING=1."""
        return self.notify("STOPPING=1" + (f"\nSTATUS={_one_line(status)}" if status else ""))

    def reloading(self) -> bool:
        """Reload began: RELOADING=1 with MONOTONIC_USEC (CLOCK_MONOTONIC, µs). Send :meth:`ready` when done."""
        usec = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
        return self.notify(f"RELOADING=1\nMONOTONIC_USEC={usec}")

    def status(self, text: str) -> bool:
        """Free-form one-line status shown by ``systemctl status``: STATUS=<text>."""
        return self.notify(f"STATUS={_one_line(text)}")

    def close(self) -> None:
        if self._sock is not None:
            self._sock.close()
            self._sock = None

    def __enter__(self) -> Notifier:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _one_line(text: str) -> str:
    return " ".join(str(text).split())


def watchdog_interval() -> float | None:
    """The service watchdog timeout [s] from ``$WATCHDOG_USEC``, or None when there is no watchdog for us.

    Like sd_watchdog_enabled(): ``$WATCHDOG_PID``, when set, must be this process. Ping at least twice
    per interval (every ``interval / 2``).
    """
    usec = os.environ.get("WATCHDOG_USEC", "")
    if not usec:
        return None
    pid = os.environ.get("WATCHDOG_PID", "")
    if pid:
        try:
            if int(pid) != os.getpid():
                return None
        except ValueError:
            log.warning("ignoring malformed WATCHDOG_PID=%r", pid)
            return None
    try:
        value = int(usec)
    except ValueError:
        log.warning("ignoring malformed WATCHDOG_USEC=%r", usec)
        return None
    if value <= 0:
        return None
    return value / 1e6


def is_journal_stream(fd: int) -> bool:
    """Whether ``fd`` is the journal's stream that systemd connected (``$JOURNAL_STREAM`` is ``device:inode`` of it,
    as sd_journal_stream_fd documents): its lines may then carry ``<N>`` priority prefixes (``man sd-daemon``)."""
    value = os.environ.get("JOURNAL_STREAM", "")
    dev, _, ino = value.partition(":")
    try:
        st = os.fstat(fd)
        return bool(ino) and (int(dev), int(ino)) == (st.st_dev, st.st_ino)
    except (OSError, ValueError):
        return False
