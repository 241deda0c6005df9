"""A chain of DYNAMIXEL X-series servos (Protocol 2.0, the control-table subset pivotd uses), for tests.

Pure and steppable: ``feed(data, now)`` answers instruction packets (PING, READ, WRITE, SYNC_WRITE, SYNC_READ,
REBOOT) with status packets; ``step(now)`` moves the servos (each in its own frame: tick 2048 is its angle 0).
In Position Control Mode with torque on, a servo follows Goal Position with the profile's velocity and
acceleration, inside Min/Max Position Limit. EEPROM (addresses < 64) can only be written with torque off. Bus
Watchdog (units of 20 ms): no instruction packet for that long → the servo stops and the watchdog reads 255
until 0 is written; goal writes are refused meanwhile.
A hardware error (``inject_error``) turns the torque off and sets the alert bit in every status packet until
REBOOT. With two servos as pan and tilt, setpoints (goal positions) and states are logged in pivotd's
convention to the serial mock's CSV: joint angles around each axis' zero tick, with its direction (what
``gimbal.dynamixel.*_zero_tick`` / ``*_reversed`` of the host say; the servos' behaviour does not depend on it).
"""

from __future__ import annotations

import math
import struct
from dataclasses import dataclass, field

from pivotd.firmware_proto.device import Axis
from pivotd.firmware_proto.messages import MODE_DISABLED, MODE_ENABLED, MODE_FAULT, State
from pivotd.firmware_proto.realtime import CsvMessageLog
from pivotd.gimbal.dynamixel_table import (
    ACCELERATION_UNIT,
    BUS_WATCHDOG,
    CENTRE_TICKS,
    EEPROM_END,
    FIRMWARE_VERSION,
    GOAL_POSITION,
    HARDWARE_ERROR_STATUS,
    MAX_POSITION_LIMIT,
    MIN_POSITION_LIMIT,
    MODEL_NUMBER,
    OPERATING_MODE,
    POSITION_CONTROL_MODE,
    POSITION_RESOLUTION,
    PRESENT_POSITION,
    PRESENT_VELOCITY,
    PROFILE_ACCELERATION,
    PROFILE_VELOCITY,
    TORQUE_ENABLE,
    VELOCITY_UNIT,
    WATCHDOG_EXPIRED,
    WATCHDOG_UNIT_MS,
    angle_to_ticks,
    hardware_faults,
    ticks_to_angle,
)
from pivotd.sim import dynamixel_protocol as dp

TABLE_SIZE = 147
MODEL_XM430_W350 = 1020
NO_LOAD_SPEED = 46 * 2 * math.pi / 60  # rad/s: profile velocity 0 means "as fast as the motor goes"
MAX_ACCELERATION = 100.0  # rad/s²: profile acceleration 0 (infinite) as the simulated motor's limit


