"""Tracking-error supervision: notices an axis that does not follow its setpoints (blocked, overloaded).

The control loop records every setpoint it sends (:meth:`TrackingErrorSupervisor.commanded`) and gives the
supervisor each new measured state (:meth:`TrackingErrorSupervisor.judge`). The error of an axis is
|commanded − measured|, the commanded position being the last setpoint sent at or before the time the state was
measured (so the transport delay of the state is not counted as error).

States (:class:`TrackingState`):

- ``OK``: the axes follow. An error beyond ``bound`` on one axis while it does not close in on its setpoint
  (its measured rate towards it is below ``REST_RATE`` and below half the setpoint's rate that way: a blocked axis;
  an axis catching up with a stream it got late, at its own limits, is closing in), continuously for
  ``window_s``, enters ``FAULT`` (counted as one episode, logged once).
- ``FAULT``: the control loop holds: the axes that did not follow and stood still (rate within ``REST_RATE``) for
  the last ``window_s`` restart from their measured state at rest, the others brake jerk-limited, and nothing moves
  towards the target, so an axis that frees itself does not close an old error at the device's full speed. After
  ``window_s`` of holding it probes: ``RECOVERING``.
- ``RECOVERING``: tracking again, jerk-limited from the held state. The episode clears (``OK``, logged) when the
  error stayed within ``bound`` for ``window_s`` and each axis that faulted followed: it moved by at least half
  of what it was commanded to since the probe began, once that was a quarter of ``bound`` (a jerk-limited start
  moves little in one window, and a blocked axis must not pass for one that follows); an axis commanded to move
  less than that counts as following once its setpoint stood still for a window (the target reached). An error
  beyond ``bound`` of an axis that stands still holds again at once (``FAULT``), so a still blocked axis runs at
  most ``bound`` away from where it stands; an axis that moves (freed, catching up with the stream at the device's
  limits) is left to close its error.
"""

from __future__ import annotations

import logging
import math
from collections import deque
from dataclasses import dataclass

from pivotd.compat import StrEnum

log = logging.getLogger(__name__)

AXES = ("pan", "tilt")
REST_RATE = math.radians(1.0)  # [rad/s] an axis measured slower than this stands still


class TrackingState(StrEnum):
    """Whether the axes follow their setpoints (see the module docstring)."""

    OK = "ok"
    FAULT = "fault"
    RECOVERING = "recovering"


@dataclass(frozen=True)
class TrackingErrorSettings:
    """bound: largest |commanded − measured| per axis [rad]; window_s: how long it may be exceeded before the
    fault, the hold before probing, and how long it must hold to clear the fault [s]."""

    bound: float = math.radians(10.0)
    window_s: float = 0.2

    def __post_init__(self) -> None:
        if not (math.isfinite(self.bound) and self.bound > 0):
            raise ValueError(f"tracking error bound must be > 0 rad, got {self.bound!r}")
        if not (math.isfinite(self.window_s) and self.window_s > 0):
            raise ValueError(f"tracking error window must be > 0 s, got {self.window_s!r}")


@dataclass(frozen=True)
class Verdict:
    """What one judged state changed: ``entered_fault``: the axes (indices) that did not follow, when the state
    entered FAULT (empty otherwise); ``restart``: those of them that stood still for the window, to restart from
    their measured state."""

    entered_fault: tuple[int, ...] = ()
    restart: tuple[int, ...] = ()


