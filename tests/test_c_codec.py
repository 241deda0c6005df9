"""The C99 firmware codec: compiled with -Wall -Wextra -Werror -std=c99 and checked against every vector."""

import shutil
import subprocess
from pathlib import Path

import pytest

from firmware_proto.vectors import c_header, load_vectors

C_DIR = Path(__file__).resolve().parent.parent / "firmware_proto" / "c"
CC = shutil.which("cc") or shutil.which("gcc")
pytestmark = pytest.mark.skipif(CC is None, reason="no C compiler")


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
    n = len(vectors["frames"]) + len(vectors["streams"])
    assert f"OK: {n} vectors checked, 0 failures" in result.stdout


def test_a_wrong_vector_is_caught(tmp_path: Path) -> None:
    vectors = load_vectors()
    frame = bytearray.fromhex(vectors["frames"][3]["frame_hex"])
    frame[5] ^= 0x10
    vectors["frames"][3]["frame_hex"] = frame.hex()
    vectors["streams"][0]["drops"]["crc"] = 7
    result = build_and_run(tmp_path, vectors)
    assert result.returncode == 1
    assert f"FAIL {vectors['frames'][3]['name']}: encoded bytes differ" in result.stdout
    assert f"FAIL {vectors['streams'][0]['name']}: drop counter differs" in result.stdout


def test_library_uses_no_heap_and_no_stdio() -> None:
    src = (C_DIR / "pivot_proto.c").read_text() + (C_DIR / "pivot_proto.h").read_text()
    for forbidden in ("malloc", "free(", "printf", "<stdio.h>", "<stdlib.h>"):
        assert forbidden not in src
