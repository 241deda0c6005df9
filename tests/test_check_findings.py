"""`pivotd check` fails where `run` would fail or the gimbal stay unreachable, and warns on implausible values.

Each error is one `pivotd check: error: FILE:LINE: KEY: …` line and exit 2; warnings are `warning:` lines on stderr
with exit 0, or 1 with --strict; --offline skips the live probes (open the device, TCP connect, Zenoh router).
"""

from __future__ import annotations

import json
import os
import socket
import subprocess
import sys
from pathlib import Path

import pytest
from bus_support import open_router
from support import REPO, child_env, free_tcp_port, wait_until
from test_maps_colmap import write_text_model

from pivotd.cli import main

MAP = "map: {allow_empty: true}\n"


def check(capsys, config: Path, *options: str) -> tuple[int, str, list[str]]:
    """Exit code, stdout and the stderr lines of `pivotd check --config CONFIG OPTIONS`."""
    code = main(["check", "--config", str(config), *options])
    out, err = capsys.readouterr()
    return code, out, err.strip().splitlines()


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "c.yaml"
    path.write_text(text)
    return path


def only_error(code: int, out: str, err: list[str]) -> str:
    assert code == 2 and out == "", (code, out, err)
    assert len(err) == 1, err
    assert err[0].startswith("pivotd check: error: ")
    return err[0].removeprefix("pivotd check: error: ")


@pytest.fixture
def pty_path():
    """A serial device that exists and opens: the slave side of a pty."""
    master, slave = os.openpty()
    yield os.ttyname(slave)
    os.close(slave)
    os.close(master)


# ------------------------------------------------------------------------------------------ backend packages
@pytest.mark.slow
@pytest.mark.parametrize(("backend", "module", "port", "expected"), [
    ("dynamixel", "dynamixel_sdk", None, "gimbal.backend: dynamixel needs dynamixel-sdk: pip install "
     "'pivotd[dynamixel]'"),
    ("mavlink", "pymavlink", "udpin:127.0.0.1:14550", "gimbal.backend: mavlink needs pymavlink: pip install "
     "'pivotd[mavlink]'"),
])
def test_a_backend_without_its_package_fails(tmp_path, pty_path, backend, module, port, expected):
    """The package is made unimportable in the child (sys.modules[name] = None), as if the extra was not installed."""
    config = write(tmp_path, f"{MAP}gimbal:\n  backend: {backend}\n  port: {port or pty_path}\n")
    code = (f"import sys; sys.modules[{module!r}] = None\n"
            "from pivotd.cli import main\n"
            f"sys.exit(main(['check', '--offline', '--config', {str(config)!r}]))\n")
    hidden = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=child_env(),
                            cwd=tmp_path, timeout=120)
    assert hidden.returncode == 2, hidden.stderr
    assert hidden.stderr.strip().splitlines() == [f"pivotd check: error: {config}:3: {expected}"]
    assert hidden.stdout == ""
    present = subprocess.run([sys.executable, "-m", "pivotd.cli", "check", "--offline", "--config", str(config)],
                             capture_output=True, text=True, env=child_env(), cwd=tmp_path, timeout=120)
    assert present.returncode == 0, present.stderr  # with the package the same config passes


# ------------------------------------------------------------------------------------------ serial device
def test_a_missing_device_fails_and_offline_warns(capsys, tmp_path):
    port = tmp_path / "ttyUSB9"
    config = write(tmp_path, f"{MAP}gimbal:\n  port: {port}\n")
    assert only_error(*check(capsys, config)) == f"{config}:3: gimbal.port: {port}: no such device"
    # the unit's check before each start: the daemon waits for an adapter plugged in later, so it may start
    code, out, err = check(capsys, config, "--offline")
    assert code == 0 and "gimbal: port" in out
    assert any(f"{config}:3: gimbal.port: {port}: no such device now; the daemon waits" in line for line in err)
    assert check(capsys, config, "--offline", "--strict")[0] == 1


def test_a_dangling_symlink_and_a_directory_are_named(capsys, tmp_path):
    link = tmp_path / "usb-FTDI-if00-port0"
    link.symlink_to(tmp_path / "ttyUSB0")
    config = write(tmp_path, f"{MAP}gimbal:\n  port: {link}\n")
    assert "no such device (a dangling symlink: the adapter is unplugged?)" in only_error(*check(capsys, config))
    config = write(tmp_path, f"{MAP}gimbal:\n  backend: dynamixel\n  port: {tmp_path}\n")
    assert only_error(*check(capsys, config, "--offline")) == (
        f"{config}:4: gimbal.port: {tmp_path}: is a directory, not a serial device")


