"""End to end: a recording (``--record``) whose file fails mid-run stops, says so in the status, and the daemon keeps
tracking and parks on SIGTERM (docs/RELIABILITY.md, process faults).

Two real failing files, no mocking: a FIFO that the soak stack reads (pivotd.bench.soak.FifoSink), whose reading end
is closed while the daemon tracks (its next write fails with EPIPE), and /dev/full, where the first chunk written
fails with ENOSPC as on a full disk.
"""

from __future__ import annotations

from pathlib import Path

import pytest
from support import wait_until

from pivotd.bench.soak import SoakStack, count_tracebacks

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]


def device_rows(stack: SoakStack, kind: str, direction: str = "rx") -> list[list[str]]:
    rows = []
    with open(stack.out / "gimbal.csv") as fh:
        for line in fh:
            cells = line.rstrip("\n").split(",")
            if len(cells) > 3 and cells[1] == direction and cells[2] == kind:
                rows.append(cells)
    return rows


DEV_FULL = Path("/dev/full")


@pytest.mark.parametrize("where", ["fifo_reader_closes", "dev_full"])
def test_a_recording_that_fails_mid_run_stops_the_daemon_keeps_tracking_and_parks(tmp_path, where):
    if where == "dev_full" and not DEV_FULL.exists():
        pytest.skip("no /dev/full")
    # on /dev/full without the map attached (record.map_max_bytes 0), the header fits the file's buffer: the first
    # chunk of messages is what fails, mid-run
    changes = {"record.map_max_bytes": 0} if where == "dev_full" else None
    with SoakStack(tmp_path, seed=5, record=True if where == "fifo_reader_closes" else DEV_FULL,
                   changes=changes) as stack:
        recording = lambda: stack.status.get("recording") or {}  # noqa: E731
        if where == "fifo_reader_closes":
            assert stack.wait_healthy(90.0) is not None, stack.daemon_logs()
            # the recording flows: the reader got a chunk of it
            assert wait_until(lambda: stack.recording.bytes > 10_000, 60), stack.status
            assert recording()["state"] == "active", stack.status
            event = stack.inject("recorder_failure")
            assert event["recording_failed"], stack.status
            error, path = "Broken pipe", ".fifo"
        else:  # the first chunk (128 KiB of messages, a few seconds of the run) fails
            assert stack.wait(lambda st: (st.get("recording") or {}).get("state") == "failed", 90.0) is not None, \
                stack.status
            error, path = "No space left on device", "/dev/full"
        rec = recording()
        assert rec["state"] == "failed" and rec["errors"] == 1, rec
        assert error in rec["error"] and rec["path"].endswith(path), rec
        assert rec["messages"] > 100, rec
        # The control loop goes on: setpoints keep reaching the device, the daemon tracks, the recording stays failed.
        sent = len(device_rows(stack, "SETPOINT"))
        assert wait_until(lambda: len(device_rows(stack, "SETPOINT")) >= sent + 300, 60)
        assert stack.wait_healthy(60.0) is not None, stack.status
        later = recording()
        assert later["state"] == "failed" and later["errors"] == 1 and later["dropped"] > rec["dropped"], later
        assert stack.status["threads_dead"] == []
        assert stack.status["last_error"] is None or stack.status["last_error"]["source"] != "control"
        # SIGTERM parks and disables: exit 0.
        assert stack.stop_daemon() == 0
    assert device_rows(stack, "ENABLE")[-1][-1] == "on=0", "no DISABLE reached the device"
    log_text = "\n".join(p.read_text() for p in stack.daemon_logs())
    assert log_text.count("stopped after") == 1, log_text[-3000:]  # the failure is logged once
    for path in stack.daemon_logs():
        n, lines = count_tracebacks(path)
        assert n == 0, lines
