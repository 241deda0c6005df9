"""The host's silence rule, shared by the gimbal backends that stream setpoints to a device that streams states.

A device that stops answering (its process stalled, a gimbal manager busy) still reads its port when it resumes,
and executes what queued up meanwhile. So the host sends no setpoint (and no watchdog feed) once the device has
been silent for a few of its own state periods, long before the link is declared lost. :class:`SilenceRule`
estimates that period from the device's clock (the smallest of the recent intervals between consecutive state
stamps: state rates differ between devices, and stamps are not delayed by the host's scheduling), bounds the
silence with a floor (host scheduling jitter) and the state timeout (also before the period is known), and counts
and logs the frames it withholds.
"""

from __future__ import annotations

import collections
import logging

log = logging.getLogger(__name__)

PERIOD_SAMPLES = 32  # consecutive-state intervals the state period is estimated from (their minimum)
_WRAP_US = 1 << 32


class SilenceRule:
    """When a device counts as silent: no state for ``periods`` of its state period, at least ``min_s``, at most
    ``timeout_s`` [s]. :meth:`note` is fed by one reader thread; :meth:`silent` may be called from any thread."""

    def __init__(self, periods: float, min_s: float, timeout_s: float, name: str, state_name: str = "state",
                 logger: logging.Logger = log) -> None:
        """``name`` labels the log line of a silence (URL or port), ``state_name`` the device's state message in it;
        ``logger``: the backend's logger."""
        self.periods = float(periods)
        self.min_s = float(min_s)
        self.timeout_s = float(timeout_s)
        self.name = name
        self.state_name = state_name
        self._log = logger
        self._prev_us: int | None = None
        self._intervals: collections.deque[int] = collections.deque(maxlen=PERIOD_SAMPLES)  # [µs]
        self._period_s: float | None = None  # smallest recent interval between states, device clock [s]
        self._logged = -1.0  # receive time of the last state before the silence last logged

    @property
    def period_s(self) -> float | None:
        """The device's state period estimated so far [s], or None before two stamped states."""
        return self._period_s

    def reset(self) -> None:
        """A new connection: the next state starts a new pair of stamps (the period estimate is kept until then
        replaced interval by interval, as before a reconnect)."""
        self._prev_us = None
        self._intervals.clear()

    def note(self, device_time_us: int) -> None:
        """One state stamped ``device_time_us`` on the device's clock [µs, wraps at 2³²] (reader thread)."""
        prev, self._prev_us = self._prev_us, int(device_time_us) % _WRAP_US
        if prev is None:
            return
        step = (self._prev_us - prev) % _WRAP_US
        if 0 < step < _WRAP_US // 2:  # forwards (a reboot restarts the clock; a repeated stamp says nothing)
            self._intervals.append(step)
            self._period_s = min(self._intervals) * 1e-6

    def silence_s(self) -> float:
        """How long [s] without a state the device counts as silent (see the class docstring)."""
        period = self._period_s
        if period is None:
            return self.timeout_s
        return min(self.timeout_s, max(self.min_s, self.periods * period))

    def silent(self, now: float, last_rx: float, have_state: bool, counters: dict[str, int], counter: str) -> bool:
        """Whether the device is silent at ``now`` [s, monotonic] given the receive time of its latest state
        ``last_rx`` (``have_state``: one was received at all). If so, counts the withheld frame in
        ``counters[counter]`` and, once per silence, ``counters["silences"]`` with one log line."""
        if have_state and now - last_rx <= self.silence_s():
            return False
        counters[counter] += 1
        if last_rx != self._logged:
            self._logged = last_rx
            counters["silences"] += 1
            self._log.info("gimbal at %s silent for %.3f s (no %s): no setpoints until it answers again", self.name,
                           now - last_rx, self.state_name)
        return True
