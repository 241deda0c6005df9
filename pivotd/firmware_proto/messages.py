"""Typed protocol messages in SI units and their payload layouts (PROTOCOL.md §4).

Every message is a frozen dataclass with a class attribute ``TYPE`` (the type byte). Angles are
radians, rates rad/s, accelerations rad/s²; on the wire they are int32 micro-units. The conversion
between the two happens only in :func:`to_micro` / :func:`from_micro`, driven by the per-message
field table ``LAYOUT`` (field name, struct code, scaled).
"""

from __future__ import annotations

import math
import struct
from dataclasses import astuple, dataclass, fields
from typing import ClassVar

PROTOCOL_VERSION = 2  # the version this package speaks by default (PROTOCOL.md §3)
SUPPORTED_VERSIONS = (1, 2)  # versions whose layouts this package knows: a host may drive a device of either
MAX_BODY = 64  # version + type + seq + payload + crc, bytes

MICRO = 1_000_000
I32_MIN, I32_MAX = -(2**31), 2**31 - 1

# STATE modes
MODE_DISABLED, MODE_ENABLED, MODE_HOLDING, MODE_FAULT = 0, 1, 2, 3
MODE_NAMES = {0: "disabled", 1: "enabled", 2: "holding", 3: "fault"}

# fault bits
FAULT_OVERCURRENT = 1 << 0
FAULT_OVERTEMP = 1 << 1
FAULT_ENCODER = 1 << 2
FAULT_DRIVER = 1 << 3
FAULT_WATCHDOG = 1 << 4
FAULT_CLAMPED = 1 << 5
FAULT_CONFIG = 1 << 6
FAULT_UNDERVOLTAGE = 1 << 7
FAULT_NAMES = ("over-current", "over-temperature", "encoder", "driver", "watchdog", "setpoint-clamped",
               "config-invalid", "under-voltage")  # by bit number


def fault_names(bits: int) -> list[str]:
    """Names of the fault bits set in ``bits`` (STATE ``faults``), lowest bit first."""
    return [name for i, name in enumerate(FAULT_NAMES) if bits >> i & 1]


#: faults that put the device into MODE_FAULT (hardware faults); the others are latched warnings
FAULTS_SEVERE = FAULT_OVERCURRENT | FAULT_OVERTEMP | FAULT_ENCODER | FAULT_DRIVER | FAULT_UNDERVOLTAGE

# ACK status (0 = ok, anything else is a NACK reason)
ACK_OK = 0
NACK_CONFIG_INVALID = 1
NACK_NOT_CONFIGURED = 2
NACK_FAULT_ACTIVE = 3
NACK_BAD_VALUE = 4
NACK_NAMES = {0: "ok", 1: "config invalid", 2: "not configured", 3: "fault active", 4: "bad value"}


def to_micro(value: float) -> int:
    """SI value (rad, rad/s, rad/s²) -> int32 micro-units, rounded to nearest and saturated to int32."""
    if not math.isfinite(value):
        raise ValueError(f"non-finite value {value!r} cannot be encoded")
    return max(I32_MIN, min(I32_MAX, round(value * MICRO)))


def from_micro(value: int) -> float:
    """int32 micro-units -> SI value."""
    return value / MICRO


class Message:
    """Base of all messages: table-driven pack/unpack of the payload."""

    TYPE: ClassVar[int]
    NAME: ClassVar[str]
    LAYOUT: ClassVar[tuple[tuple[str, str, bool], ...]]  # (field, struct code, scaled to micro-units)
    STRUCT: ClassVar[struct.Struct]
    SCALED: ClassVar[tuple[bool, ...]]

    def __init_subclass__(cls, **kwargs: object) -> None:
        super().__init_subclass__(**kwargs)
        cls.STRUCT = struct.Struct("<" + "".join(code for _, code, _ in cls.LAYOUT))
        cls.SCALED = tuple(scaled for _, _, scaled in cls.LAYOUT)

    def raw(self) -> tuple[int, ...]:
        """Payload fields as the integers that go on the wire (micro-units for scaled fields)."""
        values = astuple(self)  # type: ignore[call-overload]
        return tuple(to_micro(v) if s else int(v) for v, s in zip(values, self.SCALED, strict=True))

    def pack(self) -> bytes:
        """Payload bytes (little-endian)."""
        try:
            return self.STRUCT.pack(*self.raw())
        except struct.error as exc:
            raise ValueError(f"{self.NAME}: field out of range: {exc}") from None

    @classmethod
    def from_raw(cls, raw: tuple[int, ...]) -> Message:
        """Message from wire integers (inverse of :meth:`raw`)."""
        return cls(*(from_micro(v) if s else v for v, s in zip(raw, cls.SCALED, strict=True)))

    @classmethod
    def unpack(cls, payload: bytes | memoryview) -> Message:
        """Message from payload bytes; raises ``struct.error`` on a wrong length."""
        return cls.from_raw(cls.STRUCT.unpack(payload))


