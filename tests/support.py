"""Helpers for end-to-end tests: free ports, managed subprocesses, polling."""

from __future__ import annotations

import contextlib
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Sequence
from pathlib import Path

from pivotd.sim.launch import free_port as free_tcp_port  # noqa: F401 - re-exported for the tests

REPO = Path(__file__).resolve().parent.parent
PYTHON = sys.executable


def wait_until(predicate: Callable[[], object], timeout: float, interval: float = 0.05) -> bool:
    """Poll ``predicate`` until it returns truthy or ``timeout`` seconds pass; returns its last truthiness."""
    deadline = time.monotonic() + timeout
    while True:
        if predicate():
            return True
        if time.monotonic() >= deadline:
            return False
        time.sleep(interval)


def child_env(**extra: str) -> dict[str, str]:
    """Environment for child processes: the repository on PYTHONPATH, unbuffered output."""
    env = dict(os.environ)
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env["PYTHONUNBUFFERED"] = "1"
    env.pop("NOTIFY_SOCKET", None)
    env.update(extra)
    return env


class ManagedProcess:
    """A child process in its own process group with stdout/stderr captured line by line.

    Always use as a context manager (or call :meth:`kill`): the whole group is killed on exit.
    """

    def __init__(self, args: Sequence[str], name: str, env: dict[str, str] | None = None,
                 cwd: Path | None = None) -> None:
        self.name = name
        self.args = list(args)
        self.proc = subprocess.Popen(
            self.args,
            stdout=subprocess.PIPE,
            stderr=subprocess.PIPE,
            stdin=subprocess.DEVNULL,
            env=env or child_env(),
            cwd=str(cwd or REPO),
            text=True,
            start_new_session=True,
        )
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self._threads = [
            threading.Thread(target=self._pump, args=(self.proc.stdout, self.stdout), daemon=True),
            threading.Thread(target=self._pump, args=(self.proc.stderr, self.stderr), daemon=True),
        ]
        for t in self._threads:
            t.start()

    @staticmethod
    def _pump(stream, sink: list[str]) -> None:
        for line in stream:
            sink.append(line.rstrip("\n"))

    def __enter__(self) -> ManagedProcess:
        return self

    def __exit__(self, *exc) -> None:
        self.kill()

    @property
    def returncode(self) -> int | None:
        return self.proc.poll()

    def wait_stdout(self, predicate: Callable[[str], bool], timeout: float) -> str | None:
        """First stdout line satisfying ``predicate`` within ``timeout`` seconds (None otherwise)."""
        found: list[str] = []

        def check() -> bool:
            for line in list(self.stdout):
                if predicate(line):
                    found.append(line)
                    return True
            return False

        wait_until(lambda: check() or self.proc.poll() is not None, timeout)
        return found[0] if found else None

    def wait_stderr(self, needle: str, timeout: float) -> bool:
        return wait_until(lambda: any(needle in line for line in list(self.stderr)), timeout)

    def send_signal(self, sig: int) -> None:
        if self.proc.poll() is None:
            os.kill(self.proc.pid, sig)

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 15.0) -> int | None:
        """Send ``sig`` and wait up to ``timeout`` s for the exit code (None if it did not exit)."""
        self.send_signal(sig)
        try:
            return self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            return None

    def kill(self) -> None:
        if self.proc.poll() is None:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, signal.SIGKILL)
            self.proc.wait(timeout=10)
        for t in self._threads:
            t.join(timeout=2)

    def output(self) -> str:
        """Captured output for assertion messages."""
        return "\n".join([f"--- {self.name} stdout", *self.stdout[-40:], f"--- {self.name} stderr",
                          *self.stderr[-60:]])
