"""What the daemon needs from a gimbal, whatever drives it: :class:`GimbalInterface`, its states.

The control loop and the daemon depend only on this interface; :class:`pivotd.gimbal.link.GimbalLink`
(pivotd's own serial protocol) implements it, and other backends plug in by implementing it too.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass
from typing import Protocol

from pivotd.compat import StrEnum
from pivotd.firmware_proto.messages import MODE_DISABLED, MODE_ENABLED, MODE_FAULT, MODE_HOLDING


class LinkState(StrEnum):
    """Connection state of a gimbal link."""

    CONNECTING = "connecting"  # opening the port / handshake in progress
    UP = "up"  # handshake done, states arriving
    DOWN = "down"  # lost; reconnecting with backoff
    INCOMPATIBLE = "incompatible"  # the device speaks a protocol version we do not
    STOPPED = "stopped"  # not started, or stopped


class GimbalMode(enum.IntEnum):
    """Device mode as reported in :attr:`GimbalState.mode` (the protocol's mode numbers)."""

    DISABLED = MODE_DISABLED
    ENABLED = MODE_ENABLED
    HOLDING = MODE_HOLDING
    FAULT = MODE_FAULT


@dataclass(frozen=True)
class GimbalState:
    """Latest measured state: joint angles [rad] and rates [rad/s], mode (a :class:`GimbalMode` value), fault
    bits, echoed setpoint seq, device clock [µs, wraps at 2³²], host receive time (time.monotonic()) [s], and the
    host time the device measured it at [s] (from its clock: :class:`pivotd.gimbal.device_clock.DeviceClock`;
    None when unknown, then the receive time stands for it)."""

    pan: float
    tilt: float
    pan_rate: float
    tilt_rate: float
    mode: int
    faults: int
    last_setpoint_seq: int
    device_time_us: int
    rx_time: float
    measured_at: float | None = None

    @property
    def measured_time(self) -> float:
        """Host time [s] the state was measured at (its receive time when the device's clock is not known)."""
        return self.rx_time if self.measured_at is None else self.measured_at


class GimbalInterface(Protocol):
    """A gimbal as the control loop and the daemon use it. Implementations are thread-safe; sending never
    blocks the caller (the control thread) and is a no-op returning None/False while the link is not up."""

    @property
    def link_state(self) -> LinkState:
        """Connection state; setpoints are only sent while :attr:`LinkState.UP`."""
        ...

    @property
    def state(self) -> GimbalState | None:
        """The latest measured state (None before the first one; kept while the link is down)."""
        ...

    @property
    def last_error(self) -> str | None:
        """One line describing the last connection problem."""
        ...

    def start(self) -> None:
        """Connect (and keep reconnecting) in the background; returns immediately."""
        ...

    def stop(self, disable: bool = True) -> None:
        """Disable the gimbal (if ``disable`` and up), close the connection."""
        ...

    def send_setpoint(self, pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> int | None:
        """Queue one setpoint (pan/tilt [rad], feed-forward rates [rad/s]); an id, or None when not sent (link not
        up, the device silent, a full queue): the control loop then restarts the stream from a measured state."""
        ...

    def send_heartbeat(self) -> None:
        """Keep the device's watchdog fed without moving."""
        ...

    def set_enabled(self, on: bool, timeout: float | None = None) -> bool:
        """Enable or disable the drives; True once the device confirmed."""
        ...

    def clear_fault(self, timeout: float | None = None) -> bool:
        """Ask the device to clear its fault; True once the device confirmed."""
        ...

    def counters(self) -> dict[str, int | float]:
        """Link statistics for the status document (names are backend-specific)."""
        ...
