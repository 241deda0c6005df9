"""Host side of a pan–tilt unit made of two DYNAMIXEL X-series servos (Protocol 2.0) with ``dynamixel_sdk``.

``DynamixelGimbal(port, settings).start()`` runs one bus thread (the bus is half duplex: every transaction
happens there). On every (re)connection it pings both servos, turns the torque off, sets Position Control
Mode, Min/Max Position Limit from the joint limits, Profile Velocity/Acceleration from the motion limits, the
Goal Position to where each servo is (no jump), turns the torque on and arms the Bus Watchdog with
``watchdog_ms`` (the servos stop by themselves when the host goes silent). Then, for every setpoint, in order:
one Sync Write of both Goal Positions; after them one Sync Read of Torque Enable … Present Position (torque,
Hardware Error Status, velocity and position from one answer). A hardware error is a fault
(``clear_fault`` reboots the servo and configures it again); disabling turns the torque off. No state for
``state_timeout_s`` → link down, reconnect with backoff. Positions are 4096 ticks per turn, joint angle 0 at
each axis' zero tick (``pan_zero_tick``/``tilt_zero_tick``, 2048 by default): the joint limits must lie within
the ticks 0–4095 around it (±180° at 2048). A ping that gets no status packet names port, id and baud with
what to check; the adapter's FTDI latency timer is checked once (``latency_timer_problem``).
"""

from __future__ import annotations

import collections
import contextlib
import logging
import math
import os
import queue
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NamedTuple

from pivotd.errors import ConfigError
from pivotd.gimbal import dynamixel_table as ct
from pivotd.gimbal.interface import GimbalMode, GimbalState, LinkState
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.motion import AxisLimits
from pivotd.gimbal.supervisor import SupervisedLink

log = logging.getLogger(__name__)

_GOAL_QUEUE = 64  # setpoints waiting for the bus thread; older ones are dropped beyond this (counted)
#: where Linux shows a USB serial adapter's FTDI latency timer: ``<root>/ttyUSB0/latency_timer`` [ms]
USB_SERIAL_DEVICES = Path("/sys/bus/usb-serial/devices")


def latency_timer_problem(port: str, usb_serial_root: Path = USB_SERIAL_DEVICES) -> str | None:
    """Why the USB serial adapter behind ``port`` (a symlink such as /dev/serial/by-id/… is followed) slows every
    read: its latency timer reads more than 1 ms (the FTDI default is 16 ms). None when it is 1 ms, or when the
    port has no such file (not a USB serial adapter, or not Linux)."""
    path = usb_serial_root / os.path.basename(os.path.realpath(port)) / "latency_timer"
    try:
        value = int(path.read_text().strip())
    except (OSError, ValueError):
        return None
    if value <= 1:
        return None
    return (f"{path} is {value} ms: every servo answer waits up to that long; set it to 1 "
            f"(echo 1 > {path}, or the udev rule of docs/HARDWARE.md)")


def load_sdk() -> Any:
    """The ``dynamixel_sdk`` module; a clear error when the extra is missing."""
    try:
        import dynamixel_sdk
    except ImportError:
        raise ConfigError("gimbal.backend: dynamixel needs dynamixel-sdk: pip install 'pivotd[dynamixel]'") from None
    return dynamixel_sdk


@dataclass(frozen=True)
class DynamixelSettings:
    """Servo ids and directions, the joint limits [rad] and per-axis motion limits the servos enforce, the bus
    watchdog [ms], the cycle when no setpoint comes [s], and timing [s]."""

    limits: JointLimits
    pan_motion: AxisLimits
    tilt_motion: AxisLimits
    pan_id: int = 1
    tilt_id: int = 2
    pan_reversed: bool = False
    tilt_reversed: bool = False
    pan_zero_tick: int = ct.CENTRE_TICKS  # the servo position [ticks] of joint angle 0
    tilt_zero_tick: int = ct.CENTRE_TICKS
    watchdog_ms: int = 250
    control_period_s: float | None = None  # the daemon's control period: warned about a bus slower than it
    idle_period_s: float = 0.02
    state_timeout_s: float = 0.5
    reconnect_backoff_s: tuple = (0.1, 2.0)


