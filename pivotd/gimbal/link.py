"""Host side of the gimbal serial link: handshake, setpoints, STATE/ACK reader, reconnect loop.

``GimbalLink(url, config).start()`` opens any pyserial URL (``/dev/ttyUSB0``, ``socket://host:port``,
``mock://``, ``spy://…``) on a background thread and runs the handshake HELLO → IDENTITY (refusing an
incompatible protocol version) → CONFIG (the ACK must carry the CRC-32 of the CONFIG payload) →
ENABLE. When the port is lost (unplug, EOF, I/O error, or no STATE for ``state_timeout_s``) the link
goes ``down``, reconnects with exponential backoff and re-runs the whole handshake by itself.

Setpoints are only sent while the device answers: after a few of its state periods without a STATE
(:meth:`GimbalLink.silence_s`) :meth:`GimbalLink.send_setpoint` sends nothing and returns None, long before the
link is declared lost, so a stalled device does not find a queue of setpoints when it resumes. Each version-2
SETPOINT echoes the device clock of the newest STATE and a validity (:meth:`GimbalLink.setpoint_max_age_s`); the
device drops it once older than that on its own clock. A version-1 device (no validity) is driven with the
version-1 SETPOINT and the silence rule alone, with one warning.

Threads per open port: a reader (decodes STATE/ACK/IDENTITY, keeps the latest state) and a writer
(drains a bounded queue, so :meth:`GimbalLink.send_setpoint` never blocks the caller).
Importing this module registers the ``mock://`` URL scheme with pyserial.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
import zlib
from collections.abc import Callable
from dataclasses import dataclass

import serial

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    NACK_NAMES,
    NACK_NOT_CONFIGURED,
    PROTOCOL_VERSION,
    SUPPORTED_VERSIONS,
    Ack,
    ClearFault,
    Config,
    Enable,
    Heartbeat,
    Hello,
    Identity,
    Message,
    Setpoint,
    SetpointV1,
    State,
)
from pivotd.firmware_proto.urlhandler import register as _register_mock_url
from pivotd.gimbal.interface import GimbalState, LinkState
from pivotd.gimbal.silence import SilenceRule
from pivotd.gimbal.supervisor import Connection, SilenceClock, SupervisedLink

_register_mock_url()

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class LinkConfig:
    """The CONFIG message sent at every handshake (joint limits [rad], rate limits [rad/s], acceleration
    limits [rad/s²], device watchdog [ms]) and the link's timing."""

    limits: Config
    state_timeout_s: float = 0.5  # no STATE for this long -> link down, reconnect
    ack_timeout_s: float = 0.2  # per attempt
    ack_retries: int = 5  # extra attempts after the first
    reconnect_backoff_s: tuple = (0.1, 2.0)  # (first, max) delay between connection attempts
    silence_periods: float = 5.0  # no STATE for this many device state periods -> no setpoints are sent
    silence_min_s: float = 0.1  # [s] floor of that bound (host scheduling jitter)
    setpoint_transit_s: float = 0.1  # [s] allowed for a STATE's and a SETPOINT's transit, in the validity


class _Pending:
    """An outstanding request waiting for its ACK (or IDENTITY)."""

    def __init__(self) -> None:
        self.event = threading.Event()
        self.reply: Message | None = None


