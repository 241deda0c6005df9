"""Property-based fuzzing of the stream decoder (hypothesis)."""

import binascii

import pytest
from cobs import cobs
from hypothesis import given, settings
from hypothesis import strategies as st

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import MAX_BODY, PROTOCOL_VERSION, Ack, Heartbeat, Setpoint, State

pytestmark = pytest.mark.slow  # seconds of CPU in all: `make test`, not `make test-fast`

i32 = st.integers(-(2**31), 2**31 - 1)
u8 = st.integers(0, 255)

messages = st.one_of(
    st.builds(lambda r, s, ref, age: Setpoint.from_raw((*r, s, ref, age)), st.tuples(i32, i32, i32, i32),
              st.integers(0, 2**32 - 1), st.integers(0, 2**32 - 1), st.integers(0, 2**16 - 1)),
    st.builds(lambda t, r, a, b, c: State.from_raw((t, *r, a, b, c)), st.integers(0, 2**32 - 1),
              st.tuples(i32, i32, i32, i32), u8, u8, st.integers(0, 0xFFFF)),
    st.builds(Ack, u8, u8, u8, st.integers(0, 2**32 - 1)),
    st.just(Heartbeat()),
)
frames = st.tuples(messages, u8).map(lambda ms: (codec.encode(ms[0], ms[1]), ms[0], ms[1]))


def reference_valid_segments(stream: bytes) -> list[bytes]:
    """Bodies of all 0x00-terminated segments that decode and carry a correct CRC (slow, obvious)."""
    out = []
    for seg in stream.split(b"\x00")[:-1]:
        try:
            body = cobs.decode(seg)
        except cobs.DecodeError:
            continue
        if 5 <= len(body) <= MAX_BODY and binascii.crc_hqx(body[:-2], 0xFFFF) == int.from_bytes(body[-2:], "little"):
            out.append(body)
    return out


def feed_in_chunks(stream: bytes, cuts: list[int]) -> tuple[list[codec.Frame], codec.StreamDecoder]:
    dec = codec.StreamDecoder()
    out: list[codec.Frame] = []
    pos = 0
    for cut in sorted(c % (len(stream) + 1) for c in cuts):
        out += dec.feed(stream[pos:cut])
        pos = max(pos, cut)
    out += dec.feed(stream[pos:])
    return out, dec


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=600), st.lists(st.integers(0, 10_000), max_size=8))
def test_random_bytes_never_raise_and_only_yield_crc_valid_frames(stream, cuts) -> None:
    got, dec = feed_in_chunks(stream, cuts)
    valid = reference_valid_segments(stream)
    for f in got:
        assert codec.encode_body(f.msg, f.seq, f.version) in valid
    assert dec.frames_ok == len(got)


@settings(max_examples=300, deadline=None)
@given(st.lists(frames, min_size=1, max_size=6), st.lists(st.tuples(st.integers(0, 10_000), u8), max_size=6),
       st.lists(st.integers(0, 10_000), max_size=6))
def test_mutated_streams_yield_only_frames_with_a_correct_crc(items, mutations, cuts) -> None:
    stream = bytearray(b"".join(f for f, _, _ in items))
    for pos, value in mutations:
        stream[pos % len(stream)] = value
    got, _ = feed_in_chunks(bytes(stream), cuts)
    valid = reference_valid_segments(bytes(stream))
    assert [codec.encode_body(f.msg, f.seq, f.version) for f in got] == [
        b for b in valid if b[0] == PROTOCOL_VERSION and b[1] in (0x04, 0x40, 0x42, 0x05)
        and len(b) - 5 == {0x04: 26, 0x40: 24, 0x42: 7, 0x05: 0}[b[1]]]


@settings(max_examples=300, deadline=None)
@given(st.binary(max_size=300), frames, frames, st.lists(st.integers(0, 10_000), max_size=8))
def test_valid_frame_after_garbage_is_recovered(garbage, first, second, cuts) -> None:
    # the first frame's delimiter ends the garbage; the second frame must always come through
    got, _ = feed_in_chunks(garbage + first[0] + second[0], cuts)
    assert got and got[-1].msg == second[1] and got[-1].seq == second[2]
    # with an explicit delimiter after the garbage, the first one comes through as well
    got, _ = feed_in_chunks(garbage + b"\x00" + first[0] + second[0], cuts)
    assert [(f.msg, f.seq) for f in got[-2:]] == [(first[1], first[2]), (second[1], second[2])]


@settings(max_examples=200, deadline=None)
@given(st.lists(frames, max_size=10), st.lists(st.integers(0, 10_000), max_size=10))
def test_chunking_does_not_change_the_result(items, cuts) -> None:
    stream = b"".join(f for f, _, _ in items)
    got, dec = feed_in_chunks(stream, cuts)
    assert [(f.msg, f.seq) for f in got] == [(m, s) for _, m, s in items]
    assert dec.dropped == 0
