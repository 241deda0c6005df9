"""The MCAP recorder: writes never block or raise on the callers' threads; a failing file stops the recording,
counted and described (pivotd/daemon/recorder.py)."""

from __future__ import annotations

import os
import threading
from pathlib import Path

import pytest
from mcap.reader import make_reader
from support import wait_until

from pivotd.bus.messages import JOINT_STATE, encode_joint_state
from pivotd.daemon.recorder import JOINT_COMMAND_TOPIC, Recorder, RecordingState
from pivotd.errors import InputError

DEV_FULL = Path("/dev/full")


def joint(k: int) -> bytes:
    return encode_joint_state(k * 0.01, ["pan", "tilt"], [0.001 * k, 0.0], [0.1, 0.0])


def test_a_recording_to_a_full_disk_stops_counted_and_described_and_writes_never_raise():
    if not DEV_FULL.exists():
        pytest.skip("no /dev/full")
    rec = Recorder(DEV_FULL)
    for k in range(5000):  # well beyond one 128 KiB chunk
        rec.write(JOINT_COMMAND_TOPIC, JOINT_STATE, joint(k))
    assert wait_until(lambda: rec.state is RecordingState.FAILED, 30), rec.status()
    for k in range(100):  # after the failure: dropped, counted, no exception
        rec.write(JOINT_COMMAND_TOPIC, JOINT_STATE, joint(k))
    rec.close()
    st = rec.status()
    assert st["state"] == "failed" and st["errors"] == 1 and st["path"] == "/dev/full"
    assert st["error"] == "No space left on device (errno 28)"
    assert st["messages"] + st["dropped"] == 5100 and st["dropped"] >= 100


def test_a_fifo_nobody_reads_is_refused_with_one_line_instead_of_blocking(tmp_path):
    fifo = tmp_path / "rec.fifo"
    os.mkfifo(fifo)
    with pytest.raises(InputError, match=r"^--record .*rec\.fifo: cannot write \(a FIFO nobody reads\)$"):
        Recorder(fifo)


def test_a_recording_to_a_pipe_is_a_valid_mcap_and_counts_its_bytes(tmp_path):
    """A FIFO cannot seek or tell; the recorder keeps the position itself, so a pipe records like a file."""
    fifo = tmp_path / "rec.fifo"
    os.mkfifo(fifo)
    fd = os.open(fifo, os.O_RDONLY | os.O_NONBLOCK)
    got = bytearray()

    def drain() -> None:
        os.set_blocking(fd, True)
        while chunk := os.read(fd, 1 << 16):
            got.extend(chunk)

    rec = Recorder(fifo)
    reader = threading.Thread(target=drain)
    reader.start()
    for k in range(3000):
        rec.write(JOINT_COMMAND_TOPIC, JOINT_STATE, joint(k), log_time_ns=1_000_000_000 + k)
    rec.close()
    reader.join(10)
    os.close(fd)
    st = rec.status()
    assert st["state"] == "closed" and st["errors"] == 0 and st["messages"] == 3000 and st["bytes"] == len(got)
    out = tmp_path / "copy.mcap"
    out.write_bytes(bytes(got))
    with open(out, "rb") as fh:
        assert sum(1 for _ in make_reader(fh).iter_messages()) == 3000