class TrackingErrorSupervisor:
    """Judges measured states against the setpoints sent (one control loop's; not thread-safe). Times [s] are
    the control loop's monotonic clock."""

    def __init__(self, settings: TrackingErrorSettings, history: int = 256) -> None:
        self.settings = settings
        self.state = TrackingState.OK
        self.episodes = 0  # entries into FAULT from OK
        self.holds = 0  # entries into FAULT (episodes and re-holds while recovering)
        self.reason = ""  # the latest fault's axis and error, for the status
        self.worst_error = 0.0  # [rad] largest error judged since start
        self._sent: deque[tuple[float, float, float, float, float]] = deque(maxlen=history)  # (t, pan, tilt, rates)
        self._over_since: list[float | None] = [None, None]  # per axis: measured time the error went over
        self.status_since = -math.inf  # loop time of the last change of ``state`` [s]
        self._within_since: float | None = None  # RECOVERING: measured time since which the error is within
        self._faulted: tuple[int, ...] = ()  # the axes of the latest fault
        self._rest_since: list[float | None] = [None, None]  # per axis: measured time since it stands still
        self._probe_from: tuple[tuple[float, float], tuple[float, float]] | None = None  # (commanded, measured)

    def commanded(self, t: float, pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> None:
        """A setpoint (pan, tilt [rad], rates [rad/s]) was sent at ``t``."""
        self._sent.append((t, pan, tilt, pan_rate, tilt_rate))

    def restart(self) -> None:
        """The stream restarted from a measured state (or stopped): setpoints sent before say nothing about the
        axes any more. The state stays (an episode ends only when the axes follow)."""
        self._sent.clear()
        self._over_since = [None, None]
        self._within_since = self._probe_from = None

    def _sent_at(self, t: float) -> tuple[float, float, float, float, float] | None:
        found = None
        for entry in self._sent:
            if entry[0] > t:
                break
            found = entry
        return found

    def _commanded_at(self, t: float) -> tuple[float, float] | None:
        found = self._sent_at(t)
        return None if found is None else (found[1], found[2])

    def _closing_in(self, measured_time: float, pos: tuple[float, float], rate: tuple[float, float]) -> list[bool]:
        """Per axis: whether it moves towards its setpoint (see the module docstring)."""
        sent = self._sent_at(measured_time)
        if sent is None:
            return [False, False]
        out = []
        for i in range(2):
            way = math.copysign(1.0, sent[1 + i] - pos[i])
            out.append(way * rate[i] >= max(REST_RATE, 0.5 * way * sent[3 + i]))
        return out

    def errors(self, measured_time: float, pan: float, tilt: float) -> tuple[float, float] | None:
        """|commanded − measured| per axis [rad] for a state measured at ``measured_time`` (None: no setpoint was
        sent before it since the last restart)."""
        cmd = self._commanded_at(measured_time)
        if cmd is None:
            return None
        return abs(cmd[0] - pan), abs(cmd[1] - tilt)

    def _followed(self, measured_time: float, pan: float, tilt: float) -> bool:
        """RECOVERING: whether each axis that faulted moved with its setpoints since the probe began."""
        cmd = self._commanded_at(measured_time)
        if cmd is None:
            return False
        if self._probe_from is None:
            self._probe_from = (cmd, (pan, tilt))
            return False
        (cmd0, meas0), meas = self._probe_from, (pan, tilt)
        before = self._commanded_at(measured_time - self.settings.window_s) or cmd0
        for i in self._faulted:
            demanded = abs(cmd[i] - cmd0[i])
            if demanded >= 0.25 * self.settings.bound:
                if abs(meas[i] - meas0[i]) < 0.5 * demanded:
                    return False
            elif abs(cmd[i] - before[i]) > REST_RATE * self.settings.window_s:
                return False  # commanded to move, not far enough yet to tell: wait
        return True

    def judge(self, now: float, measured_time: float, pan: float, tilt: float, pan_rate: float = 0.0,
              tilt_rate: float = 0.0) -> Verdict:
        """Judge one new state measured at ``measured_time`` (pan, tilt [rad], rates [rad/s]) at loop time ``now``."""
        s = self.settings
        for i, rate in enumerate((pan_rate, tilt_rate)):
            if abs(rate) > REST_RATE:
                self._rest_since[i] = None
            elif self._rest_since[i] is None:
                self._rest_since[i] = measured_time
        still = tuple(i for i in range(2) if self._rest_since[i] is not None
                      and measured_time - self._rest_since[i] >= s.window_s)
        if self.state is TrackingState.FAULT:
            if now - self.status_since >= s.window_s:
                self._set(TrackingState.RECOVERING, now)
                self._within_since = None
            return Verdict()
        err = self.errors(measured_time, pan, tilt)
        if err is None:
            return Verdict()
        self.worst_error = max(self.worst_error, *err)
        over = tuple(i for i in range(2) if err[i] > s.bound)
        if self.state is TrackingState.RECOVERING:
            if any(i in still for i in over):
                return self._fault(now, over, err, still, immediate=True)
            if over:  # moving: freed, catching up with the stream
                self._within_since = None
                return Verdict()
            followed = self._followed(measured_time, pan, tilt)
            if self._within_since is None:
                self._within_since = measured_time
            elif measured_time - self._within_since >= s.window_s and followed:
                log.warning("tracking error cleared: the axes follow their setpoints again (within %.1f° for "
                            "%.2f s)", math.degrees(s.bound), s.window_s)
                self._set(TrackingState.OK, now)
                self.reason = ""
            return Verdict()
        closing = self._closing_in(measured_time, (pan, tilt), (pan_rate, tilt_rate))
        for i in range(2):
            if err[i] <= s.bound or closing[i]:
                self._over_since[i] = None
            elif self._over_since[i] is None:
                self._over_since[i] = measured_time
        late = tuple(i for i in range(2) if self._over_since[i] is not None
                     and measured_time - self._over_since[i] >= s.window_s)
        if late:
            return self._fault(now, late, err, still, immediate=False)
        return Verdict()

    def _fault(self, now: float, axes: tuple[int, ...], err: tuple[float, float], still: tuple[int, ...],
               immediate: bool) -> Verdict:
        s = self.settings
        self.reason = "; ".join(f"{AXES[i]} does not follow: |commanded - measured| {math.degrees(err[i]):.1f}° > "
                                f"{math.degrees(s.bound):.1f}°" for i in axes)
        if not immediate:
            self.episodes += 1
            log.warning("tracking error: %s for %.2f s: holding at the measured state (episode %d)", self.reason,
                        s.window_s, self.episodes)
        self.holds += 1
        self._set(TrackingState.FAULT, now)
        self._faulted = axes
        self._over_since = [None, None]
        self._within_since = self._probe_from = None
        return Verdict(entered_fault=axes, restart=tuple(i for i in axes if i in still))

    def _set(self, state: TrackingState, now: float) -> None:
        self.state = state
        self.status_since = now

    def status(self) -> dict:
        """The ``tracking_error`` block of the daemon's status document."""
        s = self.settings
        return {"state": self.state, "reason": self.reason, "episodes": self.episodes, "holds": self.holds,
                "worst_deg": round(math.degrees(self.worst_error), 3), "bound_deg": round(math.degrees(s.bound), 3),
                "window_s": s.window_s}
