"""DYNAMIXEL X-series (e.g. XM430-W350, XL430-W250; Protocol 2.0) control-table subset and unit conversions.

Addresses and sizes are those of the X-series e-Manual; positions are 4096 ticks per turn, 0–4095 in Position
Control Mode. A joint angle of 0 is the axis' zero tick (2048, the servo's centre, unless
``gimbal.dynamixel.*_zero_tick`` says otherwise). Pure data and functions, no I/O.
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
MAX_TICK = TICKS_PER_REV - 1  # Position Control Mode: Goal Position and the Position Limits lie in 0–4095
FACTORY_BAUD = 57600  # Baud Rate (8) = 1, the X-series factory setting
VELOCITY_UNIT = 0.229 * 2 * math.pi / 60  # rad/s per Profile/Present Velocity unit (0.229 rev/min)
ACCELERATION_UNIT = 214.577 * 2 * math.pi / 3600  # rad/s² per Profile Acceleration unit (214.577 rev/min²)
WATCHDOG_UNIT_MS = 20  # Bus Watchdog unit; 1–127 arms it, 0 disarms, 255 reads back once it expired
WATCHDOG_EXPIRED = 0xFF
POSITION_RESOLUTION = 2 * math.pi / TICKS_PER_REV  # rad per tick

#: Hardware Error Status bits → pivotd fault bits
_HARDWARE_ERRORS = ((1 << 0, FAULT_UNDERVOLTAGE), (1 << 2, FAULT_OVERTEMP), (1 << 3, FAULT_ENCODER),
                    (1 << 4, FAULT_DRIVER), (1 << 5, FAULT_OVERCURRENT))


def angle_to_ticks(angle: float, reversed_axis: bool = False, zero: int = CENTRE_TICKS) -> int:
    """Joint angle [rad] → servo position [ticks]: ``zero`` is the tick of angle 0; positive angle =
    counter-clockwise seen from the horn, unless ``reversed_axis``."""
    sign = -1.0 if reversed_axis else 1.0
    return round(zero + sign * angle / POSITION_RESOLUTION)


def ticks_to_angle(ticks: int, reversed_axis: bool = False, zero: int = CENTRE_TICKS) -> float:
    """Servo position [ticks] → joint angle [rad] (``zero``: the tick of angle 0)."""
    sign = -1.0 if reversed_axis else 1.0
    return sign * (ticks - zero) * POSITION_RESOLUTION


def limits_to_ticks(lo: float, hi: float, reversed_axis: bool = False, zero: int = CENTRE_TICKS) -> tuple[int, int]:
    """Joint range [rad] → (Min, Max Position Limit) [ticks], rounded inwards so that no tick inside them lies
    outside the range (``zero``: the tick of angle 0)."""
    sign = -1.0 if reversed_axis else 1.0
    a, b = zero + sign * lo / POSITION_RESOLUTION, zero + sign * hi / POSITION_RESOLUTION
    return math.ceil(min(a, b) - 1e-9), math.floor(max(a, b) + 1e-9)


def position_limits_problem(axis: str, lo: float, hi: float, reversed_axis: bool = False,
                            zero: int = CENTRE_TICKS) -> str | None:
    """Why the joint range [``lo``, ``hi``] [rad] of ``axis`` cannot be Position Limits around tick ``zero``
    (they must lie in 0–4095), or None."""
    tmin, tmax = limits_to_ticks(lo, hi, reversed_axis, zero)
    if tmin >= 0 and tmax <= MAX_TICK:
        return None
    ends = sorted(ticks_to_angle(t, reversed_axis, zero) for t in (0, MAX_TICK))
    return (f"{axis} limits [{math.degrees(lo):g}, {math.degrees(hi):g}]° are ticks [{tmin}, {tmax}] around zero "
            f"tick {zero}, outside the servo's 0–{MAX_TICK}: Position Control Mode reaches only "
            f"[{math.degrees(ends[0]):.1f}, {math.degrees(ends[1]):.1f}]° (at zero tick 2048: within ±180°)")


def bus_cycle_s(baud: int, servos: int = 2, read_length: int = PRESENT_POSITION[0] + PRESENT_POSITION[1]
                - TORQUE_ENABLE[0]) -> float:
    """Time on the wire [s] of one control period's traffic at ``baud``: a Sync Write of the Goal Positions and a
    Sync Read of ``read_length`` bytes with its status packets, 10 bit times a byte; a lower bound (the servos'
    Return Delay Time, 500 µs each at the factory setting, and the adapter's latency come on top)."""
    packet = 10  # header 4, id 1, length 2, instruction 1, CRC 2
    sync_write = packet + 4 + servos * (1 + GOAL_POSITION[1])
    sync_read = packet + 4 + servos
    status = servos * (packet + 1 + read_length)  # + the error byte
    return (sync_write + sync_read + status) * 10 / baud


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