@dataclass(frozen=True, slots=True)
class Hello(Message):
    """host→dev 0x01: start of the handshake; the device answers with IDENTITY."""

    host_version: int = PROTOCOL_VERSION
    TYPE: ClassVar[int] = 0x01
    NAME: ClassVar[str] = "HELLO"
    LAYOUT: ClassVar = (("host_version", "B", False),)


@dataclass(frozen=True, slots=True)
class Config(Message):
    """host→dev 0x02: joint limits [rad], rate limits [rad/s], acceleration limits [rad/s²], watchdog [ms]."""

    pan_min: float
    pan_max: float
    tilt_min: float
    tilt_max: float
    vmax_pan: float
    vmax_tilt: float
    amax_pan: float
    amax_tilt: float
    watchdog_ms: int
    TYPE: ClassVar[int] = 0x02
    NAME: ClassVar[str] = "CONFIG"
    LAYOUT: ClassVar = (
        ("pan_min", "i", True), ("pan_max", "i", True), ("tilt_min", "i", True), ("tilt_max", "i", True),
        ("vmax_pan", "i", True), ("vmax_tilt", "i", True), ("amax_pan", "i", True), ("amax_tilt", "i", True),
        ("watchdog_ms", "H", False),
    )


@dataclass(frozen=True, slots=True)
class Enable(Message):
    """host→dev 0x03: on = 1 enables tracking, 0 disables."""

    on: int
    TYPE: ClassVar[int] = 0x03
    NAME: ClassVar[str] = "ENABLE"
    LAYOUT: ClassVar = (("on", "B", False),)


@dataclass(frozen=True, slots=True)
class Setpoint(Message):
    """host→dev 0x04 (version 2): target pan/tilt [rad], feed-forward rates [rad/s], host clock [µs, wraps], and
    its validity: ``state_time_us``, the device clock [µs, wraps] of the newest STATE the host had when it sent
    it, and ``max_age_ms``, the age on the device clock beyond which it is stale and must not be executed
    (:func:`setpoint_is_fresh`). The defaults make a setpoint that is stale everywhere but at device time 0.
    Never ACKed."""

    pan: float
    tilt: float
    pan_rate: float = 0.0
    tilt_rate: float = 0.0
    host_time_us: int = 0
    state_time_us: int = 0
    max_age_ms: int = 0
    TYPE: ClassVar[int] = 0x04
    NAME: ClassVar[str] = "SETPOINT"
    LAYOUT: ClassVar = (
        ("pan", "i", True), ("tilt", "i", True), ("pan_rate", "i", True), ("tilt_rate", "i", True),
        ("host_time_us", "I", False), ("state_time_us", "I", False), ("max_age_ms", "H", False),
    )


@dataclass(frozen=True, slots=True)
class SetpointV1(Message):
    """host→dev 0x04 in protocol version 1: target pan/tilt [rad], feed-forward rates [rad/s], host clock [µs,
    wraps; for logging only]. It carries no validity: a version-1 device executes it whenever it arrives."""

    pan: float
    tilt: float
    pan_rate: float = 0.0
    tilt_rate: float = 0.0
    host_time_us: int = 0
    TYPE: ClassVar[int] = 0x04
    NAME: ClassVar[str] = "SETPOINT"
    LAYOUT: ClassVar = (
        ("pan", "i", True), ("tilt", "i", True), ("pan_rate", "i", True), ("tilt_rate", "i", True),
        ("host_time_us", "I", False),
    )


_U32 = 1 << 32


def setpoint_age_us(device_time_us: int, state_time_us: int) -> int:
    """Age [µs] of a setpoint that echoes the STATE stamped ``state_time_us`` at device time ``device_time_us``:
    the difference modulo 2³² (both clocks wrap), so a stamp from the future or from before a wrap reads as very
    old, never as young."""
    return (int(device_time_us) - int(state_time_us)) % _U32


def setpoint_is_fresh(sp: Setpoint, device_time_us: int) -> bool:
    """Whether the device may execute ``sp`` at device time ``device_time_us`` [µs]: its age (since the STATE it
    echoes) is at most ``max_age_ms``."""
    return setpoint_age_us(device_time_us, sp.state_time_us) <= sp.max_age_ms * 1000


@dataclass(frozen=True, slots=True)
class Heartbeat(Message):
    """host→dev 0x05: feeds the watchdog like a SETPOINT, without moving."""

    TYPE: ClassVar[int] = 0x05
    NAME: ClassVar[str] = "HEARTBEAT"
    LAYOUT: ClassVar = ()


@dataclass(frozen=True, slots=True)
class ClearFault(Message):
    """host→dev 0x06: clear all latched fault bits (ACKed)."""

    TYPE: ClassVar[int] = 0x06
    NAME: ClassVar[str] = "CLEAR_FAULT"
    LAYOUT: ClassVar = ()


@dataclass(frozen=True, slots=True)
class State(Message):
    """dev→host 0x40: device clock [µs, wraps], measured pan/tilt [rad] and rates [rad/s], mode, fault bits."""

    device_time_us: int
    pan: float
    tilt: float
    pan_rate: float
    tilt_rate: float
    last_setpoint_seq: int
    mode: int
    faults: int
    TYPE: ClassVar[int] = 0x40
    NAME: ClassVar[str] = "STATE"
    LAYOUT: ClassVar = (
        ("device_time_us", "I", False), ("pan", "i", True), ("tilt", "i", True), ("pan_rate", "i", True),
        ("tilt_rate", "i", True), ("last_setpoint_seq", "B", False), ("mode", "B", False), ("faults", "H", False),
    )


