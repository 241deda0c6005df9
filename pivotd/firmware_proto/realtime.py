"""Run the device model in real time on a thread, with fault injection and a CSV message log.

Shared by ``tools/mock_gimbal`` (pty / TCP / serial) and the in-process ``mock://`` pyserial URL.
Bytes from the host go in through :meth:`RealTimeDevice.write`; bytes from the device go out
through the ``sink`` callable (None while "unplugged": output is discarded).
"""

from __future__ import annotations

import csv
import heapq
import logging
import random
import threading
import time
from collections.abc import Callable
from pathlib import Path

from pivotd.firmware_proto.device import DeviceModel
from pivotd.firmware_proto.messages import Message, Setpoint, setpoint_age_us

log = logging.getLogger(__name__)

LOG_COLUMNS = ("t_s", "dir", "type", "seq", "pan", "tilt", "pan_rate", "tilt_rate", "mode", "faults",
               "device_time_us", "host_time_us", "detail")


class FaultInjector:
    """Per-frame link faults: drop with probability ``drop``, flip one bit with probability ``corrupt``,
    deliver ``latency_s`` later. Deterministic for a given ``seed``."""

    def __init__(self, drop: float = 0.0, corrupt: float = 0.0, latency_s: float = 0.0, seed: int | None = None):
        for name, p in (("drop", drop), ("corrupt", corrupt)):
            if not 0.0 <= p <= 1.0:
                raise ValueError(f"--{name} must be a probability in [0, 1], got {p}")
        if latency_s < 0:
            raise ValueError(f"--latency-ms must be >= 0, got {latency_s * 1000}")
        self.drop, self.corrupt, self.latency_s = drop, corrupt, latency_s
        self.rng = random.Random(seed)
        self.dropped = 0
        self.corrupted = 0

    def apply(self, frame: bytes) -> bytes | None:
        """The frame as it arrives on the other side, or None if lost."""
        if self.drop and self.rng.random() < self.drop:
            self.dropped += 1
            return None
        if self.corrupt and self.rng.random() < self.corrupt and len(frame) > 1:
            data = bytearray(frame)
            i = self.rng.randrange(len(data) - 1)  # keep the delimiter: a flipped bit inside the frame
            data[i] ^= 1 << self.rng.randrange(8)
            self.corrupted += 1
            return bytes(data)
        return frame


class CsvMessageLog:
    """Writes every message the device receives ("rx"; "stale": a SETPOINT dropped as older than its validity, not
    executed) and emits ("tx") as a CSV row (LOG_COLUMNS).

    ``t_s`` is the device clock [s]; angles/rates are SI at wire resolution. Emitted frames are logged
    before fault injection (a dropped STATE still appears here). A version-2 SETPOINT's ``detail`` is
    ``age_us=A max_age_ms=M``: its age on the device clock when it was judged, and its validity."""

    def __init__(self, path: str | Path) -> None:
        self._file = open(path, "w", newline="")  # noqa: SIM115 - closed in close()
        self._csv = csv.writer(self._file)
        self._csv.writerow(LOG_COLUMNS)
        self._lock = threading.Lock()

    def __call__(self, direction: str, msg: Message, seq: int, now: float) -> None:
        msg = msg.from_raw(msg.raw())  # log the values as they are on the wire (micro-unit resolution)
        g = lambda name: getattr(msg, name, "")  # noqa: E731
        detail = ""
        if msg.NAME in ("CONFIG", "ACK", "IDENTITY", "ENABLE", "HELLO"):
            detail = " ".join(f"{k}={v}" for k, v in zip([f[0] for f in msg.LAYOUT], msg.raw(), strict=True))
        elif isinstance(msg, Setpoint):
            detail = f"age_us={setpoint_age_us(round(now * 1e6), msg.state_time_us)} max_age_ms={msg.max_age_ms}"
        row = (f"{now:.6f}", direction, msg.NAME, seq, g("pan"), g("tilt"), g("pan_rate"), g("tilt_rate"), g("mode"),
               g("faults"), g("device_time_us"), g("host_time_us"), detail)
        with self._lock:
            self._csv.writerow(row)
            self._file.flush()

    def note(self, direction: str, name: str, now: float, detail: str = "") -> None:
        """A row for a message of another protocol that has no angles (e.g. a MAVLink command): type and detail."""
        with self._lock:
            self._csv.writerow((f"{now:.6f}", direction, name, "", "", "", "", "", "", "", "", "", detail))
            self._file.flush()

    def angles(self, direction: str, name: str, now: float, pan: float, tilt: float, pan_rate: float,
               tilt_rate: float, host_time_us: int | str = "") -> None:
        """A row of angles [rad] and rates [rad/s] of another protocol (``nan``: not on that wire)."""
        with self._lock:
            self._csv.writerow((f"{now:.6f}", direction, name, "", f"{pan:.6f}", f"{tilt:.6f}", f"{pan_rate:.6f}",
                                f"{tilt_rate:.6f}", "", "", "", host_time_us, ""))
            self._file.flush()

    def close(self) -> None:
        with self._lock:
            self._file.close()


