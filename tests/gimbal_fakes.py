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


class ModelGimbal:
    """A GimbalInterface over the reference device model (pivotd.firmware_proto.device.DeviceModel), stepped on the fake
    clock: the host's frames are encoded and fed to it when sent, and a state is the latest STATE it emitted (no
    transport delay; the device clock is the fake clock). Configured and enabled from ``cfg`` as the link's
    handshake does; ``log_path``: the device's CSV message log, as the soak's (``check_device_log`` reads it)."""

    def __init__(self, clock: FakeClock, cfg, log_path=None) -> None:
        from pivotd.config.settings import wire_config
        from pivotd.firmware_proto.device import DeviceModel
        from pivotd.firmware_proto.messages import Enable, Hello
        from pivotd.firmware_proto.realtime import CsvMessageLog

        self.clock = clock
        self.msg_log = None if log_path is None else CsvMessageLog(log_path)
        self.link_state = LinkState.UP
        self.last_error = None
        self.setpoints: list[tuple[float, float, float, float]] = []
        self.states: list[GimbalState] = []  # every STATE the device emitted
        self.heartbeats = 0
        self._seq = 0
        self.model = DeviceModel(state_hz=50.0, on_message=self._on_message)
        for msg in (Hello(), wire_config(cfg.gimbal, cfg.motion), Enable(1)):
            self._send(msg)
        self.model.step(clock())

    def _on_message(self, direction, msg, seq, now) -> None:
        from pivotd.firmware_proto.messages import State

        if self.msg_log is not None:
            self.msg_log(direction, msg, seq, now)
        if direction == "tx" and isinstance(msg, State):
            self.states.append(GimbalState(msg.pan, msg.tilt, msg.pan_rate, msg.tilt_rate, msg.mode, msg.faults,
                                           msg.last_setpoint_seq, msg.device_time_us, rx_time=now, measured_at=now))

    def _send(self, msg) -> int:
        from pivotd.firmware_proto import codec

        seq, self._seq = self._seq, (self._seq + 1) & 0xFF
        self.model.feed(codec.encode(msg, seq), self.clock())
        return seq

    @property
    def state(self) -> GimbalState | None:
        self.model.step(self.clock())
        return self.states[-1] if self.states else None

    def start(self) -> None:
        self.link_state = LinkState.UP

    def stop(self, disable: bool = True) -> None:
        self.link_state = LinkState.STOPPED
        if self.msg_log is not None:
            self.msg_log.close()

    def send_setpoint(self, pan, tilt, pan_rate=0.0, tilt_rate=0.0):
        from pivotd.firmware_proto.messages import Setpoint

        if self.link_state != LinkState.UP:
            return None
        self.setpoints.append((pan, tilt, pan_rate, tilt_rate))
        newest = self.state  # the setpoint echoes the newest STATE, valid for 200 ms on the device's clock
        state_us = 0 if newest is None else newest.device_time_us
        return self._send(Setpoint(pan, tilt, pan_rate, tilt_rate, round(self.clock() * 1e6) & 0xFFFFFFFF,
                                   state_us, 200))

    def send_heartbeat(self) -> None:
        from pivotd.firmware_proto.messages import Heartbeat

        self.heartbeats += 1
        self._send(Heartbeat())

    def set_enabled(self, on, timeout=None) -> bool:
        return True

    def clear_fault(self, timeout=None) -> bool:
        return True

    def counters(self) -> dict:
        return {"setpoints_sent": len(self.setpoints)}