@pytest.mark.skipif(os.geteuid() == 0, reason="root may open any file")
def test_a_device_this_user_may_not_open_fails(capsys, tmp_path):
    device = tmp_path / "ttyUSB0"
    device.write_bytes(b"")
    device.chmod(0o000)
    config = write(tmp_path, f"{MAP}gimbal:\n  port: {device}\n")
    assert f"gimbal.port: {device}: permission denied for this user" in only_error(*check(capsys, config, "--offline"))


def test_a_device_that_exists_but_does_not_open_fails_live_only(capsys, tmp_path):
    """A Unix socket's path exists but open() gives ENXIO, as a stale device node does."""
    path = tmp_path / "ttyS"
    with socket.socket(socket.AF_UNIX) as sock:
        sock.bind(str(path))
        config = write(tmp_path, f"{MAP}gimbal:\n  port: {path}\n")
        error = only_error(*check(capsys, config))
        assert error == (f"{config}:3: gimbal.port: {path}: cannot be opened: No such device or address "
                         "(--offline skips this)")
        code, _, err = check(capsys, config, "--offline")
        assert code == 0 and err == []


def test_a_device_that_opens_passes_and_is_summarized(capsys, tmp_path, pty_path):
    config = write(tmp_path, f"{MAP}gimbal:\n  backend: dynamixel\n  port: {pty_path}\n  baud: 1000000\n"
                             "  dynamixel: {pan_id: 3, tilt_id: 4, pan_reversed: true}\n"
                             "  mount: {xyz: [0.1, 0, 0.3], rpy_deg: [0, 0, 90]}\n")
    code, out, err = check(capsys, config)
    assert code == 0 and err == []
    assert f"gimbal: port {pty_path} @ 1000000 baud" in out and "backend dynamixel" in out
    assert "servos: pan id 3 reversed, 0° at tick 2048; tilt id 4 as mounted, 0° at tick 2048; 1000000 baud" in out
    assert "mount: xyz [0.1, 0, 0.3] m, rpy [0, 0, 90]°" in out


def test_a_tcp_port_is_connected_to_live_only_and_mock_is_not_probed(capsys, tmp_path):
    port = free_tcp_port()
    config = write(tmp_path, f"{MAP}gimbal:\n  port: socket://127.0.0.1:{port}\n")
    error = only_error(*check(capsys, config))
    assert error.startswith(f"{config}:3: gimbal.port: socket://127.0.0.1:{port}: no connection to 127.0.0.1:{port}: ")
    assert check(capsys, config, "--offline")[0] == 0
    with socket.create_server(("127.0.0.1", port)):
        code, _, err = check(capsys, config)
        assert code == 0 and err == []
    mock = write(tmp_path, f"{MAP}gimbal:\n  port: mock://\n")
    assert check(capsys, mock)[:1] == (0,)


def test_port_option_replaces_the_configured_port(capsys, tmp_path, pty_path):
    config = write(tmp_path, f"{MAP}gimbal:\n  port: {tmp_path / 'ttyUSB9'}\n")
    assert check(capsys, config, "--port", pty_path)[0] == 0
    assert "gimbal.port: " in only_error(*check(capsys, config, "--port", str(tmp_path / "absent")))


# ------------------------------------------------------------------------------------------ zenoh router
def test_client_mode_without_a_router_endpoint_is_refused(capsys, tmp_path):
    config = write(tmp_path, f"{MAP}zenoh:\n  mode: client\n")
    assert "zenoh.connect: client mode needs a router endpoint" in only_error(*check(capsys, config, "--offline"))


