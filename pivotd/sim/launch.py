"""Starting pivotd and its simulators as subprocesses: derived configs, free loopback ports, process groups.

Shared by the demo, the control benchmark and the end-to-end tests.
"""

from __future__ import annotations

import contextlib
import os
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def derive_config(base: Path, out: Path, changes: dict[str, object]) -> Path:
    """Write a copy of config ``base`` to ``out`` with dotted-key ``changes`` (``"gimbal.port": "mock://"``).

    Relative paths of the base config (``map.file``, ``map.filters.occupancy_file``, ``zenoh.config_file``,
    ``sim.route``) are made absolute so the copy can live anywhere.
    """
    import yaml

    doc = yaml.safe_load(Path(base).read_text())
    for dotted in ("map.file", "map.filters.occupancy_file", "zenoh.config_file", "sim.route"):
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.get(k) or {}
        value = node.get(keys[-1]) if isinstance(node, dict) else None
        if value:
            node[keys[-1]] = str((Path(base).parent / value).resolve())
    for dotted, value in changes.items():
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.setdefault(k, {})
        node[keys[-1]] = value
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spawn(args: list[str], log_path: Path, repo: Path | None = None) -> subprocess.Popen:
    """Start ``args`` in its own session (process group) from the repository root, output to ``log_path``.
    ``repo``: another checkout to run from (its packages first on the path; default: this one)."""
    root = REPO if repo is None else Path(repo)
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join([str(root), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.pop("NOTIFY_SOCKET", None)
    fh = open(log_path, "w")  # noqa: SIM115 - owned by the child for its lifetime
    return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                            cwd=str(root), start_new_session=True)


def stop_processes(procs, timeout: float = 15.0) -> None:
    """SIGTERM each process of ``procs`` still running (None entries skipped), in order; a process that has not
    exited within ``timeout`` [s] is killed with its process group."""
    for proc in procs:
        if proc is None or proc.poll() is not None:
            continue
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            with contextlib.suppress(ProcessLookupError):
                os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()


#: backends ``tools/mock_gimbal`` simulates (``gimbal.backend`` values)
SIMULATED_BACKENDS = ("pivot", "mavlink", "dynamixel")


def free_udp_port() -> int:
    """A UDP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket(socket.AF_INET, socket.SOCK_DGRAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_gimbal_simulator(backend: str, device_log: Path, log_path: Path) -> tuple[subprocess.Popen | None, str]:
    """A simulated gimbal for ``backend`` writing its CSV message log to ``device_log``; returns the simulator
    process (None for ``pivot``: the daemon runs the device model in process, ``mock://``) and the ``gimbal.port``
    that reaches it."""
    if backend == "pivot":
        return None, f"mock://?log={device_log}"
    if backend == "mavlink":
        port = free_udp_port()
        proc = spawn([sys.executable, str(REPO / "tools" / "mock_gimbal"), "--protocol", "mavlink", "--udp",
                      f"127.0.0.1:{port}", "--log", str(device_log)], log_path)
        return proc, f"udpout:127.0.0.1:{port}"
    if backend == "dynamixel":
        link = device_log.with_name(device_log.stem + "_servos")
        proc = spawn([sys.executable, str(REPO / "tools" / "mock_gimbal"), "--protocol", "dynamixel", "--link",
                      str(link), "--log", str(device_log)], log_path)
        deadline = time.monotonic() + 15.0
        while not link.exists():  # the pty appears once the simulator runs
            if proc.poll() is not None or time.monotonic() > deadline:
                raise RuntimeError(f"the servo simulator did not start; see {log_path}")
            time.sleep(0.05)
        return proc, str(link)
    raise ValueError(f"no simulator for gimbal backend {backend!r}; expected one of {', '.join(SIMULATED_BACKENDS)}")