@dataclass
class Servo:
    """One servo: its control table and its axis."""

    dxl_id: int
    table: bytearray = field(default_factory=lambda: bytearray(TABLE_SIZE))
    axis: Axis = field(default_factory=lambda: Axis(pos=0.0))
    last_packet: float = 0.0

    def __post_init__(self) -> None:
        self.reset()

    def reset(self) -> None:
        """Power-on / REBOOT: RAM back to defaults, EEPROM kept, errors cleared, torque off."""
        eeprom = bytes(self.table[:EEPROM_END])
        self.table[:] = bytearray(TABLE_SIZE)
        self.table[:EEPROM_END] = eeprom
        self.set(MODEL_NUMBER, MODEL_XM430_W350)
        self.set(FIRMWARE_VERSION, 48)
        self.table[7] = self.dxl_id
        if self.get(OPERATING_MODE) == 0 and self.get(MAX_POSITION_LIMIT) == 0:
            self.set(OPERATING_MODE, POSITION_CONTROL_MODE)
            self.set(MAX_POSITION_LIMIT, 4095)
        self.axis.vel = 0.0
        self.axis.target, self.axis.ff_rate = self.axis.pos, 0.0
        self.set(GOAL_POSITION, angle_to_ticks(self.axis.pos))
        self._present()

    def get(self, item: tuple[int, int], signed: bool = False) -> int:
        addr, size = item
        return int.from_bytes(self.table[addr:addr + size], "little", signed=signed)

    def set(self, item: tuple[int, int], value: int) -> None:
        addr, size = item
        self.table[addr:addr + size] = (value & ((1 << (8 * size)) - 1)).to_bytes(size, "little")

    @property
    def torque(self) -> bool:
        return bool(self.get(TORQUE_ENABLE))

    @property
    def watchdog_expired(self) -> bool:
        return self.get(BUS_WATCHDOG) == WATCHDOG_EXPIRED

    def write(self, addr: int, data: bytes) -> int:
        """WRITE; the status error number (0: done)."""
        end = addr + len(data)
        if end > TABLE_SIZE:
            return dp.ERR_DATA_LENGTH
        if addr < EEPROM_END and self.torque:
            return dp.ERR_ACCESS
        if addr <= GOAL_POSITION[0] < end and self.watchdog_expired:
            return dp.ERR_DATA_RANGE
        if addr <= BUS_WATCHDOG[0] < end:
            w = data[BUS_WATCHDOG[0] - addr]
            if w > 127:
                return dp.ERR_DATA_RANGE
        if addr <= GOAL_POSITION[0] < end:
            goal = struct.unpack_from("<i", data, GOAL_POSITION[0] - addr)[0]
            if not self.get(MIN_POSITION_LIMIT) <= goal <= self.get(MAX_POSITION_LIMIT):
                return dp.ERR_DATA_LIMIT
        was_on = self.torque
        self.table[addr:end] = data
        if self.torque and not was_on:  # torque on: hold where it is (Goal Position is what the host wrote)
            self.axis.vel = 0.0
        return 0

    def advance(self, dt: float) -> None:
        a = self.axis
        vmax = self.get(PROFILE_VELOCITY) * VELOCITY_UNIT or NO_LOAD_SPEED
        amax = self.get(PROFILE_ACCELERATION) * ACCELERATION_UNIT or MAX_ACCELERATION
        lo, hi = ticks_to_angle(self.get(MIN_POSITION_LIMIT)), ticks_to_angle(self.get(MAX_POSITION_LIMIT))
        tracking = self.torque and not self.watchdog_expired and not self.get(HARDWARE_ERROR_STATUS)
        a.target = ticks_to_angle(self.get(GOAL_POSITION, signed=True))
        a.advance(dt, vmax, amax, tracking, lo, hi)
        self._present()

    def _present(self) -> None:
        self.set(PRESENT_POSITION, angle_to_ticks(self.axis.pos))
        self.set(PRESENT_VELOCITY, round(self.axis.vel / VELOCITY_UNIT))