def split_frames(buffer: bytes, data: bytes) -> tuple[list[bytes], bytes]:
    """Split ``buffer + data`` into complete frames (each ending in 0x00) and the incomplete rest."""
    parts = (buffer + data).split(b"\x00")
    rest = parts.pop()
    return [p + b"\x00" for p in parts], rest


class RealTimeDevice:
    """A :class:`DeviceModel` stepped in real time by a background thread.

    ``faults_at`` is a list of (seconds after start, fault bit number) to inject; with
    ``faults_from_first_frame`` the seconds count from the host's first frame instead (what a test
    wants when the host may take a while to start). The device clock starts at 0 when :meth:`start`
    is called; :attr:`first_frame_at` is the device time of the host's first frame (None before).
    """

    def __init__(self, model: DeviceModel, injector: FaultInjector | None = None,
                 faults_at: list[tuple[float, int]] | None = None,
                 clock: Callable[[], float] = time.monotonic, *,
                 faults_from_first_frame: bool = False) -> None:
        self.model = model
        self.injector = injector or FaultInjector()
        # with faults_from_first_frame the faults wait in _faults_after_first_frame until the host speaks
        faults = sorted(faults_at or [])
        self._faults_after_first_frame = faults if faults_from_first_frame else []
        self.faults_at = [] if faults_from_first_frame else faults
        self.first_frame_at: float | None = None
        self.sink: Callable[[bytes], None] | None = None
        self._clock = clock
        self._t0 = clock()
        self._cond = threading.Condition()
        self._incoming: list[tuple[float, int, bytes]] = []  # heap of (due, order, frame)
        self._outgoing: list[tuple[float, int, bytes]] = []
        self._order = 0
        self._rx_rest = b""
        self._running = False
        self._thread: threading.Thread | None = None

    def elapsed(self) -> float:
        """Seconds on the device clock."""
        return self._clock() - self._t0

    def start(self) -> None:
        self._t0 = self._clock()
        self._running = True
        self._thread = threading.Thread(target=self._run, name="mock-gimbal-device", daemon=True)
        self._thread.start()

    def stop(self) -> None:
        with self._cond:
            self._running = False
            self._cond.notify_all()
        if self._thread is not None:
            self._thread.join(timeout=2.0)

    def inject_fault(self, bit: int) -> None:
        """Latch fault ``bit`` (0..15) now; callable from any thread (the device thread applies it)."""
        with self._cond:
            self.faults_at.insert(0, (self.elapsed(), int(bit)))
            self._cond.notify_all()

    def inject_stuck_axis(self, axis: str, seconds: float) -> None:
        """Hold ``axis`` ("pan"/"tilt") mechanically for ``seconds`` from now, no fault bit
        (:meth:`DeviceModel.inject_stuck_axis`); callable from any thread."""
        with self._cond:
            self.model.inject_stuck_axis(axis, seconds, self.elapsed())
            self._cond.notify_all()

    def write(self, data: bytes) -> None:
        """Bytes from the host (any chunking); faults are applied per frame."""
        with self._cond:
            frames, self._rx_rest = split_frames(self._rx_rest, bytes(data))
            now = self.elapsed()
            if frames and self.first_frame_at is None:
                self.first_frame_at = now
                self.faults_at = sorted(self.faults_at + [(t + now, bit) for t, bit in self._faults_after_first_frame])
                self._faults_after_first_frame = []
            due = now + self.injector.latency_s
            for frame in frames:
                frame = self.injector.apply(frame)
                if frame is not None:
                    self._order += 1
                    heapq.heappush(self._incoming, (due, self._order, frame))
            if frames:
                self._cond.notify_all()

    def _run(self) -> None:
        model = self.model
        while True:
            with self._cond:
                if not self._running:
                    return
                now = self.elapsed()
                wake = [model.next_state, now + 0.05]
                if self._incoming:
                    wake.append(self._incoming[0][0])
                if self._outgoing:
                    wake.append(self._outgoing[0][0])
                if self.faults_at:
                    wake.append(self.faults_at[0][0])
                timeout = min(wake) - now
                if timeout > 0:
                    self._cond.wait(timeout)
                now = self.elapsed()
                arrived = []
                while self._incoming and self._incoming[0][0] <= now:
                    arrived.append(heapq.heappop(self._incoming)[2])
                due_faults = []
                while self.faults_at and self.faults_at[0][0] <= now:
                    due_faults.append(self.faults_at.pop(0)[1])
            out = b""
            if arrived:
                out += model.feed(b"".join(arrived), now)
            for bit in due_faults:
                log.info("injecting fault bit %d at t=%.3f s", bit, now)
                model.inject_fault(1 << bit)
            out += model.step(now)
            if out:
                frames, _ = split_frames(b"", out)
                with self._cond:
                    due = now + self.injector.latency_s
                    for frame in frames:
                        frame = self.injector.apply(frame)
                        if frame is not None:
                            self._order += 1
                            heapq.heappush(self._outgoing, (due, self._order, frame))
            ready = []
            with self._cond:
                while self._outgoing and self._outgoing[0][0] <= now:
                    ready.append(heapq.heappop(self._outgoing)[2])
            sink = self.sink
            if ready and sink is not None:
                try:
                    sink(b"".join(ready))
                except OSError as exc:  # the port went away under us: output is lost, like on a wire
                    log.debug("device output lost: %s", exc)
