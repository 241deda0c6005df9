"""Host side of MAVLink Gimbal Protocol v2 (common dialect, MAVLink 2) with pymavlink: a GimbalInterface.

``MavlinkGimbal(url, settings).start()`` opens a pymavlink connection (``udpin:``/``udpout:``/``tcp:`` or a
serial device) on a background thread and, on every (re)connection: sends our HEARTBEAT (then once a second),
asks the gimbal manager for GIMBAL_MANAGER_INFORMATION (MAV_CMD_REQUEST_MESSAGE) and checks the configured joint
limits against the ones it reports (refusing to drive a gimbal whose range is smaller: ``incompatible``), then
takes primary control with MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE and asks for GIMBAL_DEVICE_ATTITUDE_STATUS at 50 Hz
(MAV_CMD_SET_MESSAGE_INTERVAL, best effort). Setpoints go out as GIMBAL_MANAGER_SET_PITCHYAW
(angles and rates, yaw in the vehicle frame). GIMBAL_DEVICE_ATTITUDE_STATUS is the measured state, its failure
flags the faults; GIMBAL_MANAGER_STATUS tells whether we are still in control (``disabled`` when not). No
attitude status for ``state_timeout_s`` → link down, reconnect with backoff. Disabling releases control
(CONFIGURE with −3: "remove control if currently in control"), after which the manager holds or returns to its
own inputs. Conversions live in :mod:`pivotd.gimbal.mavlink_frames`.

GIMBAL_MANAGER_SET_PITCHYAW carries no validity: a manager that stalls executes, when it resumes, whatever queued
up for it meanwhile. So the host's silence rule (:class:`pivotd.gimbal.silence.SilenceRule`, as for pivotd's own
protocol) applies: after ``silence_periods`` attitude-status periods (estimated from ``time_boot_ms``, the
manager's clock; at least ``silence_min_s``, at most ``state_timeout_s``) without a GIMBAL_DEVICE_ATTITUDE_STATUS,
:meth:`MavlinkGimbal.send_setpoint` sends nothing and returns None (``setpoints_withheld``) and our HEARTBEAT is
held back too (``heartbeats_withheld``); the control loop restarts from a state measured once the manager answers.

The measured pan is relative to the vehicle whatever frame the device reports its yaw in (GIMBAL_DEVICE_FLAGS,
:func:`pivotd.gimbal.mavlink_frames.yaw_frame`): a status in the earth frame is turned back by the vehicle heading,
its ``delta_yaw`` (and ``delta_yaw_velocity`` for the pan rate); when the device does not know it (NaN), or by the
older YAW_LOCK rule (no frame flag, ``delta_yaw`` to be ignored), by the heading last given to
:meth:`MavlinkGimbal.set_vehicle_heading` (at most ``heading_timeout_s`` old). A status that cannot be turned back
(no heading known: ``heading_unknown``; both frame flags set: ``yaw_frame_invalid``) is dropped, counted, logged
once; it is not a measured state, so the silence rule and the state timeout treat it as none.
"""

from __future__ import annotations

import contextlib
import logging
import math
import os
import queue
import threading
import time
from dataclasses import dataclass, replace
from typing import Any

from pivotd.compat import StrEnum
from pivotd.errors import ConfigError
from pivotd.gimbal import mavlink_frames as mf
from pivotd.gimbal.interface import GimbalMode, GimbalState, LinkState
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.silence import SilenceRule
from pivotd.gimbal.supervisor import Connection, SilenceClock, SupervisedLink

log = logging.getLogger(__name__)

MSG_GIMBAL_MANAGER_INFORMATION = 280
MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE = 1001
MAV_CMD_REQUEST_MESSAGE = 512
MAV_CMD_SET_MESSAGE_INTERVAL = 511
MSG_GIMBAL_DEVICE_ATTITUDE_STATUS = 285
ATTITUDE_INTERVAL_US = 20_000  # asked of the manager: 50 Hz attitude status (best effort, not required)
MAV_RESULT_ACCEPTED = 0
CONTROL_TAKE, CONTROL_RELEASE, CONTROL_UNCHANGED = None, -3.0, -1.0


def command_message(mavlink: Any, target: tuple[int, int], command: int, *params: float) -> Any:
    """COMMAND_LONG ``command`` to ``target`` (system, component) with up to seven params (the rest 0)."""
    p = [float(x) for x in params] + [0.0] * (7 - len(params))
    return mavlink.MAVLink_command_long_message(target[0], target[1], command, 0, *p)


