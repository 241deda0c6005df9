"""Plausibility gate for received poses: speed, jump and turn-rate limits against the last accepted pose.

A pose that a real robot could not have reached since the last accepted one is refused and counted. The
gate re-anchors on the next pose once none has been accepted for ``reanchor_after`` seconds (the control
loop already holds on a stale pose then), so a relocalised robot recovers by itself.
"""

from __future__ import annotations

import enum
import threading

import numpy as np

from pivotd.bus.messages import PoseSample
from pivotd.config.settings import PoseGateConfig
from pivotd.geometry import quat_angles

#: Reception-time slack [s] added to the time between poses (network and scheduling jitter).
TIME_SLACK_S = 0.1


class PoseVerdict(enum.Enum):
    """Outcome of :meth:`PoseGate.check`; the refusals name the limit that was exceeded."""

    ACCEPTED = "accepted"
    JUMP = "jump"
    SPEED = "speed"
    TURN = "turn"


def turn_angle(q1: np.ndarray, q2: np.ndarray) -> float:
    """Rotation angle [rad] between two unit quaternions (x, y, z, w), in [0, π]."""
    return float(quat_angles(q1, q2))


class PoseGate:
    """Stateful gate (thread-safe): :meth:`check` each pose in arrival order; counters for the status."""

    def __init__(self) -> None:
        self._last: PoseSample | None = None
        self._lock = threading.Lock()
        self._counts = {v.value: 0 for v in PoseVerdict}

    def check(self, pose: PoseSample, limits: PoseGateConfig, reanchor_after: float) -> PoseVerdict:
        """Judge ``pose`` (its ``rx_time`` [s, monotonic] is the clock) against the last accepted one."""
        with self._lock:
            verdict = self._judge(pose, limits, reanchor_after)
            self._counts[verdict.value] += 1
            if verdict is PoseVerdict.ACCEPTED:
                self._last = pose
            return verdict

    def _judge(self, pose: PoseSample, limits: PoseGateConfig, reanchor_after: float) -> PoseVerdict:
        last = self._last
        if last is None:
            return PoseVerdict.ACCEPTED
        dt = pose.rx_time - last.rx_time
        if dt > reanchor_after:
            return PoseVerdict.ACCEPTED
        span = max(dt, 0.0) + TIME_SLACK_S
        moved = float(np.linalg.norm(pose.position - last.position))
        if moved > limits.max_jump:
            return PoseVerdict.JUMP
        if moved > limits.max_speed * span:
            return PoseVerdict.SPEED
        if turn_angle(pose.quat, last.quat) > limits.max_turn_rate * span:
            return PoseVerdict.TURN
        return PoseVerdict.ACCEPTED

    def counters(self) -> dict[str, object]:
        """``{"accepted": n, "rejected": {"jump": n, "speed": n, "turn": n}}`` (a copy)."""
        with self._lock:
            c = dict(self._counts)
        accepted = c.pop(PoseVerdict.ACCEPTED.value)
        return {"accepted": accepted, "rejected": c}