@pytest.mark.slow
def test_client_mode_asks_the_router_unless_offline(capsys, tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    config = write(tmp_path, f"{MAP}zenoh:\n  mode: client\n  connect: [{endpoint}]\n")
    error = only_error(*check(capsys, config))
    assert error == (f"{config}:4: zenoh.connect: no Zenoh router answers at {endpoint} within 1 s (run would wait "
                     "for one, holding the gimbal; --offline skips this)")
    code, out, err = check(capsys, config, "--offline")
    assert code == 0 and err == [] and f"config: {config} OK" in out
    router = open_router(endpoint)
    try:
        code, _, err = check(capsys, config)
        assert code == 0 and err == []
    finally:
        router.close()


# ------------------------------------------------------------------------------------------ ProtectHome
@pytest.mark.parametrize("path", ["/home/someone/recordings", "/root/run.mcap", "/run/user/1000/pivotd"])
def test_files_the_unit_hides_warn_and_fail_under_systemd(capsys, tmp_path, monkeypatch, path):
    monkeypatch.delenv("INVOCATION_ID", raising=False)
    config = write(tmp_path, f"{MAP}record:\n  path: {path}\n")
    code, out, err = check(capsys, config)
    hidden = next(d for d in ("/home", "/root", "/run/user") if path.startswith(d))
    expected = (f"{config}:3: record.path: {path} is under {hidden}, which pivotd.service hides from the daemon "
                "(ProtectHome=yes): keep it under /etc/pivotd or /var/lib/pivotd")
    assert code == 0 and "OK" in out
    assert err == [f"warning: {expected}"]
    assert check(capsys, config, "--strict")[0] == 1
    # a shell in a terminal that runs as a user service has $INVOCATION_ID too, but not PID 1 as its parent (this
    # process's own parent may be PID 1 when the suite was started detached: the parent is set for the test)
    monkeypatch.setenv("INVOCATION_ID", "0123456789abcdef0123456789abcdef")
    monkeypatch.setattr(os, "getppid", lambda: 4242)
    assert check(capsys, config)[2] == [f"warning: {expected}"]


ORPHAN = """
import json, os, sys, time
parent = os.getpid()  # the grandchild waits until this process is gone
if os.fork():
    os._exit(0)
deadline = time.monotonic() + 30
while os.getppid() == parent and time.monotonic() < deadline:
    time.sleep(0.01)
result = sys.argv[1]
if os.getppid() != 1:  # a subreaper adopted it: no process here has PID 1 as its parent
    code, err = None, ""
else:
    import contextlib, io
    from pivotd.cli import main
    buf = io.StringIO()
    with contextlib.redirect_stderr(buf), contextlib.redirect_stdout(io.StringIO()):
        code = main(["check", "--offline", "--config", sys.argv[2]])
    err = buf.getvalue()
with open(result + ".tmp", "w") as fh:
    json.dump({"code": code, "stderr": err}, fh)
os.replace(result + ".tmp", result)
"""


@pytest.mark.slow
def test_files_the_unit_hides_fail_as_a_system_service(tmp_path):
    """As ExecStartPre: $INVOCATION_ID set and PID 1 the parent (an orphaned grandchild here, adopted by PID 1)."""
    config = write(tmp_path, f"{MAP}record:\n  path: /home/someone/recordings\n")
    result = tmp_path / "result.json"
    subprocess.run([sys.executable, "-c", ORPHAN, str(result), str(config)], check=True, timeout=60,
                   env=child_env(INVOCATION_ID="0123456789abcdef0123456789abcdef"))
    assert wait_until(result.exists, timeout=120)
    outcome = json.loads(result.read_text())
    if outcome["code"] is None:
        pytest.skip("orphans are adopted by a subreaper here, not by PID 1")
    assert outcome["code"] == 2
    assert outcome["stderr"].splitlines() == [
        f"pivotd check: error: {config}:3: record.path: /home/someone/recordings is under /home, which "
        "pivotd.service hides from the daemon (ProtectHome=yes): keep it under /etc/pivotd or /var/lib/pivotd"]


# ------------------------------------------------------------------------------------------ implausible values
@pytest.mark.parametrize(("text", "expected"), [
    ("pivot: {fov_deg: 1.05}", "2: pivot.fov_deg: 1.05° is a very narrow cone (< 5°): radians in a degree key?"),
    ("pivot:\n  fov_deg: 6\n  transition_width_deg: 8",
     "3: pivot.fov_deg: 6° is not wider than pivot.transition_width_deg (8°): the cone is all soft edge"),
    ("gimbal:\n  limits:\n    pan_min_deg: -2.9\n    pan_max_deg: 2.9",
     "5: gimbal.limits.pan_max_deg: the pan range [-2.9, 2.9]° spans only 5.8° (< 10°): radians in a degree key?"),
    ("gimbal:\n  limits: {tilt_min_deg: -0.5, tilt_max_deg: 1.5}\n  park: {tilt_deg: 0}",
     "3: gimbal.limits.tilt_max_deg: the tilt range [-0.5, 1.5]° spans only 2° (< 10°): radians in a degree key?"),
    ("motion:\n  tilt:\n    max_velocity_deg_s: 2.1",
     "4: motion.tilt.max_velocity_deg_s: 2.1°/s is implausibly slow (< 5°/s): radians in a degree key?"),
    ("motion:\n  pan:\n    max_acceleration_deg_s2: 6.28",
     "4: motion.pan.max_acceleration_deg_s2: 6.28°/s² is implausibly slow (< 10°/s²): radians in a degree key?"),
    ("gimbal:\n  mount:\n    rpy_deg: [0, 0.1, -0.2]",
     "4: gimbal.mount.rpy_deg: [0, 0.1, -0.2]: every angle is below 0.5° but not all are 0: radians in a degree key?"),
])
def test_implausible_values_warn_and_fail_only_when_strict(capsys, tmp_path, text, expected):
    config = write(tmp_path, f"{MAP}{text}\n")
    code, out, err = check(capsys, config)
    assert code == 0 and f"config: {config} OK" in out
    assert err == [f"warning: {config}:{expected}"]
    code, out, err = check(capsys, config, "--strict")
    assert code == 1 and len(err) == 1 and f"config: {config} OK" in out


@pytest.mark.parametrize("text", [
    "gimbal:\n  mount:\n    rpy_deg: [0, 0, 0]",
    "gimbal:\n  mount:\n    rpy_deg: [0.2, 0, 90]",  # a small roll next to a real yaw
    "gimbal:\n  limits: {continuous_pan: true, pan_min_deg: -1, pan_max_deg: 1}",  # the range of a continuous pan
    "pivot: {fov_deg: 8, transition_width_deg: 5}",
])
def test_plausible_values_do_not_warn(capsys, tmp_path, text):
    code, _, err = check(capsys, write(tmp_path, f"{MAP}{text}\n"), "--strict")
    assert (code, err) == (0, [])


# ------------------------------------------------------------------------------------------ view-angle filter
def test_a_view_angle_filter_without_observation_directions_warns(capsys, tmp_path):
    config = write(tmp_path, "map:\n  allow_empty: true\n  filters:\n    max_view_angle_deg: 75\n")
    code, out, err = check(capsys, config)
    assert code == 0 and "observation directions: no" in out
    assert err == [f"warning: {config}:4: map.filters.max_view_angle_deg: drops nothing: it needs the map's "
                   "observation directions and there is no map.file and landmarks on /pivot/landmarks carry none (a "
                   "COLMAP model with images.bin or images.txt beside points3D has them)"]
    (tmp_path / "plain.txt").write_text("0 0 0\n1 2 3\n")
    config = write(tmp_path, "map:\n  file: plain.txt\n  filters: {max_view_angle_deg: 75}\n")
    code, out, err = check(capsys, config)
    assert code == 0 and len(err) == 1
    assert f"map.filters.max_view_angle_deg: drops nothing: it needs the map's observation directions and " \
           f"{tmp_path / 'plain.txt'} has none" in err[0]


def test_a_view_angle_filter_on_a_colmap_model_with_images_is_fine(capsys, tmp_path):
    write_text_model(tmp_path / "model")
    config = write(tmp_path, "map:\n  file: model\n  filters: {max_view_angle_deg: 75}\n")
    code, out, err = check(capsys, config, "--strict")
    assert (code, err) == (0, [])
    assert "observation directions: yes" in out


def test_the_unit_checks_offline_before_it_runs():
    """ExecStartPre runs `check --offline` on the config ExecStart runs: a router late at boot costs no failed start."""
    lines = (REPO / "systemd" / "pivotd.service").read_text().splitlines()
    pre = [line.removeprefix("ExecStartPre=") for line in lines if line.startswith("ExecStartPre=")]
    start = next(line.removeprefix("ExecStart=") for line in lines if line.startswith("ExecStart="))
    program, _, config = start.partition(" run ")
    assert pre == [f"{program} check --offline {config}"]
