"""When the receding-horizon planner should replan: on events, not on every tick.

A plan stays valid while the robot moves along it: its waypoints after the first sit on the path's fixed
grid and the control loop interpolates the planned directions at the robot's progress. What changes a plan
is a new waypoint entering the horizon (the robot moved about one waypoint spacing), a new path or map,
or time (the robot left the path, the commanded direction drifted from the plan). The trigger is asked at
the planner's rate (``planner.replan_hz``) and answers whether a replan is due and why.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pivotd.compat import StrEnum


class ReplanReason(StrEnum):
    FIRST = "first"  # no plan yet
    INPUT = "input"  # the path or the map changed
    MOVED = "moved"  # the body moved at least ``distance`` since the last replan
    INTERVAL = "interval"  # ``max_interval`` passed since the last replan
    EVERY_TICK = "every_tick"  # event-driven replanning is off


@dataclass
class ReplanTrigger:
    """distance [m]: replan once the body moved this far from where it was at the last replan (None: replan at
    every tick); max_interval [s]: replan at least this often."""

    distance: float | None
    max_interval: float
    _last_time: float | None = field(default=None, init=False)
    _last_position: np.ndarray | None = field(default=None, init=False)
    _last_inputs: tuple | None = field(default=None, init=False)

    def due(self, now: float, position: np.ndarray, inputs: tuple) -> ReplanReason | None:
        """The reason to replan now (None: the current plan stands). ``now`` [s] monotonic, ``position`` (3,) [m]
        body position, ``inputs``: versions of what the plan depends on (path, map), compared for equality."""
        if self._last_time is None or self._last_position is None:
            return ReplanReason.FIRST
        if self.distance is None:
            return ReplanReason.EVERY_TICK
        if inputs != self._last_inputs:
            return ReplanReason.INPUT
        if float(np.linalg.norm(np.asarray(position, float) - self._last_position)) >= self.distance:
            return ReplanReason.MOVED
        if now - self._last_time >= self.max_interval:
            return ReplanReason.INTERVAL
        return None

    def planned(self, now: float, position: np.ndarray, inputs: tuple) -> None:
        """Record a replan at ``now`` [s] with the body at ``position`` (3,) [m] and these ``inputs``."""
        self._last_time = float(now)
        self._last_position = np.array(position, dtype=float)
        self._last_inputs = inputs

    def reset(self) -> None:
        """Forget the last replan (the next call to :meth:`due` answers FIRST)."""
        self._last_time = self._last_position = self._last_inputs = None
