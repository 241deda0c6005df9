"""DYNAMIXEL X-series (e.g. XM430-W350, XL430-W250; Protocol 2.0) control-table subset and unit conversions.

Addresses and sizes are those of the X-series e-Manual; positions are 4096 ticks per turn with 2048 at the
centre (Position Control Mode: 0–4095, ±180°). Pure data and functions, no I/O.
"""

from __future__ import annotations

import math

from pivotd.firmware_proto.messages import (
    FAULT_DRIVER,
    FAULT_ENCODER,
    FAULT_OVERCURRENT,
    FAULT_OVERTEMP,
    FAULT_UNDERVOLTAGE,
)

# (address, size in bytes)
MODEL_NUMBER, FIRMWARE_VERSION, OPERATING_MODE = (0, 2), (6, 1), (11, 1)
MAX_POSITION_LIMIT, MIN_POSITION_LIMIT = (48, 4), (52, 4)
TORQUE_ENABLE, HARDWARE_ERROR_STATUS, BUS_WATCHDOG = (64, 1), (70, 1), (98, 1)
PROFILE_ACCELERATION, PROFILE_VELOCITY, GOAL_POSITION = (108, 4), (112, 4), (116, 4)
PRESENT_VELOCITY, PRESENT_POSITION = (128, 4), (132, 4)
EEPROM_END = 64  # addresses below are EEPROM: writable only with the torque off

POSITION_CONTROL_MODE = 3
TICKS_PER_REV = 4096
CENTRE_TICKS = 2048
VELOCITY_UNIT = 0.229 * 2 * math.pi / 60  # rad/s per Profile/Present Velocity unit (0.229 rev/min)
ACCELERATION_UNIT = 214.577 * 2 * math.pi / 3600  # rad/s² per Profile Acceleration unit (214.577 rev/min²)
WATCHDOG_UNIT_MS = 20  # Bus Watchdog unit; 1–127 arms it, 0 disarms, 255 reads back once it expired
WATCHDOG_EXPIRED = 0xFF
POSITION_RESOLUTION = 2 * math.pi / TICKS_PER_REV  # rad per tick

#: Hardware Error Status bits → pivotd fault bits
_HARDWARE_ERRORS = ((1 << 0, FAULT_UNDERVOLTAGE), (1 << 2, FAULT_OVERTEMP), (1 << 3, FAULT_ENCODER),
                    (1 << 4, FAULT_DRIVER), (1 << 5, FAULT_OVERCURRENT))


def angle_to_ticks(angle: float, reversed_axis: bool = False) -> int:
    """Joint angle [rad] → servo position [ticks] (positive angle = counter-clockwise seen from the horn, unless
    ``reversed_axis``)."""
    sign = -1.0 if reversed_axis else 1.0
    return round(CENTRE_TICKS + sign * angle / POSITION_RESOLUTION)


def ticks_to_angle(ticks: int, reversed_axis: bool = False) -> float:
    """Servo position [ticks] → joint angle [rad]."""
    sign = -1.0 if reversed_axis else 1.0
    return sign * (ticks - CENTRE_TICKS) * POSITION_RESOLUTION


def limits_to_ticks(lo: float, hi: float, reversed_axis: bool = False) -> tuple[int, int]:
    """Joint range [rad] → (Min, Max Position Limit) [ticks], rounded inwards so that no tick inside them lies
    outside the range."""
    sign = -1.0 if reversed_axis else 1.0
    a, b = CENTRE_TICKS + sign * lo / POSITION_RESOLUTION, CENTRE_TICKS + sign * hi / POSITION_RESOLUTION
    return math.ceil(min(a, b) - 1e-9), math.floor(max(a, b) + 1e-9)


def velocity_units(rad_s: float) -> int:
    """Profile Velocity for a rate limit [rad/s], at least 1 (0 would mean unlimited)."""
    return max(1, math.floor(rad_s / VELOCITY_UNIT))


def acceleration_units(rad_s2: float) -> int:
    """Profile Acceleration for an acceleration limit [rad/s²], at least 1 (0 would mean unlimited)."""
    return max(1, math.floor(rad_s2 / ACCELERATION_UNIT))


def watchdog_units(ms: float) -> int:
    """Bus Watchdog value for a timeout [ms]: rounded up to 20 ms steps, 1–127."""
    return min(127, max(1, math.ceil(ms / WATCHDOG_UNIT_MS)))


def hardware_faults(status: int) -> int:
    """pivotd fault bits for a Hardware Error Status byte."""
    out = 0
    for bit, fault in _HARDWARE_ERRORS:
        if status & bit:
            out |= fault
    return out
