"""Shared fixtures for the protocol / link tests: run tools/mock_gimbal as a real subprocess."""

from __future__ import annotations

import csv
import os
import select
import signal
import subprocess
import sys
from pathlib import Path

from support import REPO

from pivotd.firmware_proto.messages import Config
from pivotd.gimbal.link import LinkConfig

MOCK_GIMBAL = REPO / "tools" / "mock_gimbal"


def link_config(**overrides: object) -> LinkConfig:
    """A typical CONFIG (±3 rad pan, [-1, 1] rad tilt, 2 rad/s, 10 rad/s², 250 ms watchdog) and default link
    timing; ``overrides`` may name CONFIG fields and LinkConfig timing fields alike."""
    limits = dict(pan_min=-3.0, pan_max=3.0, tilt_min=-1.0, tilt_max=1.0, vmax_pan=2.0, vmax_tilt=2.0,
                  amax_pan=10.0, amax_tilt=10.0, watchdog_ms=250)
    timing = {k: v for k, v in overrides.items() if k not in limits}
    limits.update({k: v for k, v in overrides.items() if k in limits})
    return LinkConfig(Config(**limits), **timing)  # type: ignore[arg-type]


class MockGimbal:
    """``tools/mock_gimbal ARGS`` as a subprocess; ``first_line`` is its announced endpoint."""

    def __init__(self, *args: str, tcp: bool = False) -> None:
        cmd = [sys.executable, str(MOCK_GIMBAL), *args]
        if tcp:
            cmd += ["--tcp", "127.0.0.1:0"]
        env = dict(os.environ, PYTHONPATH=str(REPO))
        self.proc = subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
        self.first_line = self.readline(timeout=10.0)
        if not self.first_line:
            self.kill()
            raise RuntimeError(f"mock_gimbal did not announce its port: {self.proc.stderr.read()}")
        self.url = f"socket://127.0.0.1:{int(self.first_line)}" if tcp else self.first_line

    def readline(self, timeout: float) -> str:
        """Next stdout line ('' on timeout or EOF)."""
        ready, _, _ = select.select([self.proc.stdout], [], [], timeout)
        return self.proc.stdout.readline().strip() if ready else ""

    def terminate(self, sig: int = signal.SIGTERM) -> int:
        """Send ``sig`` and return the exit code."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig)
        try:
            return self.proc.wait(timeout=10)
        finally:
            self.kill()

    def kill(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        for stream in (self.proc.stdout, self.proc.stderr):
            if stream:
                stream.close()

    def __enter__(self) -> MockGimbal:
        return self

    def __exit__(self, *exc: object) -> None:
        self.kill()


def read_log(path: Path) -> list[dict[str, str]]:
    """Rows of a mock gimbal CSV message log."""
    with open(path, newline="") as f:
        return list(csv.DictReader(f))
