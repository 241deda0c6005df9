"""DYNAMIXEL Protocol 2.0 packets, written from the published specification, for the servo simulator and tests.

Packet: ``FF FF FD 00 | ID | LEN_L LEN_H | INST | params… | CRC_L CRC_H``; LEN counts INST, params and CRC
(after stuffing); the CRC-16 (polynomial 0x8005, initial value 0, no reflection) covers everything before it.
Byte stuffing: inside INST and params, every ``FF FF FD`` is followed by an extra ``FD``. A status packet has
INST 0x55 and an error byte first among its params (bit 7: hardware error alert, bits 0–6: error number).
"""

from __future__ import annotations

import struct
from dataclasses import dataclass

HEADER = b"\xff\xff\xfd\x00"
BROADCAST_ID = 0xFE
INST_PING, INST_READ, INST_WRITE, INST_REBOOT = 0x01, 0x02, 0x03, 0x08
INST_STATUS, INST_SYNC_READ, INST_SYNC_WRITE, INST_FAST_SYNC_READ = 0x55, 0x82, 0x83, 0x8A
ERR_RESULT_FAIL, ERR_INSTRUCTION, ERR_CRC, ERR_DATA_RANGE, ERR_DATA_LENGTH, ERR_DATA_LIMIT, ERR_ACCESS = range(1, 8)
ERR_ALERT = 0x80


def crc16(data: bytes) -> int:
    """CRC-16 of the specification: polynomial 0x8005, initial value 0, MSB first."""
    crc = 0
    for byte in data:
        crc ^= byte << 8
        for _ in range(8):
            crc = ((crc << 1) ^ 0x8005) if crc & 0x8000 else (crc << 1)
            crc &= 0xFFFF
    return crc


def stuff(body: bytes) -> bytes:
    """Insert ``FD`` after every ``FF FF FD`` of the instruction and parameters."""
    out = bytearray()
    for b in body:
        out.append(b)
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd":
            out.append(0xFD)
    return bytes(out)


def unstuff(body: bytes) -> bytes:
    """Remove the ``FD`` that follows every ``FF FF FD``."""
    out = bytearray()
    i = 0
    while i < len(body):
        out.append(body[i])
        if len(out) >= 3 and out[-3:] == b"\xff\xff\xfd" and i + 1 < len(body) and body[i + 1] == 0xFD:
            i += 1
        i += 1
    return bytes(out)


def encode(dxl_id: int, inst: int, params: bytes = b"") -> bytes:
    """One packet (instruction or status) with stuffing and CRC."""
    body = stuff(bytes([inst]) + params)
    head = HEADER + bytes([dxl_id]) + struct.pack("<H", len(body) + 2)
    return head + body + struct.pack("<H", crc16(head + body))


def status(dxl_id: int, error: int, params: bytes = b"") -> bytes:
    """A status packet: error byte, then ``params``."""
    return encode(dxl_id, INST_STATUS, bytes([error]) + params)


@dataclass(frozen=True)
class Packet:
    """A decoded packet: id, instruction, unstuffed parameters."""

    dxl_id: int
    inst: int
    params: bytes


class PacketDecoder:
    """Splits a byte stream into packets; drops bytes before a header and packets with a bad CRC (counted)."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.crc_errors = 0

    def feed(self, data: bytes) -> list[Packet]:
        self.buf += data
        out: list[Packet] = []
        while True:
            start = self.buf.find(HEADER)
            if start < 0:
                del self.buf[: max(0, len(self.buf) - 3)]
                return out
            del self.buf[:start]
            if len(self.buf) < 7:
                return out
            length = struct.unpack_from("<H", self.buf, 5)[0]
            total = 7 + length
            if length < 3 or total > 1024:
                del self.buf[:1]
                continue
            if len(self.buf) < total:
                return out
            frame = bytes(self.buf[:total])
            del self.buf[:total]
            if crc16(frame[:-2]) != struct.unpack_from("<H", frame, total - 2)[0]:
                self.crc_errors += 1
                continue
            body = unstuff(frame[7:-2])
            out.append(Packet(frame[4], body[0], body[1:]))
