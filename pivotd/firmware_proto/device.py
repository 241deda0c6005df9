"""Reference gimbal device model: the firmware's behaviour in Python (PROTOCOL.md §5–§7).

Pure and steppable: the caller owns the clock. ``feed(data, now)`` consumes host bytes and returns
the device's answers; ``step(now)`` advances the axis dynamics, the watchdog and the STATE stream to
``now`` (seconds on the device clock) and returns the STATE frames that fell due. No threads, no I/O.
"""

from __future__ import annotations

import logging
import math
import zlib
from collections.abc import Callable
from dataclasses import dataclass, field

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    ACK_OK,
    CONFIG_LIMIT_ABS_MAX,
    CONFIG_WATCHDOG_MS_MAX,
    CONFIG_WATCHDOG_MS_MIN,
    FAULT_CLAMPED,
    FAULT_CONFIG,
    FAULT_WATCHDOG,
    FAULTS_SEVERE,
    MODE_DISABLED,
    MODE_ENABLED,
    MODE_FAULT,
    MODE_HOLDING,
    NACK_BAD_VALUE,
    NACK_CONFIG_INVALID,
    NACK_FAULT_ACTIVE,
    NACK_NOT_CONFIGURED,
    PROTOCOL_VERSION,
    Ack,
    ClearFault,
    Config,
    Enable,
    Heartbeat,
    Hello,
    Identity,
    Message,
    Setpoint,
    SetpointV1,
    State,
    config_problems,
    setpoint_age_us,
    setpoint_is_fresh,
)

log = logging.getLogger(__name__)

WATCHDOG_MS_MIN, WATCHDOG_MS_MAX = CONFIG_WATCHDOG_MS_MIN, CONFIG_WATCHDOG_MS_MAX
LIMIT_ABS_MAX = CONFIG_LIMIT_ABS_MAX  # |joint limit| [rad]
TRACKING_GAIN = 25.0  # 1/s: proportional position gain of the axis controller (gives the "little lag")
SUBSTEP = 0.001  # s: integration step of the axis dynamics
CAP_WATCHDOG, CAP_CLAMP, CAP_FAULT_INJECTION = 1 << 0, 1 << 1, 1 << 2


@dataclass
class Axis:
    """One joint: position [rad] and rate [rad/s] with bounded rate and acceleration."""

    pos: float = 0.0
    vel: float = 0.0
    target: float = 0.0
    ff_rate: float = 0.0

    def advance(self, dt: float, vmax: float, amax: float, tracking: bool, lo: float, hi: float) -> None:
        """Integrate ``dt`` seconds: track ``target`` (+ feed-forward) when ``tracking``, else brake to rest."""
        if tracking:
            err = self.target - self.pos
            # braking-distance bound keeps the approach free of overshoot; the gain adds a little lag
            brake = math.sqrt(2.0 * amax * abs(err))
            v_des = self.ff_rate + math.copysign(min(TRACKING_GAIN * abs(err), brake), err)
            v_des = max(-vmax, min(vmax, v_des))
        else:
            v_des = 0.0
        dv = max(-amax * dt, min(amax * dt, v_des - self.vel))
        self.vel += dv
        self.pos += self.vel * dt
        if self.pos < lo or self.pos > hi:
            self.pos = min(hi, max(lo, self.pos))
            self.vel = 0.0


@dataclass
class DeviceInfo:
    """What IDENTITY reports."""

    version: int = PROTOCOL_VERSION
    fw: tuple[int, int, int] = (1, 0, 0)
    capabilities: int = CAP_WATCHDOG | CAP_CLAMP | CAP_FAULT_INJECTION
    serial: int = 0x00C0FFEE


def validate_config(cfg: Config) -> str | None:
    """Reason a CONFIG is invalid, or None if the device accepts it."""
    problems = config_problems(cfg)
    return None if not problems else f"{problems[0][0]}: {problems[0][1]}"


