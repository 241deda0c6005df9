"""Test vectors shared by the Python and C codecs: build, load, and export as a C header.

``python -m pivotd.firmware_proto.vectors --json pivotd/firmware_proto/vectors.json`` regenerates the JSON file;
``--c-header FILE`` writes the same vectors as a C99 header for the firmware test program.
Frame vectors map message fields (wire integers in ``raw``, SI values in ``fields``) to exact
frame bytes; stream vectors map a byte stream to the frames and drop counts a decoder must produce;
setpoint-validity vectors map (device clock, echoed STATE time, max age) to the age and the verdict a
device must reach (PROTOCOL.md §4, SETPOINT).
"""

from __future__ import annotations

import argparse
import json
from dataclasses import asdict
from pathlib import Path
from typing import Any

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    I32_MAX,
    I32_MIN,
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
    field_names,
    setpoint_age_us,
    setpoint_is_fresh,
)

VECTORS_JSON = Path(__file__).with_name("vectors.json")
U32_MAX = 2**32 - 1


def _frame_cases() -> list[tuple[str, int, Message]]:
    """(name, seq, message) for every message type, with edge values."""
    m = 1e-6  # one micro-unit
    return [
        ("hello", 0, Hello(PROTOCOL_VERSION)),
        ("hello_seq255", 255, Hello(PROTOCOL_VERSION)),
        ("config_typical", 1, Config(-3.0, 3.0, -1.2, 0.5, 2.0, 1.5, 10.0, 8.0, 250)),
        ("config_edges", 2, Config(I32_MIN * m, I32_MAX * m, -1 * m, 0.0, 1 * m, I32_MAX * m, 1 * m, 65.536, 65535)),
        ("enable_on", 3, Enable(1)),
        ("enable_off_zero_payload", 4, Enable(0)),
        ("setpoint_typical", 5, Setpoint(0.25, -0.125, 0.5, -0.0625, 123456, 1_000_000, 200)),
        ("setpoint_zeros", 0, Setpoint(0.0, 0.0, 0.0, 0.0, 0, 0, 0)),
        ("setpoint_edges", 254, Setpoint(I32_MIN * m, I32_MAX * m, -1 * m, 1 * m, U32_MAX, U32_MAX, 65535)),
        ("heartbeat", 6, Heartbeat()),
        ("clear_fault", 7, ClearFault()),
        ("state_typical", 8, State(1_000_000, 0.5, -0.25, 1.0, -1.0, 5, 1, 0)),
        ("state_edges", 9, State(U32_MAX, I32_MIN * m, I32_MAX * m, -1 * m, 1 * m, 255, 3, 0xFFFF)),
        ("state_holding_watchdog", 10, State(20_000, 0.0, 0.0, 0.0, 0.0, 0, 2, 0x0010)),
        ("identity", 11, Identity(PROTOCOL_VERSION, 1, 0, 0, 7, 0x00C0FFEE)),
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
        "version": PROTOCOL_VERSION,
        "fields": asdict(msg),  # type: ignore[call-overload]
        "raw": dict(zip(field_names(type(msg)), msg.raw(), strict=True)),
        "body_hex": codec.encode_body(msg, seq).hex(),
        "frame_hex": codec.encode(msg, seq).hex(),
    }


def _stream_cases() -> list[tuple[str, bytes]]:
    st = codec.encode(State(42, 0.1, 0.2, 0.0, 0.0, 3, 1, 0), 20)
    sp = codec.encode(Setpoint(0.5, -0.5, 0.0, 0.0, 7, 40, 100), 21)
    v = bytes((PROTOCOL_VERSION,))
    other = bytes((PROTOCOL_VERSION + 1,))
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
        ("wrong_version", frame_of(body_with_crc(other + b"\x40\x01" + bytes(24))) + sp),
        ("identity_other_version", frame_of(body_with_crc(other + b"\x41\x01" + bytes((3, 3, 0, 1)) + bytes(8)))),
        ("unknown_type", frame_of(body_with_crc(v + b"\x7f\x01\x01\x02")) + st),
        ("wrong_payload_length", frame_of(body_with_crc(v + b"\x40\x01" + bytes(23))) + sp),
        ("too_short", frame_of(v + b"\x40\x01\x00") + st),
        # a version-1 SETPOINT (no validity) is another version's frame; its 20-byte payload under this version's
        # header is a wrong payload length: neither is ever executed without a validity
        ("setpoint_v1_is_another_version", codec.encode(SetpointV1(0.5, -0.5, 0.0, 0.0, 7), 23, version=1) + st),
        ("setpoint_v1_payload_under_v2", frame_of(body_with_crc(v + b"\x04\x18" + SetpointV1(0.5, -0.5).pack()))
         + st),
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