class GimbalLink(SupervisedLink):
    """Serial link to one gimbal speaking pivotd's protocol (see the module docstring); a
    :class:`~pivotd.gimbal.interface.GimbalInterface`. Thread-safe."""

    _thread_name = "gimbal-link"

    def __init__(self, url: str, config: LinkConfig, baudrate: int = 115200) -> None:
        super().__init__(url, config.reconnect_backoff_s,
                         ("frames_sent", "frames_received", "setpoints_sent", "retries", "reconnects", "link_losses",
                          "ack_failures", "tx_overflow", "rtt_samples", "setpoints_withheld", "heartbeats_withheld",
                          "silences"))
        self.url = url
        self.config = config
        self.baudrate = baudrate
        self._cfg_msg = config.limits
        self._cfg_msg.pack()  # fail early on limits that do not fit the wire format
        self._seq_lock = threading.Lock()
        self._identity: Identity | None = None
        self._conn: Connection | None = None
        self._seq = 0
        self._pending: dict[tuple[int, int], _Pending] = {}
        self._hello: _Pending | None = None
        self._sent_at: list[float | None] = [None] * 256
        self._decoder = codec.StreamDecoder()
        self._last_state_rx = 0.0
        self._opened_at = 0.0  # when the current connection was opened (monotonic) [s]
        self._wire_version = PROTOCOL_VERSION  # the version the device spoke at the last handshake
        self._warned_version: int | None = None
        # the state period from consecutive STATE stamps on the device's clock (reader thread), and the silence
        self._silence = SilenceRule(config.silence_periods, config.silence_min_s, config.state_timeout_s, url,
                                    "STATE", log)
        self._rtt_last = self._rtt_sum = self._rtt_max = 0.0
        self._listeners: list[Callable[[GimbalState], None]] = []

    # ------------------------------------------------------------------ public API
    @property
    def identity(self) -> Identity | None:
        """The device's IDENTITY from the last handshake."""
        return self._identity

    def wait_state(self, predicate: Callable[[GimbalState], bool], timeout: float) -> GimbalState | None:
        """Block until a received STATE satisfies ``predicate(state)``; return it, or None on timeout.
        ``predicate`` is called once per new STATE on the caller's thread, without any lock held."""
        deadline = time.monotonic() + timeout
        checked: GimbalState | None = None
        while True:
            st = self._state
            if st is not None and st is not checked:
                checked = st
                if predicate(st):
                    return st
            remaining = deadline - time.monotonic()
            if remaining <= 0:
                return None
            with self._changed:
                if self._state is checked:
                    self._changed.wait(min(remaining, 0.1))

    def subscribe(self, callback: Callable[[GimbalState], None]) -> None:
        """Call ``callback(state)`` on the reader thread for every STATE received (keep it short)."""
        self._listeners.append(callback)

    @property
    def protocol_version(self) -> int:
        """The protocol version the device spoke at the last handshake (PROTOCOL_VERSION before one)."""
        return self._wire_version

    def silence_s(self) -> float:
        """How long [s] without a STATE the device counts as silent: ``silence_periods`` of its state period (the
        smallest recent interval between STATEs on its clock), at least ``silence_min_s``, at most
        ``state_timeout_s`` (also before the period is known)."""
        return self._silence.silence_s()

    def setpoint_max_age_s(self) -> float:
        """Validity [s] sent with each version-2 SETPOINT: a setpoint is sent only while the newest STATE is at most
        :meth:`silence_s` old, plus ``setpoint_transit_s`` for that STATE's and the SETPOINT's transit."""
        return self.silence_s() + self.config.setpoint_transit_s

    def _silent(self, now: float, counter: str) -> bool:
        """Whether the device went silent (no STATE within :meth:`silence_s`); counts the withheld frame under
        ``counter`` and logs each silence once."""
        return self._silence.silent(now, self._last_state_rx, self._state is not None, self._n, counter)

    def send_setpoint(self, pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> int | None:
        """Queue a SETPOINT (pan/tilt [rad], feed-forward rates [rad/s]); return its seq, or None if the link
        is not up or the device is silent (counted as ``setpoints_withheld``; see :meth:`silence_s`). Never
        blocks; raises ValueError on non-finite values."""
        conn = self._conn
        if self._link_state != LinkState.UP or conn is None:
            return None
        now = time.monotonic()
        state = self._state
        if state is None or self._silent(now, "setpoints_withheld"):
            # A withheld setpoint still takes its seq, as a lost frame would: the gap shows the device (and its log)
            # that the stream broke here, and the control loop restarts it from a measured state.
            self._next_seq()
            return None
        seq = self._next_seq()
        host_us = int(now * 1e6) & 0xFFFFFFFF
        if self._wire_version == 1:
            msg: Message = SetpointV1(pan, tilt, pan_rate, tilt_rate, host_us)
        else:
            max_age_ms = min(0xFFFF, round(self.setpoint_max_age_s() * 1000.0))
            msg = Setpoint(pan, tilt, pan_rate, tilt_rate, host_us, state.device_time_us, max_age_ms)
        frame = codec.encode(msg, seq, self._wire_version)
        self._sent_at[seq] = now
        if not self._enqueue(conn, frame):
            return None
        self._n["setpoints_sent"] += 1
        return seq

    def send_heartbeat(self) -> None:
        """Queue a HEARTBEAT (feeds the device watchdog without moving); no-op if the link is not up or the device is
        silent (counted as ``heartbeats_withheld``: its watchdog then holds it, as for a lost link)."""
        conn = self._conn
        if (self._link_state == LinkState.UP and conn is not None
                and not self._silent(time.monotonic(), "heartbeats_withheld")):
            self._enqueue(conn, codec.encode(Heartbeat(), self._next_seq(), self._wire_version))

    def set_enabled(self, on: bool, timeout: float | None = None) -> bool:
        """ENABLE/disable the gimbal; True once ACKed with status ok. Remembered for future handshakes.
        ``timeout`` bounds the total wait [s] (default: ack_timeout_s × (ack_retries + 1))."""
        self._want_enabled = bool(on)
        if self._link_state != LinkState.UP:
            return False
        ack = self._request(Enable(1 if on else 0), timeout)
        if ack is not None and ack.status == NACK_NOT_CONFIGURED and self._conn is not None:
            # The device forgot its CONFIG: it rebooted behind a port that stayed open. Drop the connection
            # so the supervisor runs the whole handshake (HELLO, CONFIG, ENABLE) again.
            self._conn.error = "the gimbal lost its configuration (rebooted?): handshaking again"
            log.warning("gimbal at %s: %s", self.url, self._conn.error)
        return ack is not None and ack.status == 0

    def clear_fault(self, timeout: float | None = None) -> bool:
        """CLEAR_FAULT; True once ACKed with status ok."""
        if self._link_state != LinkState.UP:
            return False
        ack = self._request(ClearFault(), timeout)
        return ack is not None and ack.status == 0

    def counters(self) -> dict[str, int | float]:
        """Frames sent/received, decode drops by reason, retries, reconnects, RTT (setpoint → echoing STATE) [s]."""
        out: dict[str, int | float] = dict(self._n)
        drops = self._decoder.drops
        out["crc_errors"] = drops["crc"]
        out["decode_drops"] = self._decoder.dropped
        out.update({f"drop_{k}": v for k, v in drops.items()})
        n = self._n["rtt_samples"]
        out["rtt_last_s"] = self._rtt_last
        out["rtt_mean_s"] = self._rtt_sum / n if n else 0.0
        out["rtt_max_s"] = self._rtt_max
        return out

    # ------------------------------------------------------------------ internals
    def _next_seq(self) -> int:
        with self._seq_lock:
            seq = self._seq
            self._seq = (seq + 1) & 0xFF
        return seq

    def _open(self) -> Connection | None:
        try:
            port = serial.serial_for_url(self.url, baudrate=self.baudrate, timeout=0.05, write_timeout=0.5)
        except (serial.SerialException, OSError, ValueError) as exc:
            self._last_error = f"cannot open gimbal port {self.url}: {exc}"
            log.debug(self._last_error)
            return None
        conn = Connection(port)
        conn.tx.put_nowait(b"\x00")  # ends any partial frame the device still holds from before
        self._decoder.reset()
        self._opened_at = time.monotonic()
        self._silence.reset()
        self._conn = conn
        conn.start_threads(((self._reader, "gimbal-rx"), (self._writer, "gimbal-tx")))
        return conn

    def _close(self, conn: Connection) -> None:
        conn.stop_threads()
        with contextlib.suppress(serial.SerialException, OSError):
            conn.port.close()
        if self._conn is conn:
            self._conn = None

    def _monitor(self, conn: Connection) -> None:
        self._last_state_rx = time.monotonic()
        silence = SilenceClock(self.config.state_timeout_s / 2)  # a stall of this process is not a silent device
        while not self._stopping.is_set() and conn.alive:
            if self._silence_while_running(silence, self._last_state_rx) > self.config.state_timeout_s:
                conn.error = f"no STATE for {self.config.state_timeout_s} s"
                break
            self._stopping.wait(0.02)
        self._last_error = conn.error

    def _loss_reason(self, conn: Connection) -> str:
        return conn.error or "closed"

    def _handshake(self, conn: Connection) -> LinkState:
        """HELLO → IDENTITY → CONFIG → (ENABLE); returns the resulting LinkState (UP, DOWN or INCOMPATIBLE)."""
        ident = self._request_identity(conn)
        if ident is None:
            self._last_error = f"gimbal at {self.url} did not answer HELLO"
            return LinkState.DOWN
        self._identity = ident
        if ident.version not in SUPPORTED_VERSIONS:
            versions = " and ".join(str(v) for v in SUPPORTED_VERSIONS)
            self._last_error = (f"gimbal at {self.url} speaks protocol version {ident.version}, this host speaks "
                                f"versions {versions}: refusing to drive it")
            log.error(self._last_error)
            return LinkState.INCOMPATIBLE
        self._wire_version = self._decoder.version = ident.version
        if ident.version != PROTOCOL_VERSION and self._warned_version != ident.version:
            self._warned_version = ident.version
            log.warning("gimbal at %s speaks protocol version %d: its setpoints carry no validity, so a late one is "
                        "still executed; relying on the host sending none while the device is silent", self.url,
                        ident.version)
        if not self._wait_first_state(conn):
            self._last_error = f"gimbal at {self.url} sent no STATE within {self.config.state_timeout_s} s"
            return LinkState.DOWN
        expected_crc = zlib.crc32(self._cfg_msg.pack())
        ack = self._request(self._cfg_msg, None, conn, expect_value=expected_crc)
        if ack is None:
            self._last_error = f"gimbal at {self.url} did not acknowledge CONFIG with the right CRC"
            return LinkState.DOWN
        if ack.status != 0:
            self._last_error = (f"gimbal at {self.url} rejected CONFIG: {NACK_NAMES.get(ack.status, ack.status)} "
                                f"(limits {self._cfg_msg})")
            log.error(self._last_error)
            return LinkState.INCOMPATIBLE
        if self._want_enabled:
            ack = self._request(Enable(1), None, conn)
            if ack is None:
                self._last_error = f"gimbal at {self.url} did not acknowledge ENABLE"
                return LinkState.DOWN
            if ack.status != 0:
                log.warning("gimbal at %s refused ENABLE: %s (faults 0x%04x); link up, disabled", self.url,
                            NACK_NAMES.get(ack.status, ack.status), self._state.faults if self._state else 0)
        log.info("gimbal at %s: protocol v%d, firmware %d.%d.%d, serial %08x", self.url, ident.version,
                 ident.fw_major, ident.fw_minor, ident.fw_patch, ident.serial)
        return LinkState.UP

    def _wait_first_state(self, conn: Connection) -> bool:
        """Wait (up to ``state_timeout_s``) for a STATE received on this connection: the link is up only once
        states arrive, and setpoints echo a state of this device's clock."""
        deadline = time.monotonic() + self.config.state_timeout_s
        with self._changed:
            while self._last_state_rx < self._opened_at:
                remaining = deadline - time.monotonic()
                if remaining <= 0 or not conn.alive or self._stopping.is_set():
                    return False
                self._changed.wait(min(remaining, 0.05))
        return True

    def _attempts(self, timeout: float | None) -> tuple[int, float]:
        per = self.config.ack_timeout_s
        n = self.config.ack_retries + 1 if timeout is None else max(1, int(timeout / per + 0.999))
        return n, per

    def _request_identity(self, conn: Connection) -> Identity | None:
        pending = _Pending()
        self._hello = pending
        try:
            n, per = self._attempts(None)
            for attempt in range(n):
                if attempt:
                    self._n["retries"] += 1
                self._enqueue(conn, codec.encode(Hello(PROTOCOL_VERSION), self._next_seq()))  # versionless
                if pending.event.wait(per):
                    return pending.reply  # type: ignore[return-value]
                if not conn.alive or self._stopping.is_set():
                    return None
            return None
        finally:
            self._hello = None

    def _request(self, msg: Message, timeout: float | None, conn: Connection | None = None,
                 expect_value: int | None = None) -> Ack | None:
        """Send ``msg`` and wait for its ACK, resending the same frame (same seq) on timeout."""
        conn = conn or self._conn
        if conn is None:
            return None
        seq = self._next_seq()
        key = (seq, msg.TYPE)
        pending = _Pending()
        self._pending[key] = pending
        frame = codec.encode(msg, seq, self._wire_version)
        try:
            n, per = self._attempts(timeout)
            for attempt in range(n):
                if attempt:
                    self._n["retries"] += 1
                self._enqueue(conn, frame)
                if pending.event.wait(per):
                    ack = pending.reply
                    assert isinstance(ack, Ack)
                    if expect_value is None or ack.status != 0 or ack.value == expect_value:
                        return ack
                    log.warning("%s ACK carries CRC %08x, expected %08x: resending", msg.NAME, ack.value,
                                expect_value)
                    pending.event.clear()
                if not conn.alive or self._stopping.is_set():
                    break
            self._n["ack_failures"] += 1
            return None
        finally:
            self._pending.pop(key, None)

    def _writer(self, conn: Connection) -> None:
        while not conn.closing.is_set():
            try:
                frame = conn.tx.get(timeout=0.1)
            except queue.Empty:
                continue
            if frame is None:
                return
            try:
                conn.port.write(frame)
                self._n["frames_sent"] += 1
            except (serial.SerialException, OSError) as exc:
                conn.error = f"write failed: {exc}"
                return

    def _reader(self, conn: Connection) -> None:
        port = conn.port
        while not conn.closing.is_set():
            try:
                data = port.read(max(1, port.in_waiting))
            except (serial.SerialException, OSError, TypeError, AttributeError) as exc:
                if not conn.closing.is_set():
                    conn.error = f"read failed: {exc}"
                return
            if data:
                for frame in self._decoder.feed(data):
                    self._n["frames_received"] += 1
                    self._dispatch(frame)

    def _dispatch(self, frame: codec.Frame) -> None:
        msg = frame.msg
        if isinstance(msg, State):
            now = time.monotonic()
            self._silence.note(msg.device_time_us)
            st = GimbalState(msg.pan, msg.tilt, msg.pan_rate, msg.tilt_rate, msg.mode, msg.faults,
                             msg.last_setpoint_seq, msg.device_time_us, now,
                             self._device_clock.measured_at(msg.device_time_us, now))
            sent = self._sent_at[msg.last_setpoint_seq]
            if sent is not None:
                self._sent_at[msg.last_setpoint_seq] = None
                rtt = now - sent
                self._rtt_last = rtt
                self._rtt_sum += rtt
                self._rtt_max = max(self._rtt_max, rtt)
                self._n["rtt_samples"] += 1
            with self._changed:
                self._state = st
                self._last_state_rx = now
                self._changed.notify_all()
            for callback in self._listeners:
                try:
                    callback(st)
                except Exception:  # a listener's bug must not kill the link
                    log.exception("STATE listener failed")
        elif isinstance(msg, Ack):
            pending = self._pending.get((msg.acked_seq, msg.acked_type))
            if pending is not None:
                pending.reply = msg
                pending.event.set()
        elif isinstance(msg, Identity):
            pending = self._hello
            if pending is not None:
                pending.reply = msg
                pending.event.set()