def configure_message(mavlink: Any, manager: tuple[int, int], us: tuple[int, int], gimbal_device_id: int,
                      take: bool) -> Any:
    """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: ``us`` (system, component) as primary control, or (``take`` False)
    −3/−3, "remove control if currently in control"; secondary control unchanged (−1)."""
    primary = (float(us[0]), float(us[1])) if take else (CONTROL_RELEASE, CONTROL_RELEASE)
    return command_message(mavlink, manager, MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, *primary, CONTROL_UNCHANGED,
                           CONTROL_UNCHANGED, 0.0, 0.0, float(gimbal_device_id))


def setpoint_message(mavlink: Any, manager: tuple[int, int], gimbal_device_id: int, limits: JointLimits, pan: float,
                     tilt: float, pan_rate: float, tilt_rate: float) -> Any:
    """GIMBAL_MANAGER_SET_PITCHYAW for joint angles [rad] and rates [rad/s], clamped into ``limits`` (an axis held
    at a limit gets zero rate; a continuous pan is sent wrapped to (−π, π])."""
    cpan, ctilt = limits.clamp(pan, tilt)
    if cpan != pan:
        pan_rate = 0.0
    if ctilt != tilt:
        tilt_rate = 0.0
    if limits.continuous_pan:
        cpan = mf.wrap_pi(cpan)
    py = mf.to_pitch_yaw(cpan, ctilt, pan_rate, tilt_rate)
    return mavlink.MAVLink_gimbal_manager_set_pitchyaw_message(manager[0], manager[1], mf.SETPOINT_FLAGS,
                                                               gimbal_device_id, py.pitch, py.yaw, py.pitch_rate,
                                                               py.yaw_rate)


def load_mavutil() -> Any:
    """pymavlink's mavutil on MAVLink 2 with the common dialect; a clear error when the extra is missing."""
    os.environ.setdefault("MAVLINK20", "1")
    try:
        from pymavlink import mavutil
    except ImportError:
        raise ConfigError("gimbal.backend: mavlink needs pymavlink: pip install 'pivotd[mavlink]'") from None
    mavutil.set_dialect("common")
    return mavutil


class AttitudeDrop(StrEnum):
    """Why a GIMBAL_DEVICE_ATTITUDE_STATUS is no measured state (the value is its counter)."""

    HEADING_UNKNOWN = "heading_unknown"  # yaw in the earth frame, no vehicle heading to turn it back by
    YAW_FRAME_INVALID = "yaw_frame_invalid"  # both frame flags set


@dataclass(frozen=True)
class MavlinkSettings:
    """Identities (ours, the manager's: 0 = first heard, the device's: 0 = all), the configured joint limits
    [rad], and timing [s]."""

    limits: JointLimits
    system_id: int = 1
    component_id: int = 191
    target_system: int = 0
    target_component: int = 0
    gimbal_device_id: int = 0
    state_timeout_s: float = 0.5
    reply_timeout_s: float = 0.2
    retries: int = 5
    heartbeat_period_s: float = 1.0
    reconnect_backoff_s: tuple = (0.1, 2.0)
    silence_periods: float = 5.0  # no attitude status for this many of its periods -> no setpoints are sent
    silence_min_s: float = 0.1  # [s] floor of that bound (host scheduling jitter)
    heading_timeout_s: float = 0.5  # a heading given to set_vehicle_heading counts for this long [s]


