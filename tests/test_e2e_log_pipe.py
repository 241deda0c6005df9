"""End to end: the daemon's log output goes to a pipe that stops being read. Logging must not block any thread: the
gimbal keeps getting setpoints, reloads go on, the status counts the dropped log records, SIGTERM parks, exit 0."""

from __future__ import annotations

import contextlib
import fcntl
import os
import select
import signal
import subprocess
import threading
import time

import pytest
from support import PYTHON, REPO, child_env, free_tcp_port, wait_until
from test_e2e_daemon import start_mock_gimbal, start_sim, write_config

from pivotd.bus.probe import BusProbe
from pivotd.config import load_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

F_SETPIPE_SZ = 1031  # fcntl.F_SETPIPE_SZ (Linux)


def device_rows(path, kind: str) -> list[list[str]]:
    with open(path) as fh:
        rows = (line.rstrip("\n").split(",") for line in fh)
        return [c for c in rows if len(c) > 3 and c[1] == "rx" and c[2] == kind]


class LogPipe:
    """A FIFO for the daemon's stdout and stderr, read by a thread until :meth:`stop_reading`; :meth:`fill` then
    fills it to capacity from a writer of its own (so the daemon's next log write would block)."""

    def __init__(self, path) -> None:
        os.mkfifo(path)
        self.path = path
        self._rfd = os.open(path, os.O_RDONLY | os.O_NONBLOCK)
        with contextlib.suppress(OSError):
            fcntl.fcntl(self._rfd, F_SETPIPE_SZ, 4096)  # a small pipe fills with a few log lines
        self.text = bytearray()
        self._reading = threading.Event()
        self._reading.set()
        self._thread = threading.Thread(target=self._read, daemon=True)
        self._thread.start()

    def _read(self) -> None:
        while self._reading.is_set():
            if select.select([self._rfd], [], [], 0.05)[0]:
                with contextlib.suppress(BlockingIOError):
                    data = os.read(self._rfd, 1 << 16)
                    if data:
                        self.text.extend(data)
                    else:
                        time.sleep(0.05)

    def stop_reading(self) -> None:
        self._reading.clear()
        self._thread.join(5)

    def fill(self) -> int:
        """Write into the pipe until it is full; returns the bytes written."""
        wfd = os.open(self.path, os.O_WRONLY | os.O_NONBLOCK)  # its own open file: the daemon's stays blocking
        n = 0
        try:
            for size in (4096, 1):
                while True:
                    try:
                        n += os.write(wfd, b"x" * size)
                    except BlockingIOError:
                        break
        finally:
            os.close(wfd)
        return n

    def close(self) -> None:
        self.stop_reading()
        os.close(self._rfd)


def test_a_log_pipe_nobody_reads_neither_stops_the_gimbal_nor_sigterm(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path)
    config = write_config(tmp_path, endpoint, url)
    cfg = load_config(config)
    pipe = LogPipe(tmp_path / "log.fifo")
    out = open(pipe.path, "wb")  # noqa: SIM115 - the daemon's stdout and stderr; closed below
    daemon = subprocess.Popen([PYTHON, "-m", "pivotd.cli", "--config", str(config), "--log-level", "DEBUG"],
                              stdout=out, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=child_env(),
                              cwd=str(REPO), start_new_session=True)
    out.close()
    probe = sim = None
    try:
        with mock:
            probe = BusProbe.connect(endpoint, cfg.topics)
            sim = start_sim(endpoint, "--speed", "1.0", "--loop")
            assert wait_until(lambda: probe.status.get("state") == "tracking", 60), pipe.text[-3000:]
            pipe.stop_reading()
            assert pipe.fill() > 0
            filled = time.time()
            # Work that logs, on the planner thread (a reload) and the main thread (the signal), into the full pipe.
            for _ in range(3):
                daemon.send_signal(signal.SIGHUP)
            sent = len(device_rows(dev_log, "SETPOINT"))
            assert wait_until(lambda: len(device_rows(dev_log, "SETPOINT")) >= sent + 300, 60), probe.status
            fresh = lambda: probe.status.get("time", 0) > filled  # noqa: E731
            # the reloads went on; their log records wait in the queue (a full queue drops them, counted)
            assert wait_until(lambda: fresh() and probe.status.get("reloads", 0) >= 1
                              and (probe.status.get("logging") or {}).get("queued", 0) > 0, 60), probe.status
            assert wait_until(lambda: fresh() and probe.status.get("state") == "tracking", 60), probe.status
            assert daemon.poll() is None
            daemon.send_signal(signal.SIGTERM)
            try:
                code = daemon.wait(timeout=30)
            except subprocess.TimeoutExpired:
                code = None
            assert code == 0
            assert device_rows(dev_log, "ENABLE")[-1][-1] == "on=0", "not disabled after parking"
    finally:
        if probe is not None:
            probe.close()
        if sim is not None:
            sim.kill()
        if daemon.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(daemon.pid, signal.SIGKILL)
            daemon.wait(10)
        pipe.close()