def bus_rate_problem(baudrate: int, control_period_s: float | None) -> str | None:
    """Why one control period's bus traffic (``ct.bus_cycle_s``) does not fit in ``control_period_s`` [s] at
    ``baudrate``, or None (also when there is no control period to compare with)."""
    if control_period_s is None:
        return None
    cycle = ct.bus_cycle_s(baudrate)
    if cycle <= control_period_s:
        return None
    return (f"at {baudrate} baud one Sync Write + Sync Read takes at least {cycle * 1e3:.1f} ms, longer than the "
            f"control period {control_period_s * 1e3:g} ms: set the servos' Baud Rate and gimbal.baud to 1000000")


class _Axis(NamedTuple):
    """One servo as a joint: bus id, direction, tick of angle 0, joint range [rad], motion limits."""

    name: str
    dxl_id: int
    reversed: bool
    zero: int
    lo: float
    hi: float
    motion: AxisLimits

    @property
    def ticks(self) -> tuple[int, int]:
        """(Min, Max Position Limit) [ticks] of the joint range."""
        return ct.limits_to_ticks(self.lo, self.hi, self.reversed, self.zero)

    def goal_ticks(self, angle: float) -> int:
        """Goal Position [ticks] for a joint angle [rad], clamped into the Position Limits."""
        tmin, tmax = self.ticks
        return min(tmax, max(tmin, ct.angle_to_ticks(angle, self.reversed, self.zero)))


def axes(s: DynamixelSettings) -> tuple[_Axis, _Axis]:
    """The pan and the tilt servo of ``s``."""
    lim = s.limits
    return (_Axis("pan", s.pan_id, s.pan_reversed, s.pan_zero_tick, lim.pan_min, lim.pan_max, s.pan_motion),
            _Axis("tilt", s.tilt_id, s.tilt_reversed, s.tilt_zero_tick, lim.tilt_min, lim.tilt_max, s.tilt_motion))


def limits_problem(s: DynamixelSettings) -> str | None:
    """Why the joint limits of ``s`` cannot be the servos' Position Limits (continuous pan, a range beyond the
    servo's 0–4095 ticks around its zero tick), or None."""
    if s.limits.continuous_pan:
        return "gimbal.limits: no continuous pan for servos in Position Control Mode (within ±180°)"
    for ax in axes(s):
        problem = ct.position_limits_problem(ax.name, ax.lo, ax.hi, ax.reversed, ax.zero)
        if problem:
            return f"gimbal.limits: {problem}"
    return None


class _BusError(Exception):
    """A transaction failed (no answer, CRC) or a servo refused it."""