class MavlinkGimbal(SupervisedLink):
    """A gimbal behind a MAVLink gimbal manager (see the module docstring); thread-safe, never blocks senders."""

    _thread_name = "gimbal-mavlink"

    def __init__(self, url: str, settings: MavlinkSettings, baudrate: int = 115200) -> None:
        super().__init__(url, settings.reconnect_backoff_s,
                         ("messages_sent", "messages_received", "setpoints_sent", "heartbeats_received", "retries",
                          "reconnects", "link_losses", "command_failures", "tx_overflow", "rate_unknown",
                          "setpoints_withheld", "heartbeats_withheld", "silences",
                          *(d.value for d in AttitudeDrop)))
        self.url = url
        self.settings = settings
        self.baudrate = baudrate
        self._mavutil = load_mavutil()
        self._conn: Connection | None = None
        self._in_control = False
        self._manager: tuple[int, int] | None = None  # (system, component) of the gimbal manager
        self._info: Any = None
        self._device_limits: JointLimits | None = None
        self._waiters: dict[str, list[tuple[Any, threading.Event, list]]] = {}
        self._last_state_rx = 0.0
        self._faults = 0
        self._heading: tuple[float, float, float] | None = None  # (heading, rate, host time) from the vehicle
        self._unusable: str | None = None  # why the newest attitude status was dropped (None: it was not)
        self._warned: set[AttitudeDrop] = set()  # drop reasons logged already
        # the attitude-status period from consecutive time_boot_ms stamps (reader thread), and the silence
        self._silence = SilenceRule(settings.silence_periods, settings.silence_min_s, settings.state_timeout_s, url,
                                    "GIMBAL_DEVICE_ATTITUDE_STATUS", log)

    # ------------------------------------------------------------------ GimbalInterface
    @property
    def device_limits(self) -> JointLimits | None:
        """The joint ranges the manager reported at the last handshake."""
        return self._device_limits

    def silence_s(self) -> float:
        """How long [s] without a GIMBAL_DEVICE_ATTITUDE_STATUS the gimbal counts as silent: ``silence_periods`` of
        its status period (the smallest recent interval between statuses on its ``time_boot_ms`` clock), at least
        ``silence_min_s``, at most ``state_timeout_s`` (also before the period is known)."""
        return self._silence.silence_s()

    def set_vehicle_heading(self, heading: float, rate: float = math.nan, at: float | None = None) -> None:
        """The vehicle's heading [rad] in the gimbal's earth frame (NED: clockwise from North; from a pose in an
        East-aligned world frame: :func:`pivotd.gimbal.mavlink_frames.heading_from_body_quat`), its rate [rad/s]
        (NaN: unknown) and the host time it was measured at (``time.monotonic()`` [s], default now). Only used for
        attitude statuses in the earth frame that carry no ``delta_yaw``, for ``heading_timeout_s``; a gimbal that
        reports in the vehicle frame needs none. Thread-safe (one reference assignment)."""
        if not math.isfinite(heading):
            raise ValueError("heading must be finite")
        self._heading = (float(heading), float(rate), time.monotonic() if at is None else float(at))

    def send_setpoint(self, pan: float, tilt: float, pan_rate: float = 0.0, tilt_rate: float = 0.0) -> int | None:
        """Queue one GIMBAL_MANAGER_SET_PITCHYAW (joint limits enforced here too); its count, or None if the link
        is not up or the gimbal is silent (counted as ``setpoints_withheld``; see :meth:`silence_s`)."""
        conn, manager = self._conn, self._manager
        if self._link_state != LinkState.UP or conn is None or manager is None:
            return None
        if not all(math.isfinite(v) for v in (pan, tilt, pan_rate, tilt_rate)):
            raise ValueError("setpoint must be finite")
        if self._silence.silent(time.monotonic(), self._last_state_rx, self._state is not None, self._n,
                                "setpoints_withheld"):
            return None
        msg = setpoint_message(self._mavutil.mavlink, manager, self.settings.gimbal_device_id, self.settings.limits,
                               pan, tilt, pan_rate, tilt_rate)
        if not self._enqueue(conn, msg):
            return None
        self._n["setpoints_sent"] += 1
        return self._n["setpoints_sent"]

    def send_heartbeat(self) -> None:
        """Nothing to do per tick: the MAVLink HEARTBEAT goes out once a second by itself, and the manager holds
        the last angle setpoint without a watchdog of ours."""

    def set_enabled(self, on: bool, timeout: float | None = None) -> bool:
        """Take (True) or release (False) primary control of the gimbal; True once the manager accepted."""
        self._want_enabled = bool(on)
        conn = self._conn
        if self._link_state != LinkState.UP or conn is None:
            return False
        ok = self._configure(conn, on, timeout)
        if ok:
            self._in_control = on
            self._refresh_mode()
        return ok

    def clear_fault(self, timeout: float | None = None) -> bool:
        """MAVLink has no fault reset: the device clears its failure flags itself. True when none is set now."""
        return self._link_state == LinkState.UP and not self._faults

    def counters(self) -> dict[str, int | float]:
        return dict(self._n)

    # ------------------------------------------------------------------ internals
    def _mav_msg(self, name: str, *args: Any) -> Any:
        mav = self._mavutil.mavlink
        return getattr(mav, f"MAVLink_{name}_message")(*args)

    def _heartbeat_msg(self) -> Any:
        mav = self._mavutil.mavlink
        return self._mav_msg("heartbeat", mav.MAV_TYPE_ONBOARD_CONTROLLER, mav.MAV_AUTOPILOT_INVALID, 0, 0,
                             mav.MAV_STATE_ACTIVE, 3)

    def _open(self) -> Connection | None:
        s = self.settings
        try:
            port = self._mavutil.mavlink_connection(self.url, baud=self.baudrate, source_system=s.system_id,
                                                    source_component=s.component_id, autoreconnect=False)
        except Exception as exc:  # pymavlink raises OSError, SerialException, ValueError, ...
            self._last_error = f"cannot open MAVLink connection {self.url}: {exc}"
            log.debug(self._last_error)
            return None
        conn = Connection(port)
        self._silence.reset()
        self._conn = conn
        conn.start_threads(((self._reader, "gimbal-mavlink-rx"), (self._writer, "gimbal-mavlink-tx")))
        return conn

    def _close(self, conn: Connection) -> None:
        conn.stop_threads()
        with contextlib.suppress(Exception):
            conn.port.close()
        if self._conn is conn:
            self._conn = None
        self._in_control = False

    def _handshake(self, conn: Connection) -> LinkState:
        """HEARTBEAT, GIMBAL_MANAGER_INFORMATION (limits, capabilities), take control."""
        s = self.settings
        self._manager = None
        self._enqueue(conn, self._heartbeat_msg())
        info = None
        for attempt in range(s.retries + 1):
            if attempt:
                self._n["retries"] += 1
                self._enqueue(conn, self._heartbeat_msg())
            self._enqueue(conn, self._command(conn, MAV_CMD_REQUEST_MESSAGE, (s.target_system, s.target_component),
                                              MSG_GIMBAL_MANAGER_INFORMATION))
            info = self._wait_for("GIMBAL_MANAGER_INFORMATION", self._from_target, s.reply_timeout_s)
            if info is not None or not conn.alive or self._stopping.is_set():
                break
        if info is None:
            self._last_error = f"no gimbal manager answered at {self.url} (GIMBAL_MANAGER_INFORMATION)"
            return LinkState.DOWN
        self._manager = (info.get_srcSystem(), info.get_srcComponent())
        self._info = info
        device = mf.joint_limits_from_manager(info.pitch_min, info.pitch_max, info.yaw_min, info.yaw_max)
        self._device_limits = device
        caps = info.cap_flags
        needed = mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_AXIS | mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_YAW_AXIS
        if caps & needed != needed:
            self._last_error = f"gimbal manager at {self.url} lacks a pitch or yaw axis (cap_flags 0x{caps:x})"
            log.error(self._last_error)
            return LinkState.INCOMPATIBLE
        problem = mf.limits_problem(s.limits, device, bool(caps & mf.GIMBAL_MANAGER_CAP_FLAGS_SUPPORTS_INFINITE_YAW))
        if problem:
            self._last_error = f"gimbal at {self.url}: {problem}: refusing to drive it"
            log.error(self._last_error)
            return LinkState.INCOMPATIBLE
        if not caps & mf.GIMBAL_MANAGER_CAP_FLAGS_HAS_PITCH_FOLLOW:
            log.warning("gimbal manager at %s cannot let pitch follow the vehicle: tilt is then relative to the "
                        "horizon, not to the mount", self.url)
        if self._want_enabled and not self._configure(conn, True, None):
            self._last_error = f"gimbal manager at {self.url} did not give us control (DO_GIMBAL_MANAGER_CONFIGURE)"
            return LinkState.DOWN
        self._in_control = self._want_enabled
        self._enqueue(conn, self._command(conn, MAV_CMD_SET_MESSAGE_INTERVAL, self._manager,
                                          MSG_GIMBAL_DEVICE_ATTITUDE_STATUS, ATTITUDE_INTERVAL_US))
        if self._wait_for("GIMBAL_DEVICE_ATTITUDE_STATUS", self._from_device, s.state_timeout_s) is None:
            why = self._unusable
            self._last_error = f"gimbal at {self.url} sends no usable GIMBAL_DEVICE_ATTITUDE_STATUS: {why}" if why \
                else f"gimbal at {self.url} sends no GIMBAL_DEVICE_ATTITUDE_STATUS"
            return LinkState.DOWN
        log.info("gimbal manager %d/%d at %s: device %d, cap_flags 0x%x, pan [%.1f, %.1f] deg, tilt [%.1f, %.1f] deg",
                 *self._manager, self.url, info.gimbal_device_id, caps, math.degrees(device.pan_min),
                 math.degrees(device.pan_max), math.degrees(device.tilt_min), math.degrees(device.tilt_max))
        return LinkState.UP

    def _command(self, conn: Connection, command: int, target: tuple[int, int], *params: float) -> Any:
        return command_message(self._mavutil.mavlink, target, command, *params)

    def _configure(self, conn: Connection, take: bool, timeout: float | None) -> bool:
        """MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE: us as primary control, or remove us; True on MAV_RESULT_ACCEPTED."""
        s, manager = self.settings, self._manager
        if manager is None:
            return False
        msg = configure_message(self._mavutil.mavlink, manager, (s.system_id, s.component_id), s.gimbal_device_id,
                                take)
        attempts = s.retries + 1 if timeout is None else max(1, int(timeout / s.reply_timeout_s + 0.999))
        for attempt in range(attempts):
            if attempt:
                self._n["retries"] += 1
            self._enqueue(conn, msg)
            ack = self._wait_for("COMMAND_ACK", lambda m: m.command == MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE,
                                 s.reply_timeout_s)
            if ack is not None:
                if ack.result == MAV_RESULT_ACCEPTED:
                    return True
                log.warning("gimbal manager refused DO_GIMBAL_MANAGER_CONFIGURE (result %d)", ack.result)
                break
            if not conn.alive or self._stopping.is_set():
                break
        self._n["command_failures"] += 1
        return False

    def _wait_for(self, msg_type: str, predicate: Any, timeout: float) -> Any:
        event, box = threading.Event(), []
        entry = (predicate, event, box)
        with self._changed:
            self._waiters.setdefault(msg_type, []).append(entry)
        try:
            event.wait(timeout)
            return box[0] if box else None
        finally:
            with self._changed:
                self._waiters[msg_type].remove(entry)

    def _from_target(self, msg: Any) -> bool:
        s = self.settings
        return ((not s.target_system or msg.get_srcSystem() == s.target_system)
                and (not s.target_component or msg.get_srcComponent() == s.target_component))

    def _from_device(self, msg: Any) -> bool:
        dev = self.settings.gimbal_device_id
        return not dev or dev in (msg.get_srcComponent(), getattr(msg, "gimbal_device_id", 0))

    def _monitor(self, conn: Connection) -> None:
        s = self.settings
        self._last_state_rx = time.monotonic()
        next_hb = time.monotonic() + s.heartbeat_period_s
        silence = SilenceClock(s.state_timeout_s / 2)  # a stall of this process is not a silent device
        while not self._stopping.is_set() and conn.alive:
            now = time.monotonic()
            if self._silence_while_running(silence, self._last_state_rx) > s.state_timeout_s:
                why = self._unusable
                conn.error = f"no usable GIMBAL_DEVICE_ATTITUDE_STATUS for {s.state_timeout_s} s: {why}" if why \
                    else f"no GIMBAL_DEVICE_ATTITUDE_STATUS for {s.state_timeout_s} s"
                break
            if now >= next_hb:
                next_hb += s.heartbeat_period_s
                if not self._silence.silent(now, self._last_state_rx, self._state is not None, self._n,
                                            "heartbeats_withheld"):
                    self._enqueue(conn, self._heartbeat_msg())
            self._stopping.wait(0.02)
        self._last_error = conn.error

    def _loss_reason(self, conn: Connection) -> str:
        return conn.error or "closed"

    def _writer(self, conn: Connection) -> None:
        mav = conn.port.mav
        while not conn.closing.is_set():
            try:
                msg = conn.tx.get(timeout=0.1)
            except queue.Empty:
                continue
            if msg is None:
                return
            try:
                mav.send(msg)
                self._n["messages_sent"] += 1
            except Exception as exc:
                conn.error = f"write failed: {exc}"
                return

    def _reader(self, conn: Connection) -> None:
        while not conn.closing.is_set():
            try:
                msg = conn.port.recv_match(blocking=True, timeout=0.05)
            except Exception as exc:
                if not conn.closing.is_set():
                    conn.error = f"read failed: {exc}"
                return
            if msg is None or msg.get_type() == "BAD_DATA":
                continue
            self._n["messages_received"] += 1
            self._dispatch(msg)

    def _dispatch(self, msg: Any) -> None:
        kind = msg.get_type()
        if kind == "HEARTBEAT":
            self._n["heartbeats_received"] += 1
        elif kind == "GIMBAL_DEVICE_ATTITUDE_STATUS" and self._from_device(msg):
            if not self._on_attitude(msg):
                return  # not a measured state: nobody waiting for one gets it
        elif kind == "GIMBAL_MANAGER_STATUS" and self._manager == (msg.get_srcSystem(), msg.get_srcComponent()):
            s = self.settings
            self._in_control = (msg.primary_control_sysid, msg.primary_control_compid) == (s.system_id,
                                                                                           s.component_id)
            self._refresh_mode()
        with self._changed:
            waiters = list(self._waiters.get(kind, ()))
        for predicate, event, box in waiters:
            if not event.is_set() and predicate(msg):
                box.append(msg)
                event.set()

    def _mode(self) -> int:
        if self._faults:
            return GimbalMode.FAULT
        return GimbalMode.ENABLED if self._in_control else GimbalMode.DISABLED

    def _refresh_mode(self) -> None:
        st = self._state
        if st is not None and st.mode != self._mode():
            self._state = replace(st, mode=self._mode())

    def _heading_of(self, msg: Any, now: float) -> tuple[float, float] | AttitudeDrop:
        """The (delta_yaw [rad], delta_yaw_rate [rad/s]) that turn ``msg``'s attitude into the vehicle frame, or
        why it cannot be."""
        frame = mf.yaw_frame(int(msg.flags))
        if frame == mf.YawFrame.VEHICLE:
            return 0.0, 0.0
        if frame == mf.YawFrame.INVALID:
            return AttitudeDrop.YAW_FRAME_INVALID
        delta, delta_rate = math.nan, math.nan
        if frame == mf.YawFrame.EARTH:  # EARTH_LEGACY: delta_yaw is to be ignored (a device predating it sends 0)
            delta, delta_rate = float(msg.delta_yaw), float(msg.delta_yaw_velocity)
        given = self._heading
        if given is not None and now - given[2] > self.settings.heading_timeout_s:
            given = None
        if not math.isfinite(delta):
            if given is None:
                return AttitudeDrop.HEADING_UNKNOWN
            delta, delta_rate = given[0], given[1]
        elif not math.isfinite(delta_rate) and given is not None:
            delta_rate = given[1]
        return delta, delta_rate

    def _drop(self, reason: AttitudeDrop, msg: Any) -> None:
        """Count an attitude status that is no measured state; log each reason once."""
        self._n[reason.value] += 1
        flags = int(msg.flags)
        if reason == AttitudeDrop.HEADING_UNKNOWN:
            text = f"yaw in the earth frame (flags 0x{flags:x}) without a delta_yaw (NaN, or to be ignored without " \
                   f"a frame flag), and no vehicle heading given within {self.settings.heading_timeout_s} s"
        else:
            text = f"both YAW_IN_VEHICLE_FRAME and YAW_IN_EARTH_FRAME set (flags 0x{flags:x})"
        self._unusable = text
        if reason not in self._warned:
            self._warned.add(reason)
            log.warning("gimbal at %s: GIMBAL_DEVICE_ATTITUDE_STATUS dropped: %s (counted as %s)", self.url, text,
                        reason.value)

    def _on_attitude(self, msg: Any) -> bool:
        """Take ``msg`` as the measured state; False when it is none (dropped)."""
        now = time.monotonic()
        heading = self._heading_of(msg, now)
        if isinstance(heading, AttitudeDrop):
            self._drop(heading, msg)
            return False
        try:
            pan, tilt, pan_rate, tilt_rate = mf.joints_from_attitude(msg.q, msg.angular_velocity_x,
                                                                     msg.angular_velocity_y, msg.angular_velocity_z,
                                                                     *heading)
        except ValueError:
            return False
        self._unusable = None
        if not (math.isfinite(pan_rate) and math.isfinite(tilt_rate)):
            self._n["rate_unknown"] += 1
            pan_rate = tilt_rate = 0.0
        self._faults = mf.device_faults(msg.failure_flags)
        boot_us = (int(msg.time_boot_ms) * 1000) & 0xFFFFFFFF
        self._silence.note(boot_us)
        st = GimbalState(pan, tilt, pan_rate, tilt_rate, self._mode(), self._faults, 0, boot_us, now,
                         self._device_clock.measured_at(boot_us, now))
        with self._changed:
            self._state = st
            self._last_state_rx = now
            self._changed.notify_all()
        return True
