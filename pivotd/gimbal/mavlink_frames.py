"""pivotd's pan/tilt convention ↔ MAVLink Gimbal Protocol v2 angles, the one place where they are converted.

pivotd (REP-103 base frame, x forward, y left, z up): pan about +z (positive turns left), tilt about the panned
+y (positive looks down). MAVLink (FRD vehicle frame, x forward, y right, z down): yaw positive to the right,
pitch positive up. Hence ``yaw = −pan`` and ``pitch = −tilt`` (rates alike). Attitude quaternions are
(w, x, y, z), the rotation of the camera frame in the FRD vehicle frame, Euler order Z-Y-X (yaw, pitch, roll).

Also here: GIMBAL_DEVICE_ERROR_FLAGS → pivotd's fault bits, and the flags pivotd streams with.
Pure functions, no I/O.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

from firmware_proto.messages import FAULT_DRIVER, FAULT_ENCODER, FAULT_UNDERVOLTAGE
from pivotd.gimbal.kinematics import JointLimits

# --- common.xml values (checked byte for byte against the published definitions in tests/test_mavlink_golden.py)
GIMBAL_MANAGER_FLAGS_YAW_IN_VEHICLE_FRAME = 32
GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS = 32
GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_FOLLOW = 64
GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS = 256
GIMBAL_MANAGER_CAP_FLAGS_SUPPORTS_INFINITE_YAW = 2048
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


def joints_from_attitude(q: tuple[float, float, float, float] | list[float], wx: float, wy: float,
                         wz: float) -> tuple[float, float, float, float]:
    """(pan, tilt, pan_rate, tilt_rate) from a GIMBAL_DEVICE_ATTITUDE_STATUS quaternion (w, x, y, z) and angular
    velocity [rad/s] in the vehicle frame; rates are NaN when the device does not know them."""
    pitch, yaw = pitch_yaw_from_quaternion(q)
    pan, tilt, _, _ = from_pitch_yaw(pitch, yaw)
    pan_rate, tilt_rate = joint_rates_from_angular_velocity(wx, wy, wz, yaw)
    return pan, tilt, pan_rate, tilt_rate


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
