"""pyserial ``mock://`` URL: the reference device model running in-process in real time.

Query options (all optional): ``state_hz`` (default 50), ``drop``, ``corrupt`` (probabilities),
``latency_ms``, ``seed``, ``log`` (CSV file of every message, see pivotd.firmware_proto.realtime),
``fault_at`` (``SECONDS:BIT``, repeatable), ``version`` (protocol version the device speaks).
Example: ``mock://?state_hz=100&log=/tmp/gimbal.csv``.
"""

from __future__ import annotations

import threading
import time
import urllib.parse

from serial.serialutil import PortNotOpenError, SerialBase, SerialException

from pivotd.firmware_proto.device import DeviceInfo, DeviceModel
from pivotd.firmware_proto.messages import PROTOCOL_VERSION
from pivotd.firmware_proto.realtime import CsvMessageLog, FaultInjector, RealTimeDevice

_OPTIONS = {"state_hz", "drop", "corrupt", "latency_ms", "seed", "log", "fault_at", "version"}


def parse_url(url: str) -> dict[str, list[str]]:
    """Query options of a ``mock://`` URL; raises SerialException naming a bad option."""
    parts = urllib.parse.urlsplit(url)
    if parts.scheme != "mock":
        raise SerialException(f"expected a mock:// URL, got {url!r}")
    opts = urllib.parse.parse_qs(parts.query, keep_blank_values=True)
    unknown = set(opts) - _OPTIONS
    if unknown:
        raise SerialException(f"{url}: unknown option(s) {', '.join(sorted(unknown))} (known: {sorted(_OPTIONS)})")
    return opts


class Serial(SerialBase):
    """A serial port whose other end is a simulated gimbal."""

    def __init__(self, *args, **kwargs) -> None:  # type: ignore[no-untyped-def]
        self._device: RealTimeDevice | None = None
        self._log: CsvMessageLog | None = None
        self._rx = bytearray()
        self._rx_cond = threading.Condition()
        super().__init__(*args, **kwargs)

    def open(self) -> None:
        if self.is_open:
            raise SerialException("port already open")
        if self._port is None:
            raise SerialException("port must be configured before it can be used")
        opts = parse_url(self.portstr)
        try:
            first = {k: v[-1] for k, v in opts.items()}
            state_hz = float(first.get("state_hz", 50.0))
            injector = FaultInjector(float(first.get("drop", 0)), float(first.get("corrupt", 0)),
                                     float(first.get("latency_ms", 0)) / 1000.0,
                                     int(first["seed"]) if "seed" in first else None)
            faults_at = [(float(t), int(b)) for t, b in (s.split(":") for s in opts.get("fault_at", []))]
            version = int(first.get("version", PROTOCOL_VERSION))
        except ValueError as exc:
            raise SerialException(f"{self.portstr}: bad option value: {exc}") from None
        if state_hz <= 0:
            raise SerialException(f"{self.portstr}: state_hz must be > 0")
        self._log = CsvMessageLog(first["log"]) if first.get("log") else None
        model = DeviceModel(state_hz=state_hz, info=DeviceInfo(version=version), on_message=self._log)
        self._device = RealTimeDevice(model, injector, faults_at)
        self._device.sink = self._receive
        self._device.start()
        self.is_open = True

    def _receive(self, data: bytes) -> None:
        with self._rx_cond:
            self._rx += data
            self._rx_cond.notify_all()

    def close(self) -> None:
        if self._device is not None:
            self._device.stop()
            self._device = None
        if self._log is not None:
            self._log.close()
            self._log = None
        self.is_open = False

    def _reconfigure_port(self) -> None:
        """Baud rate and the like have no meaning here."""

    @property
    def device(self) -> RealTimeDevice | None:
        """The simulated device (for tests and diagnostics)."""
        return self._device

    @property
    def in_waiting(self) -> int:
        if not self.is_open:
            raise PortNotOpenError()
        return len(self._rx)

    def read(self, size: int = 1) -> bytes:
        if not self.is_open:
            raise PortNotOpenError()
        deadline = None if self._timeout is None else time.monotonic() + self._timeout
        with self._rx_cond:
            while len(self._rx) < size and self.is_open:
                remaining = None if deadline is None else deadline - time.monotonic()
                if remaining is not None and remaining <= 0:
                    break
                self._rx_cond.wait(remaining)
            data = bytes(self._rx[:size])
            del self._rx[:size]
        return data

    def write(self, data: bytes) -> int:
        if not self.is_open or self._device is None:
            raise PortNotOpenError()
        data = bytes(data)
        self._device.write(data)
        return len(data)

    def reset_input_buffer(self) -> None:
        with self._rx_cond:
            self._rx.clear()

    def reset_output_buffer(self) -> None:
        """Writes are delivered immediately: nothing to discard."""

    def flush(self) -> None:
        """Writes are delivered immediately."""
