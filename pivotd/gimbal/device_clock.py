"""When a gimbal state was measured, on the host's clock, from the device's own timestamp.

A state's receive time says when the host read it, not when the device measured it: after the host was held up
(a stall, a loaded machine) it reads the states that queued up meanwhile all at once, each looking fresh.
:class:`DeviceClock` maps the device's 32-bit microsecond clock onto host monotonic time with the smallest
transit delay seen so far (the least-delayed state bounds the offset between the clocks), allowed to grow by
``drift`` per second of host time so that clock drift between the two is followed. A queued state keeps its
device timestamp, so its measured time stays in the past however late it is read.
"""

from __future__ import annotations

_WRAP_US = 1 << 32


class DeviceClock:
    """Device clock [µs, wraps at 2³²] → host monotonic time [s] of the measurement. Not thread-safe: one reader
    thread feeds it."""

    def __init__(self, drift: float = 1e-3) -> None:
        self.drift = drift  # [s/s] the most the offset may grow per second of host time (clock drift)
        self.reset()

    def reset(self) -> None:
        """Forget the device (a new connection, or its clock restarted)."""
        self._last_us: int | None = None
        self._device_s = 0.0  # unwrapped device time of the last state [s]
        self._offset: float | None = None  # host time − device time [s]
        self._last_rx = 0.0

    def measured_at(self, device_time_us: int, rx_time: float) -> float:
        """Host time [s] at which the state stamped ``device_time_us`` was measured, given that it was read at
        ``rx_time`` [s]; never later than ``rx_time``. A device clock that runs backwards (a reboot) starts over."""
        us = int(device_time_us) % _WRAP_US
        if self._last_us is None:
            self._device_s = us * 1e-6
        else:
            step = (us - self._last_us) % _WRAP_US
            if step >= _WRAP_US // 2:  # backwards: the device restarted its clock
                self.reset()
                self._device_s = us * 1e-6
            else:
                self._device_s += step * 1e-6
        self._last_us = us
        sample = rx_time - self._device_s
        if self._offset is None:
            self._offset = sample
        else:
            self._offset = min(sample, self._offset + self.drift * max(0.0, rx_time - self._last_rx))
        self._last_rx = rx_time
        return min(rx_time, self._device_s + self._offset)
