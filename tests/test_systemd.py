"""sd_notify over real unix datagram sockets (path and abstract namespace), watchdog interval parsing."""

import os
import shutil
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path

import pytest

from pivotd.daemon.systemd import Notifier, watchdog_interval

REPO = Path(__file__).resolve().parent.parent


@pytest.fixture
def path_socket():
    """A bound datagram socket at a short filesystem path (AF_UNIX paths are limited to 108 bytes)."""
    directory = tempfile.mkdtemp(prefix="pvn", dir="/tmp")
    path = os.path.join(directory, "notify")
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(path)
    sock.settimeout(5.0)
    try:
        yield path, sock
    finally:
        sock.close()
        shutil.rmtree(directory, ignore_errors=True)


@pytest.fixture
def abstract_socket():
    name = f"pivotd-test-{uuid.uuid4().hex}"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(b"\0" + name.encode())
    sock.settimeout(5.0)
    try:
        yield "@" + name, sock
    finally:
        sock.close()


def receive(sock: socket.socket) -> str:
    return sock.recv(4096).decode()


def test_messages_arrive_on_a_path_socket(path_socket, monkeypatch):
    path, sock = path_socket
    monkeypatch.setenv("NOTIFY_SOCKET", path)
    with Notifier() as notifier:
        assert notifier.enabled
        assert notifier.ready(status="map loaded,\n 3150 landmarks")
        assert receive(sock) == "READY=1\nSTATUS=map loaded, 3150 landmarks"
        assert notifier.watchdog()
        assert receive(sock) == "WATCHDOG=1"
        assert notifier.status("tracking")
        assert receive(sock) == "STATUS=tracking"
        assert notifier.stopping()
        assert receive(sock) == "STOPPING=1"


def test_reloading_carries_monotonic_usec(abstract_socket, monkeypatch):
    name, sock = abstract_socket
    monkeypatch.setenv("NOTIFY_SOCKET", name)
    notifier = Notifier()
    before = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    assert notifier.reloading()
    after = time.clock_gettime_ns(time.CLOCK_MONOTONIC) // 1000
    lines = receive(sock).split("\n")
    assert lines[0] == "RELOADING=1"
    key, value = lines[1].split("=")
    assert key == "MONOTONIC_USEC"
    assert before <= int(value) <= after
    notifier.close()


def test_explicit_address_overrides_environment(abstract_socket, monkeypatch):
    name, sock = abstract_socket
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    assert Notifier(address=name).ready()
    assert receive(sock) == "READY=1"


def test_no_op_without_notify_socket(monkeypatch):
    monkeypatch.delenv("NOTIFY_SOCKET", raising=False)
    notifier = Notifier()
    assert not notifier.enabled
    assert notifier.ready() is False
    assert notifier.watchdog() is False
    assert notifier.reloading() is False
    assert notifier.stopping() is False


def test_dead_socket_is_reported_not_raised(monkeypatch):
    monkeypatch.setenv("NOTIFY_SOCKET", "/tmp/pivotd-no-such-socket-" + uuid.uuid4().hex)
    notifier = Notifier()
    assert notifier.enabled
    assert notifier.ready() is False
    assert notifier.watchdog() is False


@pytest.mark.slow
def test_child_process_notifies_through_inherited_environment(abstract_socket):
    name, sock = abstract_socket
    env = dict(os.environ, NOTIFY_SOCKET=name, PYTHONPATH=str(REPO))
    code = "from pivotd.daemon.systemd import Notifier; n = Notifier(); n.ready(); n.watchdog(); n.stopping()"
    proc = subprocess.run([sys.executable, "-c", code], env=env, timeout=60, capture_output=True, text=True)
    assert proc.returncode == 0, proc.stderr
    assert [receive(sock) for _ in range(3)] == ["READY=1", "WATCHDOG=1", "STOPPING=1"]


@pytest.mark.parametrize(
    ("usec", "pid", "expected"),
    [
        ("2000000", None, 2.0),
        ("500000", "self", 0.5),
        ("500000", "1", None),  # the watchdog belongs to another process
        ("", None, None),
        ("abc", None, None),
        ("0", None, None),
        ("1000000", "xyz", None),
    ],
)
def test_watchdog_interval(monkeypatch, usec, pid, expected):
    monkeypatch.setenv("WATCHDOG_USEC", usec)
    if pid is None:
        monkeypatch.delenv("WATCHDOG_PID", raising=False)
    else:
        monkeypatch.setenv("WATCHDOG_PID", str(os.getpid()) if pid == "self" else pid)
    assert watchdog_interval() == expected


def test_no_watchdog_without_environment(monkeypatch):
    monkeypatch.delenv("WATCHDOG_USEC", raising=False)
    monkeypatch.delenv("WATCHDOG_PID", raising=False)
    assert watchdog_interval() is None
