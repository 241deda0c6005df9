"""A MAVLink gimbal manager and its gimbal device in one component (common dialect, MAVLink 2), for tests.

Pure and steppable like the serial protocol's device model: ``handle(msg, now)`` answers one decoded message,
``step(now)`` advances the rate- and acceleration-limited axes and returns the messages that fell due
(GIMBAL_DEVICE_ATTITUDE_STATUS at ``state_hz``, GIMBAL_MANAGER_STATUS at 5 Hz, HEARTBEAT at 1 Hz). It answers
MAV_CMD_REQUEST_MESSAGE(GIMBAL_MANAGER_INFORMATION) and MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, follows
GIMBAL_MANAGER_SET_PITCHYAW from the component in primary control (clamped to its range), drops the rate
feed-forward and holds the angle when setpoints stop for ``setpoint_timeout_s``, and stops moving while a
failure flag is set. Every setpoint and state goes to ``log`` in pivotd's pan/tilt convention (the CSV of the
serial protocol's mock), commands as notes.

The gimbal sits on a vehicle at ``heading`` (NED, clockwise from North [rad]) turning at ``heading_rate``
[rad/s]; the attitude status reports its yaw in the frame ``yaw_frame`` (:class:`StatusFrame`) picks: the vehicle
frame (YAW_IN_VEHICLE_FRAME), the earth frame (YAW_IN_EARTH_FRAME, with ``delta_yaw`` / ``delta_yaw_velocity``
or with both NaN), or by the older rule without a frame flag (YAW_LOCK set: earth frame; none: vehicle frame),
with the zeros a device predating the extension fields leaves in them. The earth-frame attitude is built here
directly at yaw = relative yaw + heading, not with the host's conversion. The log's states are relative to the
vehicle (the joint angles) whatever the frame.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

from pivotd.compat import StrEnum
from pivotd.firmware_proto.device import Axis
from pivotd.firmware_proto.messages import MODE_DISABLED, MODE_ENABLED, MODE_FAULT, SetpointV1, State
from pivotd.firmware_proto.realtime import CsvMessageLog
from pivotd.gimbal import mavlink_frames as mf
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.mavlink_link import load_mavutil

MAV_COMP_ID_GIMBAL = 154
DEVICE_ID = 1  # manager and device share the component: the device is addressed as 1
CAP_FLAGS = (mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS | mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_FOLLOW
             | mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS | 512)  # 512: HAS_YAW_FOLLOW
SUBSTEP = 0.001  # s


class StatusFrame(StrEnum):
    """The frame GIMBAL_DEVICE_ATTITUDE_STATUS reports yaw in, and what it puts in ``flags`` and ``delta_yaw``."""

    VEHICLE = "vehicle"  # YAW_IN_VEHICLE_FRAME, delta_yaw = the heading
    EARTH = "earth"  # YAW_IN_EARTH_FRAME, delta_yaw = the heading
    EARTH_NO_DELTA = "earth-no-delta"  # YAW_IN_EARTH_FRAME, delta_yaw NaN (the device does not know the heading)
    LEGACY_LOCK = "legacy-lock"  # no frame flag, YAW_LOCK: earth frame; delta_yaw 0 (a field it does not know)
    LEGACY_FOLLOW = "legacy-follow"  # no frame flag, no YAW_LOCK: vehicle frame; delta_yaw 0
    BOTH_FLAGS = "both-flags"  # both frame flags (not allowed; the attitude as in the vehicle frame)


@dataclass
class MavlinkGimbalModel:
    """Manager + device. ``limits``: the device's range in pivotd's convention [rad]; ``vmax`` [rad/s], ``amax``
    [rad/s²] per axis; times in seconds on the caller's clock."""

    limits: JointLimits
    vmax: float = math.radians(180.0)
    amax: float = math.radians(720.0)
    state_hz: float = 50.0
    setpoint_timeout_s: float = 0.25
    system_id: int = 1
    component_id: int = MAV_COMP_ID_GIMBAL
    log: CsvMessageLog | None = None
    pan: Axis = field(default_factory=Axis)
    tilt: Axis = field(default_factory=Axis)
    yaw_frame: StatusFrame = StatusFrame.VEHICLE
    heading: float = 0.0  # the vehicle's heading [rad], NED (clockwise from North)
    heading_rate: float = 0.0  # [rad/s]

    def __post_init__(self) -> None:
        mavutil = load_mavutil()
        self.mavlink = mavutil.mavlink
        self.primary: tuple[int, int] = (0, 0)
        self.failure_flags = 0
        self.failure_until = math.inf
        self.last_setpoint = -math.inf
        self.now = 0.0
        self._started = False
        self._next = {"state": 0.0, "manager": 0.0, "heartbeat": 0.0}
        self.setpoints = 0
        self._timed_out = True

    def _hold_here(self) -> None:
        for ax in (self.pan, self.tilt):
            ax.target, ax.ff_rate = ax.pos, 0.0

    # ----------------------------------------------------------------- input
    def handle(self, msg: Any, now: float, sent_us: int | None = None) -> list[Any]:
        """Answers to one message received at ``now``; ``sent_us``: when the host sent it, on the host's monotonic
        clock [µs] if known (logged as the setpoint's host time; MAVLink setpoints carry none)."""
        self.step(now)
        kind = msg.get_type()
        if kind == "GIMBAL_MANAGER_SET_PITCHYAW":
            self._on_setpoint(msg, now, round(now * 1e6) if sent_us is None else sent_us)
        elif kind == "COMMAND_LONG" and msg.target_component in (0, self.component_id):
            return self._on_command(msg, now)
        return []

    def _on_command(self, msg: Any, now: float) -> list[Any]:
        m = self.mavlink
        src = (msg.get_srcSystem(), msg.get_srcComponent())
        if msg.command == m.MAV_CMD_REQUEST_MESSAGE and int(msg.param1) == m.MAVLINK_MSG_ID_GIMBAL_MANAGER_INFORMATION:
            self._note("rx", "REQUEST_MESSAGE", now, "GIMBAL_MANAGER_INFORMATION")
            return [self._ack(msg, m.MAV_RESULT_ACCEPTED, src), self._information(now)]
        if msg.command == m.MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE:
            sysid, compid = int(msg.param1), int(msg.param2)
            if (sysid, compid) == (-3, -3):
                if self.primary == src:
                    self.primary = (0, 0)
            elif (sysid, compid) == (-2, -2):
                self.primary = src
            elif sysid >= 0 and compid >= 0:
                self.primary = (sysid, compid)
            self._hold_here()  # a new controller starts from where the gimbal is
            self._note("rx", "GIMBAL_MANAGER_CONFIGURE", now, f"primary={sysid}/{compid} on={int(self.enabled)}")
            return [self._ack(msg, m.MAV_RESULT_ACCEPTED, src)]
        return [self._ack(msg, m.MAV_RESULT_UNSUPPORTED, src)]

    def _on_setpoint(self, msg: Any, now: float, sent_us: int) -> None:
        pan, tilt, pan_rate, tilt_rate = mf.from_pitch_yaw(msg.pitch, msg.yaw, msg.pitch_rate, msg.yaw_rate)
        self.setpoints += 1
        if self.log is not None and all(math.isfinite(v) for v in (pan, tilt, pan_rate, tilt_rate)):
            self.log("rx", SetpointV1(pan, tilt, pan_rate, tilt_rate, sent_us & 0xFFFFFFFF), 0, now)
        if (msg.get_srcSystem(), msg.get_srcComponent()) != self.primary or self.failure_flags:
            return
        if not all(math.isfinite(v) for v in (pan, tilt)):
            return
        lim = self.limits
        cpan, ctilt = lim.clamp(pan, tilt)
        self.pan.target, self.tilt.target = cpan, ctilt
        self.pan.ff_rate = pan_rate if cpan == pan and math.isfinite(pan_rate) else 0.0
        self.tilt.ff_rate = tilt_rate if ctilt == tilt and math.isfinite(tilt_rate) else 0.0
        self.last_setpoint = now
        self._timed_out = False

    def inject_failure(self, flags: int, now: float, duration: float) -> None:
        """Set GIMBAL_DEVICE_ERROR_FLAGS ``flags`` for ``duration`` seconds (the device then clears them)."""
        self.failure_flags |= flags
        self.failure_until = now + duration
        self._hold_here()  # once cleared, it does not resume towards a setpoint from before the failure
        self._note("event", "FAILURE", now, f"flags={flags}")

    @property
    def enabled(self) -> bool:
        """Someone is in primary control."""
        return self.primary != (0, 0)

    @property
    def mode(self) -> int:
        """The pivotd mode number this state corresponds to (for the log)."""
        if self.failure_flags & mf.SEVERE_DEVICE_ERRORS:
            return MODE_FAULT
        return MODE_ENABLED if self.enabled else MODE_DISABLED

    # ----------------------------------------------------------------- time
    def step(self, now: float) -> list[Any]:
        """Advance to ``now`` [s]; the periodic messages that fell due."""
        if not self._started:
            self._started = True
            self.now = now
            self._next = dict.fromkeys(self._next, now)
        out: list[Any] = []
        while True:
            kind = min(self._next, key=self._next.__getitem__)
            due = self._next[kind]
            if due > now:
                break
            self._advance(due)
            out.append(self._periodic(kind, due))
            period = {"state": 1.0 / self.state_hz, "manager": 0.2, "heartbeat": 1.0}[kind]
            self._next[kind] = due + period
        self._advance(now)
        return out

    def _advance(self, t: float) -> None:
        while self.now < t:
            dt = min(SUBSTEP, t - self.now)
            self.now += dt
            self.heading += self.heading_rate * dt
            if self.failure_flags and self.now >= self.failure_until:
                self.failure_flags = 0
                self.failure_until = math.inf
            if not self._timed_out and self.now - self.last_setpoint > self.setpoint_timeout_s:
                self._timed_out = True  # setpoints stopped: drop the rate feed-forward, hold where it is
                self._hold_here()
            tracking = self.enabled and not self.failure_flags
            lim = self.limits
            self.pan.advance(dt, self.vmax, self.amax, tracking, lim.pan_min, lim.pan_max)
            self.tilt.advance(dt, self.vmax, self.amax, tracking, lim.tilt_min, lim.tilt_max)

    def _periodic(self, kind: str, now: float) -> Any:
        m = self.mavlink
        boot_ms = int(now * 1000) & 0xFFFFFFFF
        if kind == "heartbeat":
            return m.MAVLink_heartbeat_message(m.MAV_TYPE_GIMBAL, m.MAV_AUTOPILOT_INVALID, 0, 0, m.MAV_STATE_ACTIVE, 3)
        if kind == "manager":
            return m.MAVLink_gimbal_manager_status_message(boot_ms, mf.SETPOINT_FLAGS, DEVICE_ID, *self.primary, 0, 0)
        py = mf.to_pitch_yaw(self.pan.pos, self.tilt.pos, self.pan.vel, self.tilt.vel)  # relative to the vehicle
        flags, earth, delta, delta_rate = self._status_frame()
        if earth:
            py = mf.PitchYaw(py.pitch, py.yaw + self.heading, py.pitch_rate, py.yaw_rate + self.heading_rate)
        q = mf.quaternion_from_pitch_yaw(py.pitch, py.yaw)
        wx, wy, wz = _angular_velocity(py)
        if self.log is not None:
            state = State(round(now * 1e6) & 0xFFFFFFFF, self.pan.pos, self.tilt.pos, self.pan.vel, self.tilt.vel, 0,
                          self.mode, mf.device_faults(self.failure_flags))
            self.log("tx", state, 0, now)
        return m.MAVLink_gimbal_device_attitude_status_message(
            0, 0, boot_ms, flags, q, wx, wy, wz, self.failure_flags, delta, delta_rate, DEVICE_ID)

    def _status_frame(self) -> tuple[int, bool, float, float]:
        """(flags, whether yaw is in the earth frame, delta_yaw [rad], delta_yaw_velocity [rad/s]) of a status."""
        heading = mf.wrap_pi(self.heading)
        both = mf.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME | mf.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME
        return {
            StatusFrame.VEHICLE: (mf.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME, False, heading, self.heading_rate),
            StatusFrame.EARTH: (mf.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME, True, heading, self.heading_rate),
            StatusFrame.EARTH_NO_DELTA: (mf.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME, True, math.nan, math.nan),
            StatusFrame.LEGACY_LOCK: (mf.GIMBAL_DEVICE_FLAGS_YAW_LOCK, True, 0.0, 0.0),
            StatusFrame.LEGACY_FOLLOW: (0, False, 0.0, 0.0),
            StatusFrame.BOTH_FLAGS: (both, False, heading, self.heading_rate),
        }[self.yaw_frame]

    def _information(self, now: float) -> Any:
        m, lim = self.mavlink, self.limits
        return m.MAVLink_gimbal_manager_information_message(
            int(now * 1000) & 0xFFFFFFFF, CAP_FLAGS, DEVICE_ID, 0.0, 0.0, -lim.tilt_max, -lim.tilt_min, -lim.pan_max,
            -lim.pan_min)

    def _ack(self, msg: Any, result: int, src: tuple[int, int]) -> Any:
        m = self.mavlink
        return m.MAVLink_command_ack_message(msg.command, result, 0, 0, src[0], src[1])

    def _note(self, direction: str, name: str, now: float, detail: str) -> None:
        if self.log is not None:
            self.log.note(direction, name, now, detail)


def _angular_velocity(py: mf.PitchYaw) -> tuple[float, float, float]:
    """Angular velocity (FRD vehicle frame) [rad/s] of a zero-roll camera moving at the pitch/yaw rates."""
    return (-math.sin(py.yaw) * py.pitch_rate, math.cos(py.yaw) * py.pitch_rate, py.yaw_rate)
