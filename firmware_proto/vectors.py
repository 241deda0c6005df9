"""Test vectors shared by the Python and C codecs: build, load, and export as a C header.

``python -m firmware_proto.vectors --json firmware_proto/vectors.json`` regenerates the JSON file;
``--c-header FILE`` writes the same vectors as a C99 header for the firmware test program.
Frame vectors map message fields (wire integers in ``raw``, SI values in ``fields``) to exact
frame bytes; stream vectors map a byte stream to the frames and drop counts a decoder must produce.
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

from firmware_proto import codec
from firmware_proto.messages import (
    I32_MAX,
    I32_MIN,
    Ack,
    ClearFault,
    Config,
    Enable,
    Heartbeat,
    Hello,
    Identity,
    Message,
    Setpoint,
    State,
    field_names,
)

VECTORS_JSON = Path(__file__).with_name("vectors.json")
U32_MAX = 2**32 - 1


def _frame_cases() -> list[tuple[str, int, Message]]:
    """(name, seq, message) for every message type, with edge values."""
    m = 1e-6  # one micro-unit
    return [
        ("hello", 0, Hello(1)),
        ("hello_seq255", 255, Hello(1)),
        ("config_typical", 1, Config(-3.0, 3.0, -1.2, 0.5, 2.0, 1.5, 10.0, 8.0, 250)),
        ("config_edges", 2, Config(I32_MIN * m, I32_MAX * m, -1 * m, 0.0, 1 * m, I32_MAX * m, 1 * m, 65.536, 65535)),
        ("enable_on", 3, Enable(1)),
        ("enable_off_zero_payload", 4, Enable(0)),
        ("setpoint_typical", 5, Setpoint(0.25, -0.125, 0.5, -0.0625, 123456)),
        ("setpoint_zeros", 0, Setpoint(0.0, 0.0, 0.0, 0.0, 0)),
        ("setpoint_edges", 254, Setpoint(I32_MIN * m, I32_MAX * m, -1 * m, 1 * m, U32_MAX)),
        ("heartbeat", 6, Heartbeat()),
        ("clear_fault", 7, ClearFault()),
        ("state_typical", 8, State(1_000_000, 0.5, -0.25, 1.0, -1.0, 5, 1, 0)),
        ("state_edges", 9, State(U32_MAX, I32_MIN * m, I32_MAX * m, -1 * m, 1 * m, 255, 3, 0xFFFF)),
        ("state_holding_watchdog", 10, State(20_000, 0.0, 0.0, 0.0, 0.0, 0, 2, 0x0010)),
        ("identity", 11, Identity(1, 1, 0, 0, 7, 0x00C0FFEE)),
        ("ack_config", 12, Ack(1, Config.TYPE, 0, 0xDEADBEEF)),
        ("nack_config_invalid", 13, Ack(2, Config.TYPE, 1, 0)),
        ("ack_enable", 14, Ack(3, Enable.TYPE, 0, 0)),
    ]


def _frame_vector(name: str, seq: int, msg: Message) -> dict[str, Any]:
    return {
        "name": name,
        "type": msg.NAME,
        "type_id": msg.TYPE,
        "seq": seq,
        "version": 1,
        "fields": asdict(msg),  # type: ignore[call-overload]
        "raw": dict(zip(field_names(type(msg)), msg.raw(), strict=True)),
        "body_hex": codec.encode_body(msg, seq).hex(),
        "frame_hex": codec.encode(msg, seq).hex(),
    }


def _stream_cases() -> list[tuple[str, bytes]]:
    st = codec.encode(State(42, 0.1, 0.2, 0.0, 0.0, 3, 1, 0), 20)
    sp = codec.encode(Setpoint(0.5, -0.5, 0.0, 0.0, 7), 21)
    bad_crc = bytearray(codec.encode_body(Ack(1, 2, 0, 5), 22))
    bad_crc[-1] ^= 0x01
    from cobs import cobs

    def frame_of(body: bytes) -> bytes:
        return cobs.encode(body) + b"\x00"

    def body_with_crc(head: bytes) -> bytes:
        return head + codec.crc16(head).to_bytes(2, "little")

    return [
        ("two_frames", st + sp),
        ("garbage_then_frame", b"\x13\x37\xff\xfe\x01\x00" + st),
        ("leading_delimiters", b"\x00\x00\x00" + sp),
        ("bad_crc_then_frame", frame_of(bytes(bad_crc)) + st),
        ("wrong_version", frame_of(body_with_crc(b"\x02\x40\x01" + bytes(24))) + sp),
        ("identity_other_version", frame_of(body_with_crc(b"\x02\x41\x01" + bytes((2, 3, 0, 1)) + bytes(8)))),
        ("unknown_type", frame_of(body_with_crc(b"\x01\x7f\x01\x01\x02")) + st),
        ("wrong_payload_length", frame_of(body_with_crc(b"\x01\x40\x01" + bytes(23))) + sp),
        ("too_short", frame_of(b"\x01\x40\x01\x00") + st),
        ("overlong_segment", bytes(range(1, 101)) + b"\x00" + sp),
        ("truncated_frame_then_frame", st[:10] + b"\x00" + sp),
    ]


def _stream_vector(name: str, stream: bytes) -> dict[str, Any]:
    dec = codec.StreamDecoder()
    frames = dec.feed(stream)
    return {
        "name": name,
        "stream_hex": stream.hex(),
        "frames": [
            {"type_id": f.msg.TYPE, "seq": f.seq, "version": f.version, "raw": list(f.msg.raw())} for f in frames
        ],
        "drops": dict(dec.drops),
    }


def build_vectors() -> dict[str, Any]:
    """All vectors as the JSON-ready dictionary stored in vectors.json."""
    return {
        "protocol_version": 1,
        "crc_check": {"input_ascii": "123456789", "crc16": codec.crc16(b"123456789")},
        "frames": [_frame_vector(*case) for case in _frame_cases()],
        "streams": [_stream_vector(*case) for case in _stream_cases()],
    }


def load_vectors(path: Path = VECTORS_JSON) -> dict[str, Any]:
    """The stored vectors."""
    return json.loads(Path(path).read_text())


def _c_bytes(hex_str: str) -> str:
    data = bytes.fromhex(hex_str)
    return "{" + ", ".join(f"0x{b:02x}" for b in data) + "}" if data else "{0}"


def c_header(vectors: dict[str, Any]) -> str:
    """The vectors as a C99 header (``pp_vectors.h``) for firmware/c/test_vectors.c."""
    drop_keys = list(codec.DROP_REASONS)
    lines = [
        "/* Generated by python -m firmware_proto.vectors --c-header; do not edit. */",
        "#ifndef PP_VECTORS_H", "#define PP_VECTORS_H", "#include <stddef.h>", "#include <stdint.h>", "",
        "typedef struct { const char *name; uint8_t type; uint8_t seq; int64_t raw[9]; size_t nraw;",
        "                 uint8_t frame[80]; size_t frame_len; } pp_frame_vector;",
        "typedef struct { uint8_t type; uint8_t seq; uint8_t version; int64_t raw[9]; size_t nraw; }",
        "        pp_expected_frame;",
        "typedef struct { const char *name; uint8_t stream[256]; size_t stream_len;",
        "                 pp_expected_frame frames[4]; size_t nframes; uint32_t drops[6]; } pp_stream_vector;",
        f"/* drops[] order: {', '.join(drop_keys)} */", "",
        "static const pp_frame_vector PP_FRAME_VECTORS[] = {",
    ]
    for v in vectors["frames"]:
        raw = list(v["raw"].values())
        raw_c = "{" + ", ".join(f"{x}LL" for x in raw) + "}" if raw else "{0}"
        n = len(bytes.fromhex(v["frame_hex"]))
        lines.append(f'    {{"{v["name"]}", 0x{v["type_id"]:02x}, {v["seq"]}, {raw_c}, {len(raw)}, '
                     f'{_c_bytes(v["frame_hex"])}, {n}}},')
    lines += ["};", "", "static const pp_stream_vector PP_STREAM_VECTORS[] = {"]
    for s in vectors["streams"]:
        frames = []
        for f in s["frames"]:
            raw_c = "{" + ", ".join(f"{x}LL" for x in f["raw"]) + "}" if f["raw"] else "{0}"
            frames.append(f'{{0x{f["type_id"]:02x}, {f["seq"]}, {f["version"]}, {raw_c}, {len(f["raw"])}}}')
        frames_c = "{" + ", ".join(frames) + "}" if frames else "{{0}}"
        drops_c = "{" + ", ".join(str(s["drops"][k]) for k in drop_keys) + "}"
        n = len(bytes.fromhex(s["stream_hex"]))
        lines.append(f'    {{"{s["name"]}", {_c_bytes(s["stream_hex"])}, {n}, {frames_c}, {len(frames)}, {drops_c}}},')
    lines += ["};", "", f"#define PP_CRC_CHECK 0x{vectors['crc_check']['crc16']:04x}u", "#endif", ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--json", type=Path, help="write freshly built vectors to this JSON file")
    parser.add_argument("--c-header", type=Path, help="write the stored vectors.json as a C header")
    args = parser.parse_args(argv)
    if args.json:
        args.json.write_text(json.dumps(build_vectors(), indent=1) + "\n")
    if args.c_header:
        args.c_header.write_text(c_header(load_vectors()))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
