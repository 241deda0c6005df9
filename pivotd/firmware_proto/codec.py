"""Frame encoder and incremental stream decoder (PROTOCOL.md §2).

Wire frame: ``COBS(body) 0x00`` with ``body = version | type | seq | payload | crc16_le``; the
CRC-16/CCITT-FALSE covers version..payload. The decoder accepts arbitrary byte chunks, resyncs on
the 0x00 delimiter after garbage and drops (and counts, per reason) every frame that is not valid.
"""

from __future__ import annotations

import binascii
import struct
from dataclasses import dataclass

from cobs import cobs

from pivotd.firmware_proto.messages import (
    MAX_BODY,
    MESSAGE_TYPES_BY_VERSION,
    PROTOCOL_VERSION,
    Hello,
    Identity,
    Message,
    message_types,
)

#: longest COBS encoding of a MAX_BODY body (one overhead byte per 254 data bytes)
MAX_ENCODED = MAX_BODY + 1 + MAX_BODY // 254
_CRC = struct.Struct("<H")

#: types whose layout is frozen across versions, accepted whatever the version byte says
VERSIONLESS_TYPES = frozenset((Hello.TYPE, Identity.TYPE))

DROP_REASONS = ("framing", "length", "crc", "version", "unknown_type", "payload")


def crc16(data: bytes | bytearray | memoryview) -> int:
    """CRC-16/CCITT-FALSE (poly 0x1021, init 0xFFFF, no reflection, no final xor)."""
    return binascii.crc_hqx(data, 0xFFFF)


def encode_body(msg: Message, seq: int, version: int = PROTOCOL_VERSION) -> bytes:
    """Unframed body ``version | type | seq | payload | crc`` of ``msg``; raises ValueError if it does not fit, or if
    ``msg`` has a layout other than the one of its type in ``version`` (when that version is known)."""
    table = MESSAGE_TYPES_BY_VERSION.get(version)
    if table is not None and table.get(msg.TYPE) is not type(msg):
        raise ValueError(f"{type(msg).__name__} is not the {msg.NAME} layout of protocol version {version}")
    head = bytes((version & 0xFF, msg.TYPE, seq & 0xFF)) + msg.pack()
    if len(head) + 2 > MAX_BODY:
        raise ValueError(f"{msg.NAME}: body of {len(head) + 2} bytes exceeds {MAX_BODY}")
    return head + _CRC.pack(crc16(head))


def encode(msg: Message, seq: int, version: int = PROTOCOL_VERSION) -> bytes:
    """Complete wire frame ``COBS(body) 0x00`` of ``msg`` with sequence number ``seq`` (taken mod 256)."""
    return cobs.encode(encode_body(msg, seq, version)) + b"\x00"


@dataclass(frozen=True, slots=True)
class Frame:
    """One decoded, valid frame."""

    version: int
    seq: int
    msg: Message

    @property
    def type(self) -> int:
        return self.msg.TYPE


class StreamDecoder:
    """Incremental decoder: ``feed(chunk)`` returns the valid frames completed by ``chunk``.

    Invalid frames are dropped and counted in :attr:`drops` by reason: ``framing`` (bad COBS),
    ``length`` (body too short or too long, or no delimiter within the maximum frame length),
    ``crc``, ``version`` (a version this decoder does not speak; HELLO and IDENTITY are exempt
    because their layouts are frozen), ``unknown_type``, ``payload`` (payload length wrong for the type).
    """

    def __init__(self, version: int = PROTOCOL_VERSION) -> None:
        self.version = version
        self._buf = b""
        self._discarding = False  # inside an over-long segment: skip until the next delimiter
        self.frames_ok = 0
        self.drops: dict[str, int] = dict.fromkeys(DROP_REASONS, 0)

    @property
    def version(self) -> int:
        """The protocol version this decoder accepts (and whose layouts it decodes)."""
        return self._version

    @version.setter
    def version(self, value: int) -> None:
        self._version = value
        self._types = message_types(value)

    @property
    def dropped(self) -> int:
        """Total number of dropped frames."""
        return sum(self.drops.values())

    def reset(self) -> None:
        """Forget any partial frame (counters are kept)."""
        self._buf = b""
        self._discarding = False

    def feed(self, chunk: bytes | bytearray | memoryview) -> list[Frame]:
        """Consume ``chunk``; return the frames it completed, in order."""
        parts = (self._buf + bytes(chunk)).split(b"\x00")
        self._buf = parts.pop()
        out: list[Frame] = []
        for segment in parts:
            if self._discarding:
                self._discarding = False
                continue
            if segment:
                frame = self.decode_segment(segment)
                if frame is not None:
                    out.append(frame)
        if len(self._buf) > MAX_ENCODED:
            self._buf = b""
            if not self._discarding:
                self.drops["length"] += 1
                self._discarding = True
        return out

    def decode_segment(self, segment: bytes) -> Frame | None:
        """Decode one COBS segment (without delimiter); count and return None if invalid."""
        drops = self.drops
        if len(segment) > MAX_ENCODED:
            drops["length"] += 1
            return None
        try:
            body = cobs.decode(segment)
        except cobs.DecodeError:
            drops["framing"] += 1
            return None
        n = len(body)
        if n < 5 or n > MAX_BODY:
            drops["length"] += 1
            return None
        if binascii.crc_hqx(body[:-2], 0xFFFF) != body[-2] | (body[-1] << 8):
            drops["crc"] += 1
            return None
        version, mtype, seq = body[0], body[1], body[2]
        if version != self._version and mtype not in VERSIONLESS_TYPES:
            drops["version"] += 1
            return None
        cls = self._types.get(mtype)
        if cls is None:
            drops["unknown_type"] += 1
            return None
        try:
            msg = cls.unpack(body[3:-2])
        except struct.error:
            drops["payload"] += 1
            return None
        self.frames_ok += 1
        return Frame(version, seq, msg)

    def counters(self) -> dict[str, int]:
        """``frames_ok`` and one ``drop_<reason>`` entry per reason."""
        return {"frames_ok": self.frames_ok, **{f"drop_{k}": v for k, v in self.drops.items()}}
