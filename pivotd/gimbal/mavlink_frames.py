"""pivotd's pan/tilt convention ↔ MAVLink Gimbal Protocol v2 angles, the one place where they are converted.

pivotd (REP-103 base frame, x forward, y left, z up): pan about +z (positive turns left), tilt about the panned
+y (positive looks down). MAVLink (FRD vehicle frame, x forward, y right, z down): yaw positive to the right,
pitch positive up. Hence ``yaw = −pan`` and ``pitch = −tilt`` (rates alike). Attitude quaternions are
(w, x, y, z), the rotation of the camera frame in the FRD vehicle frame, Euler order Z-Y-X (yaw, pitch, roll).

GIMBAL_DEVICE_ATTITUDE_STATUS reports that attitude either in the vehicle frame or in the earth frame (NED, yaw
from North), as its ``flags`` say (:func:`yaw_frame`). The two differ by a turn about the down axis by the
vehicle's heading ``delta_yaw`` (NED, clockwise from North): ``q_earth = q_delta_yaw · q_vehicle``, and the
angular velocities ``ω_earth = Rz(delta_yaw) ω_vehicle + delta_yaw_velocity ẑ`` (the message's
``w_earth = w_delta_yaw_velocity + w_vehicle``, with ``w_vehicle`` turned into the earth axes);
:func:`joints_from_attitude` undoes it. Pitch and roll are the same in both frames.

Also here: GIMBAL_DEVICE_ERROR_FLAGS → pivotd's fault bits, and the flags pivotd streams with.
Pure functions, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from pivotd.compat import StrEnum
from pivotd.firmware_proto.messages import FAULT_DRIVER, FAULT_ENCODER, FAULT_UNDERVOLTAGE
from pivotd.gimbal.kinematics import JointLimits

# --- common.xml values (checked byte for byte against the published definitions in tests/test_mavlink_golden.py)
GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME = 32
GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS = 32
GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_FOLLOW = 64
GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS = 256
GIMBAL_MANAGER_CAP_FLAGS_SUPPORTS_INFINITE_YAW = 2048
GIMBAL_DEVICE_FLAGS_YAW_LOCK = 16
GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME = 32
GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME = 64
GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR = 8
GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR = 16
GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR = 32
GIMBAL_DEVICE_ERROR_FLAGS_SOFTWARE_ERROR = 64
GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR = 128
GIMBAL_DEVICE_ERROR_FLAGS_CALIBRATION_RUNNING = 256

#: pivotd streams angles relative to the vehicle on every axis (no lock: pitch and yaw follow the vehicle),
#: because the control loop compensates the body attitude itself, at control rate.
SETPOINT_FLAGS = GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME

#: device failures that stop motion, and the pivotd fault bit each one becomes
_FAULT_MAP = (
    (GIMBAL_DEVICE_ERROR_FLAGS_ENCODER_ERROR, FAULT_ENCODER),
    (GIMBAL_DEVICE_ERROR_FLAGS_POWER_ERROR, FAULT_UNDERVOLTAGE),
    (GIMBAL_DEVICE_ERROR_FLAGS_MOTOR_ERROR, FAULT_DRIVER),
    (GIMBAL_DEVICE_ERROR_FLAGS_SOFTWARE_ERROR, FAULT_DRIVER),
    (GIMBAL_DEVICE_ERROR_FLAGS_COMMS_ERROR, FAULT_DRIVER),
)
SEVERE_DEVICE_ERRORS = 0
for _flag, _ in _FAULT_MAP:
    SEVERE_DEVICE_ERRORS |= _flag


class YawFrame(StrEnum):
    """The frame of a GIMBAL_DEVICE_ATTITUDE_STATUS's yaw, from its ``flags`` (:func:`yaw_frame`)."""

    VEHICLE = "vehicle"  # relative to the vehicle heading
    EARTH = "earth"  # relative to North; delta_yaw / delta_yaw_velocity give the vehicle heading (NaN: unknown)
    EARTH_LEGACY = "earth-legacy"  # relative to North by the older YAW_LOCK rule: delta_yaw is to be ignored
    INVALID = "invalid"  # both frame flags set: not allowed


