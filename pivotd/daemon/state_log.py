"""The daemon's state changes as log lines, each once (the journal shows when and why the gimbal moved or held).

:class:`StateLog` is told about the inputs and every control tick and logs on edges only: the first pose and the
first path received (INFO), the first tick that follows a plan (INFO, ``tracking``), poses going stale — no pose for
longer than ``control.pose_timeout_s``: the control loop holds the gimbal still (WARNING) — and poses resuming
(INFO). Nothing is logged per tick or per message, so a run in steady state logs nothing.
"""

from __future__ import annotations

import logging
import threading

from pivotd.bus.messages import PoseSample
from pivotd.daemon.states import DaemonState


class StateLog:
    """Edge-triggered log of the daemon's states. :meth:`tick` runs on the control thread, :meth:`pose` and
    :meth:`path` on the bus's decoding threads; each edge is logged by one thread only (a flag set under a lock)."""

    def __init__(self, pose_topic: str, path_topic: str, log: logging.Logger) -> None:
        self.pose_topic = pose_topic
        self.path_topic = path_topic
        self._log = log
        self._lock = threading.Lock()
        self._posed = False  # a pose was accepted
        self._pathed = False  # a path was received
        self._tracked = False  # a tick followed a plan
        self._stale_since: float | None = None  # rx time [s] of the last pose before the current gap, if stale

    def pose(self, pose: PoseSample) -> None:
        """A pose was accepted (first one: one line with where the robot is)."""
        with self._lock:
            first, self._posed = not self._posed, True
        if first:
            self._log.info("first pose on %s: robot at %s", self.pose_topic,
                           [round(float(v), 2) for v in pose.position])

    def path(self, points: int) -> None:
        """A path of ``points`` poses was received (first one: one line)."""
        with self._lock:
            first, self._pathed = not self._pathed, True
        if first:
            self._log.info("first path on %s: %d poses", self.path_topic, points)

    def tick(self, now: float, mode: DaemonState, pose: PoseSample | None, pose_timeout_s: float) -> None:
        """One control tick at monotonic ``now`` [s] decided ``mode`` with the latest ``pose``."""
        if mode is DaemonState.TRACKING and not self._tracked:
            self._tracked = True
            self._log.info("tracking: the gimbal follows the plan")
        if pose is None:
            return
        age = now - pose.rx_time
        if age > pose_timeout_s:
            if self._stale_since is None:
                self._stale_since = pose.rx_time
                self._log.warning("no pose on %s for %.2f s (more than control.pose_timeout_s %.2f s): holding the "
                                  "gimbal still until poses resume", self.pose_topic, age, pose_timeout_s)
        elif self._stale_since is not None:
            gap = pose.rx_time - self._stale_since
            self._stale_since = None
            self._log.info("poses on %s again after a gap of %.2f s: the hold ends", self.pose_topic, gap)