@dataclass
class DynamixelChain:
    """Servos on one bus; ``pan_id``/``tilt_id`` name the two that are logged as a pan–tilt unit, with joint angle 0
    at ``zero_ticks`` (pan, tilt) and the directions ``reversed_axes`` (pan, tilt)."""

    ids: tuple[int, ...] = (1, 2)
    pan_id: int = 1
    tilt_id: int = 2
    state_hz: float = 50.0
    log: CsvMessageLog | None = None
    zero_ticks: tuple[int, int] = (CENTRE_TICKS, CENTRE_TICKS)
    reversed_axes: tuple[bool, bool] = (False, False)

    def __post_init__(self) -> None:
        self.servos = {i: Servo(i) for i in self.ids}
        self.decoder = dp.PacketDecoder()
        self.now = 0.0
        self._started = False
        self._next_state = 0.0
        self.packets = 0

    def feed(self, data: bytes, now: float, sent_us: int | None = None) -> bytes:
        """Answers (status packets) to the instruction packets in ``data`` received at ``now``. Bytes that waited
        in the port while the simulator was not scheduled count as received at ``now`` for the watchdog (the host
        was not silent)."""
        pkts = self.decoder.feed(data)
        if pkts:
            for servo in self.servos.values():
                servo.last_packet = max(servo.last_packet, now) if self._started else servo.last_packet
        self.step(now)
        out = b""
        for pkt in pkts:
            self.packets += 1
            for servo in self.servos.values():
                servo.last_packet = now
            out += self._handle(pkt, now, round(now * 1e6) if sent_us is None else sent_us)
        return out

    def _status(self, servo: Servo, error: int, params: bytes = b"") -> bytes:
        alert = dp.ERR_ALERT if servo.get(HARDWARE_ERROR_STATUS) else 0
        return dp.status(servo.dxl_id, error | alert, params)

    def _handle(self, pkt: dp.Packet, now: float, sent_us: int) -> bytes:
        p = pkt.params
        if pkt.inst == dp.INST_SYNC_WRITE:
            addr, size = struct.unpack_from("<HH", p)
            for off in range(4, len(p) - size + 1, size + 1):
                servo = self.servos.get(p[off])
                if servo is not None:
                    servo.write(addr, p[off + 1:off + 1 + size])
            if addr == GOAL_POSITION[0] and size == GOAL_POSITION[1]:
                self._log_setpoint(now, sent_us)
            return b""
        if pkt.inst == dp.INST_SYNC_READ:
            addr, size = struct.unpack_from("<HH", p)
            out = b""
            for dxl_id in p[4:]:
                servo = self.servos.get(dxl_id)
                if servo is not None:
                    out += self._status(servo, 0, bytes(servo.table[addr:addr + size]))
            return out
        servo = self.servos.get(pkt.dxl_id)
        if servo is None:
            return b""
        if pkt.inst == dp.INST_PING:
            return self._status(servo, 0, struct.pack("<HB", servo.get(MODEL_NUMBER), servo.get(FIRMWARE_VERSION)))
        if pkt.inst == dp.INST_READ:
            addr, size = struct.unpack_from("<HH", p)
            if addr + size > TABLE_SIZE:
                return self._status(servo, dp.ERR_DATA_LENGTH)
            return self._status(servo, 0, bytes(servo.table[addr:addr + size]))
        if pkt.inst == dp.INST_WRITE:
            addr = struct.unpack_from("<H", p)[0]
            err = servo.write(addr, p[2:])
            if self.log is not None and addr <= TORQUE_ENABLE[0] < addr + len(p) - 2:
                self.log.note("rx", "TORQUE_ENABLE", now, f"id={servo.dxl_id} on={servo.get(TORQUE_ENABLE)}")
            return self._status(servo, err)
        if pkt.inst == dp.INST_REBOOT:
            servo.reset()
            if self.log is not None:
                self.log.note("rx", "REBOOT", now, f"id={servo.dxl_id}")
            return self._status(servo, 0)
        return self._status(servo, dp.ERR_INSTRUCTION)

    def inject_error(self, dxl_id: int, bits: int, now: float) -> None:
        """Latch Hardware Error Status ``bits`` on servo ``dxl_id``: torque off until REBOOT."""
        servo = self.servos[dxl_id]
        servo.set(HARDWARE_ERROR_STATUS, servo.get(HARDWARE_ERROR_STATUS) | bits)
        servo.set(TORQUE_ENABLE, 0)
        if self.log is not None:
            self.log.note("event", "HARDWARE_ERROR", now, f"id={dxl_id} bits={bits}")

    def step(self, now: float) -> None:
        """Advance the servos to ``now`` [s] (and log the pan–tilt state at ``state_hz``)."""
        if not self._started:
            self._started = True
            self.now = self._next_state = now
            for servo in self.servos.values():
                servo.last_packet = now
        while self.now < now:
            dt = min(0.001, now - self.now)
            self.now += dt
            for servo in self.servos.values():
                w = servo.get(BUS_WATCHDOG)
                if 0 < w <= 127 and self.now - servo.last_packet > w * WATCHDOG_UNIT_MS / 1000.0:
                    servo.set(BUS_WATCHDOG, WATCHDOG_EXPIRED)
                    servo.set(GOAL_POSITION, angle_to_ticks(servo.axis.pos))
                servo.advance(dt)
            if self.now >= self._next_state:
                self._next_state += 1.0 / self.state_hz
                self._log_state(self.now)

    def _pan_tilt(self) -> tuple[Servo, Servo] | None:
        pan, tilt = self.servos.get(self.pan_id), self.servos.get(self.tilt_id)
        return None if pan is None or tilt is None else (pan, tilt)

    def _log_setpoint(self, now: float, sent_us: int) -> None:
        pt = self._pan_tilt()
        if self.log is None or pt is None:
            return
        pan, tilt = (ticks_to_angle(s.get(GOAL_POSITION, signed=True), rev, zero)
                     for s, rev, zero in zip(pt, self.reversed_axes, self.zero_ticks, strict=True))
        self.log.angles("rx", "SETPOINT", now, pan, tilt, math.nan, math.nan, host_time_us=sent_us & 0xFFFFFFFF)

    def _log_state(self, now: float) -> None:
        pt = self._pan_tilt()
        if self.log is None or pt is None:
            return
        pan, tilt = pt
        errors = pan.get(HARDWARE_ERROR_STATUS) | tilt.get(HARDWARE_ERROR_STATUS)
        mode = MODE_FAULT if errors else MODE_ENABLED if pan.torque and tilt.torque else MODE_DISABLED
        (p, pv), (t, tv) = (self._joint(s, rev, zero)
                            for s, rev, zero in zip(pt, self.reversed_axes, self.zero_ticks, strict=True))
        self.log("tx", State(round(now * 1e6) & 0xFFFFFFFF, p, t, pv, tv, 0, mode, hardware_faults(errors)), 0, now)

    @staticmethod
    def _joint(servo: Servo, reversed_axis: bool, zero: int) -> tuple[float, float]:
        """The servo's position and velocity as joint angle [rad] and rate [rad/s]."""
        sign = -1.0 if reversed_axis else 1.0
        return (sign * (servo.axis.pos - (zero - CENTRE_TICKS) * POSITION_RESOLUTION), sign * servo.axis.vel)