def _validity_cases() -> list[tuple[str, int, int, int]]:
    """(name, device clock [µs], echoed STATE time [µs], max_age_ms) of SETPOINT validity, with the edges."""
    return [
        ("fresh_typical", 1_020_000, 1_000_000, 200),
        ("at_the_limit", 1_200_000, 1_000_000, 200),
        ("one_us_past_the_limit", 1_200_001, 1_000_000, 200),
        ("after_a_2s_device_stall", 3_000_000, 1_000_000, 200),
        ("same_microsecond_zero_age", 5_000, 5_000, 0),
        ("zero_validity_one_us_old", 5_001, 5_000, 0),
        ("across_the_clock_wrap", 100, U32_MAX - 899, 1),
        ("state_time_from_the_future", 1_000, 2_000, 65535),
        ("longest_validity", 65_535_000, 0, 65535),
        ("longest_validity_exceeded", 65_535_001, 0, 65535),
    ]


def _validity_vector(name: str, device_us: int, state_us: int, max_age_ms: int) -> dict[str, Any]:
    sp = Setpoint(0.0, 0.0, 0.0, 0.0, 0, state_us, max_age_ms)
    return {"name": name, "device_time_us": device_us, "state_time_us": state_us, "max_age_ms": max_age_ms,
            "age_us": setpoint_age_us(device_us, state_us), "fresh": setpoint_is_fresh(sp, device_us)}


def build_vectors() -> dict[str, Any]:
    """All vectors as the JSON-ready dictionary stored in vectors.json."""
    return {
        "protocol_version": PROTOCOL_VERSION,
        "crc_check": {"input_ascii": "123456789", "crc16": codec.crc16(b"123456789")},
        "frames": [_frame_vector(*case) for case in _frame_cases()],
        "streams": [_stream_vector(*case) for case in _stream_cases()],
        "setpoint_validity": [_validity_vector(*case) for case in _validity_cases()],
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
        "/* Generated by python -m pivotd.firmware_proto.vectors --c-header; do not edit. */",
        "#ifndef PP_VECTORS_H", "#define PP_VECTORS_H", "#include <stddef.h>", "#include <stdint.h>", "",
        "typedef struct { const char *name; uint8_t type; uint8_t seq; int64_t raw[9]; size_t nraw;",
        "                 uint8_t frame[80]; size_t frame_len; } pp_frame_vector;",
        "typedef struct { uint8_t type; uint8_t seq; uint8_t version; int64_t raw[9]; size_t nraw; }",
        "        pp_expected_frame;",
        "typedef struct { const char *name; uint8_t stream[256]; size_t stream_len;",
        "                 pp_expected_frame frames[4]; size_t nframes; uint32_t drops[6]; } pp_stream_vector;",
        "typedef struct { const char *name; uint32_t device_time_us, state_time_us; uint16_t max_age_ms;",
        "                 uint32_t age_us; int fresh; } pp_validity_vector;",
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
    lines += ["};", "", "static const pp_validity_vector PP_VALIDITY_VECTORS[] = {"]
    for c in vectors["setpoint_validity"]:
        lines.append(f'    {{"{c["name"]}", {c["device_time_us"]}u, {c["state_time_us"]}u, {c["max_age_ms"]}u, '
                     f'{c["age_us"]}u, {int(c["fresh"])}}},')
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