@dataclass
class DeviceModel:
    """State machine + axis dynamics + STATE stream of one gimbal. All times are device seconds.

    ``on_message(direction, msg, seq, now)`` is called for every message received and executed ("rx"), received
    and dropped as stale ("stale": a version-2 SETPOINT older than its validity, counted in
    :attr:`stale_setpoints`) and sent ("tx"), for logging. A version-1 device (``info.version`` 1) decodes the
    version-1 SETPOINT, which carries no validity, and executes every one.
    """

    state_hz: float = 50.0
    info: DeviceInfo = field(default_factory=DeviceInfo)
    on_message: Callable[[str, Message, int, float], None] | None = None

    def __post_init__(self) -> None:
        self.decoder = codec.StreamDecoder(self.info.version)
        self.mode = MODE_DISABLED
        self.faults = 0
        self.config: Config | None = None
        self.pan = Axis()
        self.tilt = Axis()
        self.last_setpoint_seq = 0
        self.now = 0.0
        self.last_feed = 0.0  # last SETPOINT/HEARTBEAT while enabled (watchdog)
        self.next_state = 0.0
        self.tx_seq = 0
        self.received = 0
        self.stale_setpoints = 0  # SETPOINTs dropped because they arrived older than their validity
        self._started = False
        self._state_t0 = 0.0
        self._state_count = 0
        self.stuck_until: dict[str, float] = {}  # axis name -> device time [s] it is held mechanically until

    # ----------------------------------------------------------------- input
    def feed(self, data: bytes, now: float) -> bytes:
        """Consume host bytes received at ``now``; return the encoded answers (IDENTITY, ACK)."""
        out = self.step(now)
        for frame in self.decoder.feed(data):
            self.received += 1
            if isinstance(frame.msg, Setpoint) and not setpoint_is_fresh(frame.msg, self.clock_us()):
                self._drop_stale(frame.msg, frame.seq, now)
                continue
            if self.on_message:
                self.on_message("rx", frame.msg, frame.seq, now)
            reply = self._handle(frame.msg, frame.seq, now)
            if reply is not None:
                out += self._send(reply)
        return out

    def clock_us(self) -> int:
        """The device clock [µs, wraps at 2³²], as STATE reports it."""
        return round(self.now * 1e6) & 0xFFFFFFFF

    def _drop_stale(self, sp: Setpoint, seq: int, now: float) -> None:
        """A SETPOINT past its validity: not executed, no effect on mode, targets, watchdog or the echoed seq."""
        self.stale_setpoints += 1
        if self.on_message:
            self.on_message("stale", sp, seq, now)
        if self.stale_setpoints == 1 or self.stale_setpoints % 100 == 0:
            log.info("stale SETPOINT seq %d dropped at t=%.3f s: %.1f ms old, valid for %d ms (%d dropped so far)",
                     seq, now, setpoint_age_us(self.clock_us(), sp.state_time_us) / 1000.0, sp.max_age_ms,
                     self.stale_setpoints)

    def _handle(self, msg: Message, seq: int, now: float) -> Message | None:
        if isinstance(msg, (Setpoint, SetpointV1)):
            self._on_setpoint(msg, seq, now)
            return None
        if isinstance(msg, Heartbeat):
            if self.mode == MODE_ENABLED:
                self.last_feed = now
            return None
        if isinstance(msg, Hello):
            i = self.info
            return Identity(i.version, *i.fw, i.capabilities, i.serial)
        if isinstance(msg, Config):
            reason = validate_config(msg)
            if reason is not None:
                log.info("CONFIG rejected: %s", reason)
                self.faults |= FAULT_CONFIG
                return Ack(seq, msg.TYPE, NACK_CONFIG_INVALID, 0)
            self.config = msg
            return Ack(seq, msg.TYPE, ACK_OK, zlib.crc32(msg.pack()))
        if isinstance(msg, Enable):
            return Ack(seq, msg.TYPE, self._on_enable(msg, now), 0)
        if isinstance(msg, ClearFault):
            self.faults = 0
            if self.mode == MODE_FAULT:
                self.mode = MODE_DISABLED
            return Ack(seq, msg.TYPE, ACK_OK, 0)
        return None  # device→host types arriving here are ignored

    def _on_enable(self, msg: Enable, now: float) -> int:
        if msg.on not in (0, 1):
            return NACK_BAD_VALUE
        if msg.on == 0:
            if self.mode != MODE_FAULT:
                self.mode = MODE_DISABLED
            return ACK_OK
        if self.mode == MODE_FAULT:
            return NACK_FAULT_ACTIVE
        if self.config is None:
            return NACK_NOT_CONFIGURED
        if self.mode != MODE_ENABLED:
            self.mode = MODE_ENABLED
            for ax in (self.pan, self.tilt):  # start from where we are: no jump
                ax.target, ax.ff_rate = ax.pos, 0.0
        self.last_feed = now
        return ACK_OK

    def _on_setpoint(self, sp: Setpoint | SetpointV1, seq: int, now: float) -> None:
        self.last_setpoint_seq = seq
        if self.mode not in (MODE_ENABLED, MODE_HOLDING) or self.config is None:
            return
        c = self.config
        pan = min(c.pan_max, max(c.pan_min, sp.pan))
        tilt = min(c.tilt_max, max(c.tilt_min, sp.tilt))
        if pan != sp.pan or tilt != sp.tilt:
            self.faults |= FAULT_CLAMPED
        self.pan.target, self.tilt.target = pan, tilt
        self.pan.ff_rate = 0.0 if pan != sp.pan else max(-c.vmax_pan, min(c.vmax_pan, sp.pan_rate))
        self.tilt.ff_rate = 0.0 if tilt != sp.tilt else max(-c.vmax_tilt, min(c.vmax_tilt, sp.tilt_rate))
        self.mode = MODE_ENABLED  # a setpoint while holding resumes tracking from the held position
        self.last_feed = now

    def inject_fault(self, bits: int) -> None:
        """Latch fault ``bits`` as if the hardware had detected them (severe bits enter MODE_FAULT)."""
        self.faults |= bits & 0xFFFF
        if bits & FAULTS_SEVERE:
            self.mode = MODE_FAULT

    def inject_stuck_axis(self, axis: str, seconds: float, now: float | None = None) -> None:
        """Hold ``axis`` ("pan" or "tilt") mechanically for ``seconds`` from ``now`` (default: the device clock):
        it does not move, its encoder reports the stuck position at rate 0, and no fault bit is set (a blocked
        axis the firmware cannot tell from a slow one). Setpoints are still taken: when it frees, it tracks its
        target from where it stands."""
        if axis not in ("pan", "tilt"):
            raise ValueError(f"axis must be 'pan' or 'tilt', got {axis!r}")
        if not seconds >= 0:
            raise ValueError(f"stuck seconds must be >= 0, got {seconds!r}")
        start = self.now if now is None else now
        self.stuck_until[axis] = start + seconds

    # ----------------------------------------------------------------- time
    def step(self, now: float) -> bytes:
        """Advance dynamics/watchdog to ``now`` [s]; return the STATE frames due up to ``now``."""
        out = b""
        if not self._started:  # the clock starts at the first call, whatever its origin
            self._started = True
            self.now = self.next_state = self.last_feed = self._state_t0 = now
        while self.next_state <= now:
            self._advance(self.next_state)
            out += self._send(self._state())
            self._state_count += 1  # schedule from the start time: no drift accumulates
            self.next_state = self._state_t0 + self._state_count / self.state_hz
        self._advance(now)
        return out

    def _advance(self, t: float) -> None:
        while self.now < t:
            if t - self.now > SUBSTEP:
                dt = SUBSTEP
                self.now += SUBSTEP
            else:
                dt = t - self.now
                self.now = t
            self._check_watchdog()
            c = self.config
            tracking = self.mode == MODE_ENABLED
            if c is None:
                self.pan.vel = self.tilt.vel = 0.0
                continue
            held = self._stuck_axes() if self.stuck_until else ()
            self.pan.advance(dt, c.vmax_pan, c.amax_pan, tracking, c.pan_min, c.pan_max)
            self.tilt.advance(dt, c.vmax_tilt, c.amax_tilt, tracking, c.tilt_min, c.tilt_max)
            for ax, pos in held:  # held mechanically: it did not move
                ax.pos, ax.vel = pos, 0.0

    def _stuck_axes(self) -> list[tuple[Axis, float]]:
        """The axes held mechanically at this substep, with their positions (see :meth:`inject_stuck_axis`)."""
        held = []
        for name, until in list(self.stuck_until.items()):
            if self.now > until:
                if self.stuck_until.get(name) == until:  # not renewed meanwhile (inject_stuck_axis, any thread)
                    del self.stuck_until[name]
                continue
            ax = self.pan if name == "pan" else self.tilt
            held.append((ax, ax.pos))
        return held

    def _check_watchdog(self) -> None:
        c = self.config
        if self.mode == MODE_ENABLED and c is not None and self.now - self.last_feed > c.watchdog_ms / 1000.0:
            self.mode = MODE_HOLDING
            self.faults |= FAULT_WATCHDOG
            log.info("watchdog expired at t=%.3f s: holding", self.now)

    def _state(self) -> State:
        return State(
            self.clock_us(), self.pan.pos, self.tilt.pos, self.pan.vel, self.tilt.vel,
            self.last_setpoint_seq, self.mode, self.faults,
        )

    def _send(self, msg: Message) -> bytes:
        seq = self.tx_seq
        self.tx_seq = (seq + 1) & 0xFF
        if self.on_message:
            self.on_message("tx", msg, seq, self.now)
        return codec.encode(msg, seq, self.info.version)
