"""The C99 firmware codec: compiled with -Wall -Wextra -Werror -std=c99 and checked against every vector."""

import shutil
import subprocess
from pathlib import Path

import pytest

from pivotd.firmware_proto.vectors import c_header, load_vectors

C_DIR = Path(__file__).resolve().parent.parent / "pivotd" / "firmware_proto" / "c"
CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = [pytest.mark.slow, pytest.mark.skipif(CC is None, reason="no C compiler")]


def build_and_run(tmp_path: Path, vectors: dict) -> subprocess.CompletedProcess:
    (tmp_path / "pp_vectors.h").write_text(c_header(vectors))
    exe = tmp_path / "test_vectors"
    subprocess.run([CC, "-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic", "-O2", f"-I{C_DIR}", f"-I{tmp_path}",
                    "-o", str(exe), str(C_DIR / "test_vectors.c"), str(C_DIR / "pivot_proto.c")],
                   check=True, capture_output=True, text=True)
    return subprocess.run([str(exe)], capture_output=True, text=True, timeout=30)


def test_every_vector_passes_in_c(tmp_path: Path) -> None:
    vectors = load_vectors()
    result = build_and_run(tmp_path, vectors)
    assert result.returncode == 0, result.stdout
    n = len(vectors["frames"]) + len(vectors["streams"]) + len(vectors["setpoint_validity"])
    assert f"OK: {n} vectors checked, 0 failures" in result.stdout


def test_a_wrong_vector_is_caught(tmp_path: Path) -> None:
    vectors = load_vectors()
    frame = bytearray.fromhex(vectors["frames"][3]["frame_hex"])
    frame[5] ^= 0x10
    vectors["frames"][3]["frame_hex"] = frame.hex()
    vectors["streams"][0]["drops"]["crc"] = 7
    stale = next(c for c in vectors["setpoint_validity"] if not c["fresh"])
    stale["fresh"] = True
    result = build_and_run(tmp_path, vectors)
    assert result.returncode == 1
    assert f"FAIL {vectors['frames'][3]['name']}: encoded bytes differ" in result.stdout
    assert f"FAIL {vectors['streams'][0]['name']}: drop counter differs" in result.stdout
    assert f"FAIL {stale['name']}: setpoint validity differs" in result.stdout


def test_library_uses_no_heap_and_no_stdio() -> None:
    src = (C_DIR / "pivot_proto.c").read_text() + (C_DIR / "pivot_proto.h").read_text()
    for forbidden in ("malloc", "free(", "printf", "<stdio.h>", "<stdlib.h>"):
        assert forbidden not in src


def test_c_and_python_decoders_agree_on_random_and_mutated_streams(tmp_path: Path) -> None:
    import random

    from pivotd.firmware_proto import codec
    from pivotd.firmware_proto.messages import Ack, Heartbeat, Identity, Setpoint, State

    exe = tmp_path / "decode_lines"
    subprocess.run([CC, "-Wall", "-Wextra", "-Werror", "-std=c99", "-pedantic", "-O2", f"-I{C_DIR}", "-o", str(exe),
                    str(C_DIR / "decode_lines.c"), str(C_DIR / "pivot_proto.c")], check=True, capture_output=True)
    rng = random.Random(1234)
    msgs = [Setpoint(0.1, -0.2, 0.0, 0.5, 9, 1_000, 200), State(5, 1.0, 0.0, 0.0, 0.0, 3, 1, 0), Ack(1, 2, 0, 77),
            Heartbeat(), Identity(3, 1, 0, 0, 0, 0)]
    streams = []
    for _ in range(400):
        parts = [codec.encode(rng.choice(msgs), rng.randrange(256)) for _ in range(rng.randrange(1, 6))]
        data = bytearray(b"".join(parts))
        kind = rng.randrange(3)
        if kind == 0:  # random byte substitutions
            for _ in range(rng.randrange(1, 4)):
                data[rng.randrange(len(data))] = rng.randrange(256)
        elif kind == 1:  # garbage in front, possibly long
            data[:0] = bytes(rng.randrange(256) for _ in range(rng.randrange(0, 150)))
        else:  # pure noise
            data = bytearray(rng.randrange(256) for _ in range(rng.randrange(1, 300)))
        streams.append(bytes(data))
    out = subprocess.run([str(exe)], input="\n".join(s.hex() for s in streams) + "\n", capture_output=True,
                         text=True, timeout=60, check=True).stdout.splitlines()
    expected = []
    for s in streams:
        dec = codec.StreamDecoder()
        for f in dec.feed(s):
            expected.append(f"F {f.msg.TYPE} {f.seq} {f.version} {f.msg.pack().hex()}")
        expected.append("D " + " ".join(str(dec.drops[k]) for k in codec.DROP_REASONS))
    assert out == expected
    assert sum(line.startswith("F") for line in out) > 300  # the comparison covered many real frames