class DynamixelGimbal(SupervisedLink):
    """Two servos as a pan–tilt unit (see the module docstring); a GimbalInterface. Thread-safe."""

    _thread_name = "gimbal-dynamixel"

    def __init__(self, port: str, settings: DynamixelSettings, baudrate: int = ct.FACTORY_BAUD,
                 usb_serial_root: Path = USB_SERIAL_DEVICES) -> None:
        super().__init__(port, settings.reconnect_backoff_s,
                         ("setpoints_sent", "sync_writes", "sync_reads", "comm_errors", "reconnects", "link_losses",
                          "reboots", "goals_dropped", "write_errors"))
        self.port_name = port
        self.settings = settings
        self.baudrate = baudrate
        self.usb_serial_root = usb_serial_root
        #: the latency-timer warning given at the first opening (latency_timer_problem), or None
        self.latency_warning: str | None = None
        #: the warning that the baud rate is too slow for the control period (bus_rate_problem), or None
        self.bus_warning = bus_rate_problem(baudrate, settings.control_period_s)
        self._latency_checked = False
        self._sdk = load_sdk()
        self._ph = self._sdk.PacketHandler(2.0)
        self._port: Any = None
        self._goals: collections.deque[tuple[float, float]] = collections.deque(maxlen=_GOAL_QUEUE)
        self._wake = threading.Event()
        self._requests: queue.Queue = queue.Queue()
        self._torque = (False, False)
        self._hw_errors = (0, 0)
        # False from the start of a configuration until it completed: a failed write half-way (a lost status
        # packet) leaves a rebooted servo without its profile and watchdog, so torque-on configures again first
        self._configured = False

    # ------------------------------------------------------------------ GimbalInterface
    def send_setpoint(self, pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> int | None:
        """Hand the next Goal Positions (clamped into the joint limits) to the bus thread; the servos take no rate
        feed-forward in Position Control Mode, so the rates are not sent."""
        if self._link_state != LinkState.UP:
            return None
        if not all(math.isfinite(v) for v in (pan, tilt, pan_rate, tilt_rate)):
            raise ValueError("setpoint must be finite")
        if len(self._goals) == _GOAL_QUEUE:
            self._n["goals_dropped"] += 1
        self._goals.append(self.settings.limits.clamp(pan, tilt))
        self._wake.set()
        self._n["setpoints_sent"] += 1
        return self._n["setpoints_sent"]

    def send_heartbeat(self) -> None:
        """Nothing to send: the bus thread's reads feed the servos' Bus Watchdog."""

    def set_enabled(self, on: bool, timeout: float | None = None) -> bool:
        """Torque on or off on both servos; True once both confirmed."""
        self._want_enabled = bool(on)
        return bool(self._call(lambda: self._set_torque(on), timeout))

    def clear_fault(self, timeout: float | None = None) -> bool:
        """Reboot the servos that report a hardware error and configure them again; True when none is left."""
        return bool(self._call(self._reboot_faulted, timeout))

    def counters(self) -> dict[str, int | float]:
        return dict(self._n)

    # ------------------------------------------------------------------ requests to the bus thread
    def _call(self, fn: Callable[[], bool], timeout: float | None) -> bool:
        if self._link_state != LinkState.UP:
            return False
        done, box = threading.Event(), []
        self._requests.put((fn, done, box))
        self._wake.set()
        if not done.wait(2.0 if timeout is None else timeout):
            return False
        return bool(box and box[0])

    def _serve_requests(self) -> None:
        """Run the queued requests; a failed one answers False (a port failure is raised after answering)."""
        while True:
            try:
                fn, done, box = self._requests.get_nowait()
            except queue.Empty:
                return
            try:
                box.append(fn())
            except _BusError as exc:
                log.warning("dynamixel request failed: %s", exc)
                box.append(False)
            finally:
                done.set()

    # ------------------------------------------------------------------ bus thread
    def _interrupt(self) -> None:
        self._wake.set()

    def _on_down(self) -> None:
        self._drain_requests()

    def _drain_requests(self) -> None:
        while True:
            try:
                _, done, box = self._requests.get_nowait()
            except queue.Empty:
                return
            box.append(False)
            done.set()

    def _open(self) -> Any | None:
        """The opened PortHandler, or None."""
        try:
            port = self._sdk.PortHandler(self.port_name)
            if not port.openPort() or not port.setBaudRate(self.baudrate):
                raise OSError(f"baud rate {self.baudrate} not supported")
        except Exception as exc:
            self._last_error = f"cannot open servo bus {self.port_name}: {exc}"
            log.debug(self._last_error)
            return None
        self._port = port
        if self.bus_warning and not self._latency_checked:
            log.warning("servo bus %s: %s", self.port_name, self.bus_warning)
        if not self._latency_checked:
            self._latency_checked = True
            self.latency_warning = latency_timer_problem(self.port_name, self.usb_serial_root)
            if self.latency_warning:
                log.warning("servo bus %s: %s", self.port_name, self.latency_warning)
        return port

    def _handshake(self, port: Any) -> LinkState:
        try:
            return self._configure()
        except Exception as exc:
            error = f"servos at {self.port_name}: {exc}"
            if error != self._last_error:  # once, not at every retry
                log.warning("%s", error)
            self._last_error = error
            return LinkState.DOWN

    def _close(self, port: Any) -> None:
        if self._port is not None:
            with contextlib.suppress(Exception):
                self._port.closePort()
        self._port = None

    def _check(self, what: str, dxl_id: int, comm: int, error: int) -> None:
        if comm != self._sdk.COMM_SUCCESS:
            self._n["comm_errors"] += 1
            self._port.clearPort()
            hint = ""
            if comm == self._sdk.COMM_RX_TIMEOUT:
                hint = (f" (no answer from id {dxl_id} on {self.port_name} at {self.baudrate} baud: check the servo "
                        "ids gimbal.dynamixel.pan_id/tilt_id, gimbal.baud against the servos' Baud Rate (factory "
                        f"{ct.FACTORY_BAUD}), their 12 V supply, and the wiring: TTL 3-pin vs RS-485 4-pin)")
            raise _BusError(f"{what} on servo {dxl_id}: {self._ph.getTxRxResult(comm)}{hint}")
        if error & 0x7F:
            raise _BusError(f"{what} on servo {dxl_id}: {self._ph.getRxPacketError(error)}")

    def _write(self, dxl_id: int, item: tuple[int, int], value: int) -> None:
        addr, size = item
        fn = {1: self._ph.write1ByteTxRx, 2: self._ph.write2ByteTxRx, 4: self._ph.write4ByteTxRx}[size]
        comm, error = fn(self._port, dxl_id, addr, value & ((1 << (8 * size)) - 1))
        self._check(f"write {addr}", dxl_id, comm, error)

    def _read(self, dxl_id: int, item: tuple[int, int], signed: bool = False) -> int:
        addr, size = item
        fn = {1: self._ph.read1ByteTxRx, 2: self._ph.read2ByteTxRx, 4: self._ph.read4ByteTxRx}[size]
        value, comm, error = fn(self._port, dxl_id, addr)
        self._check(f"read {addr}", dxl_id, comm, error)
        if signed and value >= 1 << (8 * size - 1):
            value -= 1 << (8 * size)
        return value

    def _axes(self) -> tuple[_Axis, _Axis]:
        return axes(self.settings)

    def _ids(self) -> tuple[int, int]:
        return self.settings.pan_id, self.settings.tilt_id

    def _configure(self) -> LinkState:
        """Ping, then the settings of the module docstring; UP, DOWN or INCOMPATIBLE."""
        s = self.settings
        problem = limits_problem(s)
        if problem:
            self._last_error = problem
            log.error(self._last_error)
            return LinkState.INCOMPATIBLE
        self._configured = False
        for dxl_id in self._ids():
            model, comm, error = self._ph.ping(self._port, dxl_id)
            self._check("ping", dxl_id, comm, error)
        for ax in self._axes():
            dxl_id, motion = ax.dxl_id, ax.motion
            self._write(dxl_id, ct.TORQUE_ENABLE, 0)
            self._write(dxl_id, ct.OPERATING_MODE, ct.POSITION_CONTROL_MODE)
            tmin, tmax = ax.ticks
            self._write(dxl_id, ct.MIN_POSITION_LIMIT, tmin)
            self._write(dxl_id, ct.MAX_POSITION_LIMIT, tmax)
            self._write(dxl_id, ct.BUS_WATCHDOG, 0)  # clears an expired watchdog
            self._write(dxl_id, ct.PROFILE_ACCELERATION, ct.acceleration_units(motion.max_acceleration))
            self._write(dxl_id, ct.PROFILE_VELOCITY, ct.velocity_units(motion.max_velocity))
            present = self._read(dxl_id, ct.PRESENT_POSITION, signed=True)
            self._write(dxl_id, ct.GOAL_POSITION, min(tmax, max(tmin, present)))
        self._goals.clear()
        self._read_state()
        if self._want_enabled and not any(self._hw_errors):
            self._write_torque(True)
        for dxl_id in self._ids():
            self._write(dxl_id, ct.BUS_WATCHDOG, ct.watchdog_units(s.watchdog_ms))
        self._read_state()
        self._configured = True
        log.info("servos %d (pan) and %d (tilt) at %s configured: model %d", s.pan_id, s.tilt_id, self.port_name,
                 model)
        return LinkState.UP

    def _set_torque(self, on: bool) -> bool:
        if on and not self._configured:  # an earlier configuration failed half-way: complete it (it enables)
            return self._configure() is LinkState.UP and self._torque == (True, True)
        return self._write_torque(on)

    def _write_torque(self, on: bool) -> bool:
        for dxl_id in self._ids():
            self._write(dxl_id, ct.TORQUE_ENABLE, 1 if on else 0)
        self._read_state()
        return self._torque == (on, on)

    def _reboot_faulted(self) -> bool:
        self._read_state()
        if not any(self._hw_errors):
            return self._configured or self._configure() is LinkState.UP
        for dxl_id, err in zip(self._ids(), self._hw_errors, strict=True):
            if err:
                comm, error = self._ph.reboot(self._port, dxl_id)
                self._check("reboot", dxl_id, comm, error & 0x7F)
                self._n["reboots"] += 1
        time.sleep(0.05)
        return self._configure() is LinkState.UP and not any(self._hw_errors)

    def _sync_read(self, start: int, length: int) -> list[bytes] | None:
        gsr = self._sdk.GroupSyncRead(self._port, self._ph, start, length)
        for dxl_id in self._ids():
            gsr.addParam(dxl_id)
        comm = gsr.txRxPacket()
        self._n["sync_reads"] += 1
        if comm != self._sdk.COMM_SUCCESS:
            self._n["comm_errors"] += 1
            self._port.clearPort()  # a late answer must not be taken for the next one
            return None
        out = []
        for dxl_id in self._ids():
            if not gsr.isAvailable(dxl_id, start, length):
                self._n["comm_errors"] += 1
                return None
            out.append(bytes(gsr.getData(dxl_id, start + i, 1) for i in range(length)))
        return out

    def _read_state(self) -> bool:
        """One Sync Read of Torque Enable … Present Position (64–135) from both servos: torque, hardware errors,
        position and velocity always come from the same answer, so a late answer can only be an older state."""
        start = ct.TORQUE_ENABLE[0]
        asked = time.monotonic()  # the servos measured the answer after this: a lower bound of its time
        data = self._sync_read(start, ct.PRESENT_POSITION[0] + ct.PRESENT_POSITION[1] - start)
        if data is None:
            return False
        now = time.monotonic()

        def field(raw: bytes, item: tuple[int, int]) -> int:
            off = item[0] - start
            return int.from_bytes(raw[off:off + item[1]], "little", signed=item[1] == 4)

        self._torque = (bool(field(data[0], ct.TORQUE_ENABLE)), bool(field(data[1], ct.TORQUE_ENABLE)))
        self._hw_errors = (field(data[0], ct.HARDWARE_ERROR_STATUS), field(data[1], ct.HARDWARE_ERROR_STATUS))
        values = []
        for raw, ax in zip(data, self._axes(), strict=True):
            vel = field(raw, ct.PRESENT_VELOCITY) * ct.VELOCITY_UNIT
            pos = ct.ticks_to_angle(field(raw, ct.PRESENT_POSITION), ax.reversed, ax.zero)
            values.append((pos, -vel if ax.reversed else vel))
        errors = self._hw_errors[0] | self._hw_errors[1]
        mode = GimbalMode.FAULT if errors else GimbalMode.ENABLED if all(self._torque) else GimbalMode.DISABLED
        st = GimbalState(values[0][0], values[1][0], values[0][1], values[1][1], mode, ct.hardware_faults(errors),
                         0, int(now * 1e6) & 0xFFFFFFFF, now, asked)
        with self._changed:
            self._state = st
            self._changed.notify_all()
        return True

    def _write_goal(self, goal: tuple[float, float]) -> None:
        gsw = self._sdk.GroupSyncWrite(self._port, self._ph, ct.GOAL_POSITION[0], ct.GOAL_POSITION[1])
        for angle, ax in zip(goal, self._axes(), strict=True):
            gsw.addParam(ax.dxl_id, list(ax.goal_ticks(angle).to_bytes(4, "little", signed=True)))
        result = gsw.txPacket()
        if result != self._sdk.COMM_SUCCESS:
            self._n["write_errors"] += 1
            log.debug("goal sync write failed: %s", self._ph.getTxRxResult(result))
        self._n["sync_writes"] += 1

    def _cycle(self, cycle: int) -> bool:
        """Requests, the pending goal, status now and then, the state; whether the state was read."""
        try:
            self._serve_requests()
        except _BusError as exc:
            log.warning("%s", exc)
        while self._goals:  # every setpoint goes on the wire, in order, even when the bus fell behind
            goal = self._goals.popleft()
            if all(self._torque) and not any(self._hw_errors):
                self._write_goal(goal)
        return self._read_state()

    def _monitor(self, port: Any) -> None:
        """Bus cycles until the servos stop answering, the port fails or the link stops."""
        s = self.settings
        last_ok = time.monotonic()
        cycle = 0
        while not self._stopping.is_set():
            self._wake.wait(s.idle_period_s)
            self._wake.clear()
            try:
                ok = self._cycle(cycle)
            except Exception as exc:
                self._last_error = f"servo bus {self.port_name}: {exc}"
                return
            cycle += 1
            if ok:
                last_ok = time.monotonic()
            elif time.monotonic() - last_ok > s.state_timeout_s:
                self._last_error = f"no answer from the servos for {s.state_timeout_s} s"
                return