def yaw_frame(flags: int) -> YawFrame:
    """The frame a GIMBAL_DEVICE_ATTITUDE_STATUS with GIMBAL_DEVICE_FLAGS ``flags`` reports yaw in (common.xml):
    YAW_IN_VEHICLE_FRAME (32) or YAW_IN_EARTH_FRAME (64); neither set: earth if YAW_LOCK (16), else vehicle."""
    vehicle = bool(flags & GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME)
    earth = bool(flags & GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME)
    if vehicle and earth:
        return YawFrame.INVALID
    if vehicle:
        return YawFrame.VEHICLE
    if earth:
        return YawFrame.EARTH
    return YawFrame.EARTH_LEGACY if flags & GIMBAL_DEVICE_FLAGS_YAW_LOCK else YawFrame.VEHICLE


@dataclass(frozen=True)
class PitchYaw:
    """A MAVLink pitch/yaw pair [rad] and their rates [rad/s] (pitch positive up, yaw positive right)."""

    pitch: float
    yaw: float
    pitch_rate: float
    yaw_rate: float


def to_pitch_yaw(pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> PitchYaw:
    """pivotd joint angles [rad] and rates [rad/s] → MAVLink pitch/yaw in the vehicle frame."""
    return PitchYaw(pitch=-tilt, yaw=-pan, pitch_rate=-tilt_rate, yaw_rate=-pan_rate)


def from_pitch_yaw(pitch: float, yaw: float, pitch_rate: float = 0.0, yaw_rate: float = 0.0) -> tuple[float, ...]:
    """MAVLink pitch/yaw [rad] and rates [rad/s] → (pan, tilt, pan_rate, tilt_rate)."""
    return -yaw, -pitch, -yaw_rate, -pitch_rate


def quaternion_from_pitch_yaw(pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of Rz(yaw)·Ry(pitch) in the FRD frame (zero roll)."""
    cy, sy = math.cos(yaw / 2), math.sin(yaw / 2)
    cp, sp = math.cos(pitch / 2), math.sin(pitch / 2)
    return cy * cp, -sy * sp, cy * sp, sy * cp


def pitch_yaw_from_quaternion(q: tuple[float, float, float, float] | list[float]) -> tuple[float, float]:
    """(pitch, yaw) [rad] of the Z-Y-X Euler angles of the (w, x, y, z) quaternion ``q`` (normalised here)."""
    w, x, y, z = (float(c) for c in q)
    n = math.sqrt(w * w + x * x + y * y + z * z)
    if not n > 0 or not math.isfinite(n):
        raise ValueError(f"not a rotation quaternion: {q!r}")
    w, x, y, z = w / n, x / n, y / n, z / n
    pitch = math.asin(max(-1.0, min(1.0, 2.0 * (w * y - z * x))))
    yaw = math.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))
    return pitch, yaw


def joint_rates_from_angular_velocity(wx: float, wy: float, wz: float, yaw: float) -> tuple[float, float]:
    """(pan_rate, tilt_rate) [rad/s] from the angular velocity (FRD vehicle frame) [rad/s] of a camera at ``yaw``
    with zero roll: yaw rate = ω_z, pitch rate = ω · Rz(yaw) ŷ. NaN components (unknown) give NaN rates."""
    yaw_rate = wz
    pitch_rate = -math.sin(yaw) * wx + math.cos(yaw) * wy
    return -yaw_rate, -pitch_rate


def yawed(q: tuple[float, float, float, float] | list[float], angle: float) -> tuple[float, float, float, float]:
    """(w, x, y, z) of Rz(``angle``)·q: the rotation ``q`` turned by ``angle`` [rad] about the frame's z axis
    (FRD/NED: down, so positive turns right)."""
    w, x, y, z = (float(c) for c in q)
    c, s = math.cos(angle / 2), math.sin(angle / 2)
    return c * w - s * z, c * x - s * y, c * y + s * x, c * z + s * w


def vehicle_from_earth(q: tuple[float, float, float, float] | list[float], wx: float, wy: float, wz: float,
                       delta_yaw: float, delta_yaw_rate: float) -> tuple[tuple[float, float, float, float], float,
                                                                          float, float]:
    """(q, ωx, ωy, ωz) in the vehicle frame from an attitude (w, x, y, z) and angular velocity [rad/s] in the
    earth frame, for a vehicle at heading ``delta_yaw`` [rad] (NED, clockwise from North) turning at
    ``delta_yaw_rate`` [rad/s] (NaN: unknown, then ωz is NaN): ``q_vehicle = q_delta_yaw⁻¹ · q_earth``,
    ``ω_vehicle = Rz(−delta_yaw) (ω_earth − delta_yaw_rate ẑ)``."""
    c, s = math.cos(delta_yaw), math.sin(delta_yaw)
    return yawed(q, -delta_yaw), c * wx + s * wy, -s * wx + c * wy, wz - delta_yaw_rate


def joints_from_attitude(q: tuple[float, float, float, float] | list[float], wx: float, wy: float,
                         wz: float, delta_yaw: float = 0.0,
                         delta_yaw_rate: float = 0.0) -> tuple[float, float, float, float]:
    """(pan, tilt, pan_rate, tilt_rate) from a GIMBAL_DEVICE_ATTITUDE_STATUS quaternion (w, x, y, z) and angular
    velocity [rad/s]: in the vehicle frame (the defaults), or in the earth frame with the vehicle's heading
    ``delta_yaw`` [rad] and its rate ``delta_yaw_rate`` [rad/s] (:func:`vehicle_from_earth`); rates are NaN when
    the device (or, for the pan rate, ``delta_yaw_rate``) does not know them. Pan comes out in [−π, π)."""
    if delta_yaw or delta_yaw_rate:
        q, wx, wy, wz = vehicle_from_earth(q, wx, wy, wz, delta_yaw, delta_yaw_rate)
    pitch, yaw = pitch_yaw_from_quaternion(q)
    pan, tilt, _, _ = from_pitch_yaw(pitch, yaw)
    pan_rate, tilt_rate = joint_rates_from_angular_velocity(wx, wy, wz, yaw)
    return pan, tilt, pan_rate, tilt_rate


def heading_from_body_quat(quat: tuple[float, float, float, float] | list[float]) -> float:
    """The MAVLink heading [rad] (NED: clockwise from North, in (−π, π]) of a body at attitude ``quat`` (x, y, z, w)
    in a REP-103 world frame whose x axis points East (ENU): the direction of the body's forward axis,
    ``atan2(east, north)``. A world frame not aligned with East needs its own yaw offset added."""
    x, y, z, w = (float(c) for c in quat)
    east = 1.0 - 2.0 * (y * y + z * z)  # first column of the rotation matrix: the forward axis in ENU
    north = 2.0 * (x * y + z * w)
    return math.atan2(east, north)


def device_faults(failure_flags: int) -> int:
    """pivotd fault bits for a GIMBAL_DEVICE_ATTITUDE_STATUS ``failure_flags`` (limit flags are not faults)."""
    out = 0
    for flag, bit in _FAULT_MAP:
        if failure_flags & flag:
            out |= bit
    return out


def joint_limits_from_manager(pitch_min: float, pitch_max: float, yaw_min: float, yaw_max: float) -> JointLimits:
    """The pan/tilt ranges [rad] a gimbal manager reports (GIMBAL_MANAGER_INFORMATION) as pivotd joint limits."""
    return JointLimits(pan_min=-yaw_max, pan_max=-yaw_min, tilt_min=-pitch_max, tilt_max=-pitch_min)


def limits_problem(ours: JointLimits, device: JointLimits, infinite_yaw: bool) -> str | None:
    """Why the configured joint limits do not fit the device's (None when they do), in degrees."""
    eps = 1e-4

    def span(lo: float, hi: float) -> str:
        return f"[{math.degrees(lo):.1f}, {math.degrees(hi):.1f}] deg"

    if ours.continuous_pan and not infinite_yaw:
        return "gimbal.limits.continuous_pan is set but the gimbal manager does not support infinite yaw"
    if not ours.continuous_pan and (ours.pan_min < device.pan_min - eps or ours.pan_max > device.pan_max + eps):
        return f"gimbal.limits pan {span(ours.pan_min, ours.pan_max)} exceeds the device's " \
               f"{span(device.pan_min, device.pan_max)}"
    if ours.tilt_min < device.tilt_min - eps or ours.tilt_max > device.tilt_max + eps:
        return f"gimbal.limits tilt {span(ours.tilt_min, ours.tilt_max)} exceeds the device's " \
               f"{span(device.tilt_min, device.tilt_max)}"
    return None


def wrap_pi(angle: float) -> float:
    """``angle`` [rad] wrapped to (−π, π]."""
    out = math.remainder(angle, 2.0 * math.pi)
    return math.pi if out == -math.pi else out
