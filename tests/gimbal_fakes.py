"""A fake of pivotd's own GimbalInterface (an ideal plant) and a fake monotonic clock, for deterministic tests
of the control loop; plus plan and pose builders."""

from __future__ import annotations

from dataclasses import replace

import numpy as np

from pivotd.bus.messages import PoseSample
from pivotd.daemon.planner import Plan
from pivotd.gimbal.interface import GimbalMode, GimbalState, LinkState

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


class FakeClock:
    def __init__(self) -> None:
        self.t = 1000.0

    def __call__(self) -> float:
        return self.t


class FakeGimbal:
    """A GimbalInterface whose measured state is the last setpoint (an ideal plant)."""

    def __init__(self, clock: FakeClock) -> None:
        self.clock = clock
        self.link_state = LinkState.UP
        self.state: GimbalState | None = GimbalState(0.2, -0.1, 0.0, 0.0, GimbalMode.ENABLED, 0, 0, 0, clock())
        self.last_error = None
        self.setpoints: list[tuple[float, float, float, float]] = []
        self.heartbeats = 0

    def start(self) -> None:
        self.link_state = LinkState.UP

    def stop(self, disable: bool = True) -> None:
        self.link_state = LinkState.STOPPED

    def send_setpoint(self, pan, tilt, pan_rate=0.0, tilt_rate=0.0):
        if self.link_state != LinkState.UP:
            return None
        self.setpoints.append((pan, tilt, pan_rate, tilt_rate))
        seq = len(self.setpoints) & 0xFF  # the wire's 8-bit sequence number, echoed in the state
        self.state = replace(self.state, pan=pan, tilt=tilt, pan_rate=pan_rate, tilt_rate=tilt_rate,
                             last_setpoint_seq=seq, rx_time=self.clock())
        return seq

    def send_heartbeat(self) -> None:
        self.heartbeats += 1

    def set_enabled(self, on, timeout=None) -> bool:
        return True

    def clear_fault(self, timeout=None) -> bool:
        return True

    def counters(self) -> dict:
        return {"setpoints_sent": len(self.setpoints)}


def plan_towards(direction, created: float, n: int = 5) -> Plan:
    pos = np.column_stack([np.arange(n) * 0.5, np.zeros(n), np.full(n, 0.9)])
    d = np.tile(np.asarray(direction, float) / np.linalg.norm(direction), (n, 1))
    return Plan(created=created, positions=pos, directions=d, body_quats=np.tile(IDENTITY, (n, 1)),
                visible=np.zeros(n, int), s=np.arange(n) * 0.5, map_version=0, path_version=1, solve_s=0.0)


def pose_at(rx_time: float, quat=IDENTITY) -> PoseSample:
    return PoseSample(stamp=rx_time, frame_id="map", position=np.array([0.0, 0.0, 0.7]), quat=np.asarray(quat),
                      rx_time=rx_time)
