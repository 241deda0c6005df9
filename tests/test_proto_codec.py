"""Codec: CRC, round trip of every message, SI <-> micro-unit conversion, vectors (Python side)."""

import binascii
import math

import pytest
from cobs import cobs

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    MAX_BODY,
    MESSAGE_BY_NAME,
    MESSAGE_TYPES,
    PROTOCOL_VERSION,
    Ack,
    ClearFault,
    Config,
    Enable,
    Heartbeat,
    Hello,
    Identity,
    Setpoint,
    SetpointV1,
    State,
    from_micro,
    setpoint_age_us,
    setpoint_is_fresh,
    to_micro,
)
from pivotd.firmware_proto.vectors import build_vectors, load_vectors

SAMPLES = [
    Hello(1), Config(-3.0, 3.0, -1.0, 1.0, 2.0, 2.0, 10.0, 10.0, 250), Enable(1), Enable(0),
    Setpoint(0.1, -0.2, 0.3, -0.4, 99, 12345, 200), Heartbeat(), ClearFault(),
    State(123456, 1.5, -0.5, 0.25, -0.125, 17, 2, 0x30), Identity(1, 2, 3, 4, 5, 6), Ack(7, 2, 0, 0xFFFFFFFF),
]


def test_crc_check_value() -> None:
    assert codec.crc16(b"123456789") == 0x29B1


def test_every_message_type_has_a_sample() -> None:
    assert {type(m) for m in SAMPLES} == set(MESSAGE_TYPES.values())


@pytest.mark.parametrize("msg", SAMPLES, ids=lambda m: m.NAME)
@pytest.mark.parametrize("seq", [0, 1, 255])
def test_round_trip(msg, seq) -> None:
    frame = codec.encode(msg, seq)
    assert frame.endswith(b"\x00") and frame.count(0) == 1
    body = cobs.decode(frame[:-1])
    assert body[:3] == bytes((PROTOCOL_VERSION, msg.TYPE, seq))
    assert len(body) <= MAX_BODY
    assert int.from_bytes(body[-2:], "little") == binascii.crc_hqx(body[:-2], 0xFFFF)
    (decoded,) = codec.StreamDecoder().feed(frame)
    assert decoded.seq == seq and decoded.version == PROTOCOL_VERSION
    assert decoded.msg == msg


def test_body_sizes_match_the_contract() -> None:
    sizes = {m.NAME: len(codec.encode_body(m, 0)) - 5 for m in SAMPLES}
    assert sizes == {"HELLO": 1, "CONFIG": 34, "ENABLE": 1, "SETPOINT": 26, "HEARTBEAT": 0, "CLEAR_FAULT": 0,
                     "STATE": 24, "IDENTITY": 12, "ACK": 7}


def test_micro_unit_conversion_rounds_and_saturates() -> None:
    assert to_micro(1.0) == 1_000_000
    assert to_micro(-0.0000015) == -2  # round half to even of -1.5
    assert to_micro(0.0000014) == 1
    assert to_micro(1e6) == 2**31 - 1
    assert to_micro(-1e6) == -(2**31)
    assert from_micro(-2_500_000) == -2.5
    with pytest.raises(ValueError, match="non-finite"):
        to_micro(math.nan)
    with pytest.raises(ValueError, match="non-finite"):
        codec.encode(Setpoint(math.inf, 0.0), 0)


def test_angles_are_micro_radians_on_the_wire() -> None:
    body = codec.encode_body(Setpoint(0.000001, -1.0, 0.5, 0.0, 7), 3)
    assert body[3:7] == (1).to_bytes(4, "little", signed=True)
    assert body[7:11] == (-1_000_000).to_bytes(4, "little", signed=True)
    assert body[11:15] == (500_000).to_bytes(4, "little", signed=True)
    assert body[19:23] == (7).to_bytes(4, "little")


def test_out_of_range_integer_field_is_rejected() -> None:
    with pytest.raises(ValueError, match="out of range"):
        codec.encode(Ack(256, 2, 0, 0), 0)


def test_stored_vectors_are_current() -> None:
    assert load_vectors() == build_vectors()


def test_vectors_cover_every_type_and_a_payload_with_zero_bytes() -> None:
    vectors = load_vectors()
    assert {v["type_id"] for v in vectors["frames"]} == set(MESSAGE_TYPES)
    assert any(0 in bytes.fromhex(v["body_hex"])[3:-2] for v in vectors["frames"])