@dataclass(frozen=True, slots=True)
class Identity(Message):
    """dev→host 0x41: answer to HELLO. Its layout is frozen across all protocol versions."""

    version: int
    fw_major: int
    fw_minor: int
    fw_patch: int
    capabilities: int
    serial: int
    TYPE: ClassVar[int] = 0x41
    NAME: ClassVar[str] = "IDENTITY"
    LAYOUT: ClassVar = (
        ("version", "B", False), ("fw_major", "B", False), ("fw_minor", "B", False), ("fw_patch", "B", False),
        ("capabilities", "I", False), ("serial", "I", False),
    )


@dataclass(frozen=True, slots=True)
class Ack(Message):
    """dev→host 0x42: acknowledges CONFIG / ENABLE / CLEAR_FAULT by (seq, type); status 0 ok, else NACK reason."""

    acked_seq: int
    acked_type: int
    status: int
    value: int = 0
    TYPE: ClassVar[int] = 0x42
    NAME: ClassVar[str] = "ACK"
    LAYOUT: ClassVar = (("acked_seq", "B", False), ("acked_type", "B", False), ("status", "B", False),
                        ("value", "I", False))


#: CONFIG validity on the device (PROTOCOL.md §4): watchdog range [ms] and joint limit magnitude [rad]
CONFIG_WATCHDOG_MS_MIN, CONFIG_WATCHDOG_MS_MAX = 10, 10_000
CONFIG_LIMIT_ABS_MAX = 2 * math.pi
CONFIG_LIMITS = ("pan_min", "pan_max", "tilt_min", "tilt_max")
CONFIG_RATES = ("vmax_pan", "vmax_tilt", "amax_pan", "amax_tilt")


def config_problems(cfg: Config) -> list[tuple[str, str]]:
    """(field, reason) for each CONFIG value the device would refuse or the wire cannot carry faithfully.

    Values are judged as they arrive on the wire: rounded to micro-units (a rate that rounds to 0 is
    refused; a value beyond int32 micro-units would be saturated). Empty when the device accepts ``cfg``
    with exactly these values.
    """
    out: list[tuple[str, str]] = []
    for name in CONFIG_LIMITS + CONFIG_RATES:
        v = getattr(cfg, name)
        if not math.isfinite(v) or not I32_MIN <= round(v * MICRO) <= I32_MAX:
            out.append((name, f"{v:g} does not fit the wire's int32 micro-units (±{I32_MAX / MICRO:g})"))
    if out:
        return out
    wire = Config.from_raw(cfg.raw())
    for name in CONFIG_LIMITS:
        if abs(getattr(wire, name)) > CONFIG_LIMIT_ABS_MAX:
            out.append((name, f"{getattr(wire, name):g} rad is beyond ±2π"))
    for lo, hi in (("pan_min", "pan_max"), ("tilt_min", "tilt_max")):
        if not getattr(wire, lo) < getattr(wire, hi):
            out.append((hi, f"{hi} must exceed {lo} on the wire (µrad resolution)"))
    for name in CONFIG_RATES:
        if getattr(wire, name) <= 0:
            out.append((name, f"{getattr(cfg, name):g} rounds to {to_micro(getattr(cfg, name))} micro-units "
                              "on the wire; must be > 0"))
    if not CONFIG_WATCHDOG_MS_MIN <= cfg.watchdog_ms <= CONFIG_WATCHDOG_MS_MAX:
        out.append(("watchdog_ms", f"{cfg.watchdog_ms} ms is outside [{CONFIG_WATCHDOG_MS_MIN}, "
                                   f"{CONFIG_WATCHDOG_MS_MAX}]"))
    return out


MESSAGE_TYPES: dict[int, type[Message]] = {
    cls.TYPE: cls for cls in (Hello, Config, Enable, Setpoint, Heartbeat, ClearFault, State, Identity, Ack)
}  # the layouts of PROTOCOL_VERSION
#: the message classes of each known version: version 1 differs only in SETPOINT
MESSAGE_TYPES_BY_VERSION: dict[int, dict[int, type[Message]]] = {
    1: {**MESSAGE_TYPES, SetpointV1.TYPE: SetpointV1},
    2: MESSAGE_TYPES,
}
MESSAGE_BY_NAME: dict[str, type[Message]] = {cls.NAME: cls for cls in MESSAGE_TYPES.values()}


def message_types(version: int) -> dict[int, type[Message]]:
    """Message classes by type of protocol ``version`` (an unknown version: those of PROTOCOL_VERSION)."""
    return MESSAGE_TYPES_BY_VERSION.get(version, MESSAGE_TYPES)


def field_names(cls: type[Message]) -> list[str]:
    """Payload field names of a message class, in wire order."""
    return [f.name for f in fields(cls)]  # type: ignore[arg-type]