@pytest.mark.parametrize("vector", load_vectors()["frames"], ids=lambda v: v["name"])
def test_frame_vector(vector) -> None:
    cls = MESSAGE_BY_NAME[vector["type"]]
    msg = cls.from_raw(tuple(vector["raw"].values()))
    assert codec.encode(msg, vector["seq"]).hex() == vector["frame_hex"]
    assert cls(**vector["fields"]).raw() == tuple(vector["raw"].values())
    (frame,) = codec.StreamDecoder().feed(bytes.fromhex(vector["frame_hex"]))
    assert frame.seq == vector["seq"]
    assert frame.msg.raw() == tuple(vector["raw"].values())


@pytest.mark.parametrize("vector", load_vectors()["streams"], ids=lambda v: v["name"])
def test_stream_vector_fed_byte_by_byte(vector) -> None:
    dec = codec.StreamDecoder()
    stream = bytes.fromhex(vector["stream_hex"])
    frames = [f for i in range(len(stream)) for f in dec.feed(stream[i:i + 1])]
    assert [(f.msg.TYPE, f.seq, f.version, list(f.msg.raw())) for f in frames] == [
        (e["type_id"], e["seq"], e["version"], e["raw"]) for e in vector["frames"]]
    assert dec.drops == vector["drops"]


def test_decoder_counts_each_drop_reason() -> None:
    dec = codec.StreamDecoder()
    good = codec.encode(Heartbeat(), 1)
    body = bytearray(codec.encode_body(Heartbeat(), 1))
    body[-1] ^= 0xFF
    dec.feed(cobs.encode(bytes(body)) + b"\x00")
    dec.feed(b"\x05\x01\x00")  # COBS code pointing past the end
    assert dec.feed(good) and dec.drops["crc"] == 1 and dec.drops["framing"] == 1
    assert dec.frames_ok == 1 and dec.dropped == 2


def test_other_version_is_dropped_except_identity() -> None:
    dec = codec.StreamDecoder()
    assert dec.feed(codec.encode(State(1, 0, 0, 0, 0, 0, 0, 0), 5, version=3)) == []
    assert dec.drops["version"] == 1
    (f,) = dec.feed(codec.encode(Identity(3, 0, 0, 0, 0, 0), 6, version=3))
    assert f.version == 3 and f.msg.version == 3


def test_setpoint_layouts_per_version() -> None:
    """Version 2 adds the validity (state_time_us u32, max_age_ms u16) after host_time_us; version 1 keeps its
    20-byte SETPOINT, decoded only by a version-1 decoder, and neither layout can be sent under the other's version."""
    v2 = Setpoint(0.25, -0.125, 0.5, -0.0625, 123456, 1_000_000, 200)
    body = codec.encode_body(v2, 5)
    assert len(body) - 5 == 26
    assert body[23:27] == (1_000_000).to_bytes(4, "little") and body[27:29] == (200).to_bytes(2, "little")
    v1 = SetpointV1(0.25, -0.125, 0.5, -0.0625, 123456)
    frame_v1 = codec.encode(v1, 5, version=1)
    assert len(codec.encode_body(v1, 5, version=1)) - 5 == 20
    (f,) = codec.StreamDecoder(version=1).feed(frame_v1)
    assert f.version == 1 and f.msg == v1
    dec = codec.StreamDecoder()
    assert dec.feed(frame_v1) == [] and dec.drops["version"] == 1
    with pytest.raises(ValueError, match="SETPOINT layout of protocol version 2"):
        codec.encode(v1, 0)
    with pytest.raises(ValueError, match="SETPOINT layout of protocol version 1"):
        codec.encode(v2, 0, version=1)


@pytest.mark.parametrize("case", load_vectors()["setpoint_validity"], ids=lambda c: c["name"])
def test_setpoint_validity_vector(case) -> None:
    sp = Setpoint(0.0, 0.0, 0.0, 0.0, 0, case["state_time_us"], case["max_age_ms"])
    assert setpoint_age_us(case["device_time_us"], case["state_time_us"]) == case["age_us"]
    assert setpoint_is_fresh(sp, case["device_time_us"]) is case["fresh"]
