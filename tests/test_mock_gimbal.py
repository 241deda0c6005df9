"""tools/mock_gimbal as a real subprocess: endpoints, signals, CSV log, fault injection (raw protocol)."""

import os
import select
import signal
import socket
import subprocess
import sys
import time
import tty

import pytest
import serial
from proto_support import MOCK_GIMBAL, REPO, MockGimbal, read_log

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    FAULT_ENCODER,
    MODE_FAULT,
    Ack,
    Config,
    Enable,
    Hello,
    Identity,
    Setpoint,
    State,
)

pytestmark = pytest.mark.slow  # subprocesses / real time


def exchange(port, msgs, wait: float = 0.3, until=None) -> list:
    """Send ``msgs`` (list of (msg, seq)) and return the frames received within ``wait`` seconds, or (with
    ``until``, a predicate on the frames so far) as soon as ``until`` holds, waiting at most ``wait``."""
    for msg, seq in msgs:
        port.write(codec.encode(msg, seq))
    dec = codec.StreamDecoder()
    frames = []
    deadline = time.monotonic() + wait
    while time.monotonic() < deadline and not (until is not None and until(frames)):
        frames += dec.feed(port.read(256))
    return frames


def _acked_and_ten_states_after_setpoint(frames: list) -> bool:
    """Both ACKs in, and ten STATEs of which the newest echoes setpoint 4 (a loaded machine may be slow)."""
    states = [f.msg for f in frames if isinstance(f.msg, State)]
    return (sum(isinstance(f.msg, Ack) for f in frames) >= 2 and len(states) >= 10
            and states[-1].last_setpoint_seq == 4)


def test_pty_announces_path_and_speaks_the_protocol(tmp_path) -> None:
    log_file = tmp_path / "log.csv"
    with MockGimbal("--log", str(log_file), "--state-hz", "100") as mock:
        assert mock.first_line.startswith("/dev/pts/")
        port = serial.serial_for_url(mock.url, timeout=0.05)
        try:
            frames = exchange(port, [(Hello(1), 1), (Config(-1, 1, -1, 1, 1, 1, 5, 5, 500), 2), (Enable(1), 3),
                                     (Setpoint(0.25, -0.5, 0.0, 0.0, 42, 0, 65535), 4)], wait=20.0,
                              until=_acked_and_ten_states_after_setpoint)
        finally:
            port.close()
        assert mock.terminate() == 0
    assert any(isinstance(f.msg, Identity) for f in frames)
    acks = [f.msg for f in frames if isinstance(f.msg, Ack)]
    assert [(a.acked_seq, a.acked_type, a.status) for a in acks] == [(2, 2, 0), (3, 3, 0)]
    states = [f.msg for f in frames if isinstance(f.msg, State)]
    assert len(states) >= 10 and states[-1].last_setpoint_seq == 4 and states[-1].mode == 1
    rows = read_log(log_file)
    sp = [r for r in rows if r["type"] == "SETPOINT" and r["dir"] == "rx"]
    assert len(sp) == 1 and float(sp[0]["pan"]) == 0.25 and float(sp[0]["tilt"]) == -0.5
    assert sp[0]["host_time_us"] == "42" and sp[0]["seq"] == "4"
    tx_states = [r for r in rows if r["type"] == "STATE" and r["dir"] == "tx"]
    assert len(tx_states) >= len(states)


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_clean_exit_on_signals(sig) -> None:
    with MockGimbal(tcp=True) as mock:
        time.sleep(0.2)
        assert mock.terminate(sig) == 0


def test_tcp_announces_port_serves_one_client_and_fault_at() -> None:
    # the fault comes 2 s after the start: this client is connected long before (even on a loaded machine)
    with MockGimbal("--fault-at", "2.0:2", tcp=True) as mock:
        port_no = int(mock.first_line)
        assert 0 < port_no < 65536
        port = serial.serial_for_url(mock.url, timeout=0.05)
        try:
            other = socket.create_connection(("127.0.0.1", port_no), timeout=2)
            other.settimeout(2)
            assert other.recv(10) == b""  # a second client is refused while the first is connected
            other.close()
            frames = exchange(port, [], wait=30.0, until=lambda fr: any(
                isinstance(f.msg, State) and f.msg.mode == MODE_FAULT for f in fr))
        finally:
            port.close()
    states = [f.msg for f in frames if isinstance(f.msg, State)]
    assert states[-1].mode == MODE_FAULT and states[-1].faults == FAULT_ENCODER
    assert states[0].faults == 0


def test_bad_arguments_exit_2_with_a_message() -> None:
    r = subprocess.run([sys.executable, str(MOCK_GIMBAL), "--fault-at", "soon"], capture_output=True, text=True,
                       env={"PYTHONPATH": str(REPO)}, timeout=30)
    assert r.returncode == 2 and "--fault-at expects SECONDS:BIT" in r.stderr
    r = subprocess.run([sys.executable, str(MOCK_GIMBAL), "--drop", "1.5"], capture_output=True, text=True,
                       env={"PYTHONPATH": str(REPO)}, timeout=30)
    assert r.returncode == 2 and "--drop must be a probability" in r.stderr


def test_stuck_axis_option_holds_the_axis_without_a_fault_bit() -> None:
    """--stuck-axis pan:0:5: pan does not follow the setpoints, no fault bit; a bad value exits 2 naming it."""
    with MockGimbal("--stuck-axis", "pan:0:5", tcp=True) as mock:
        port = serial.serial_for_url(mock.url, timeout=0.05)
        try:
            cfg = Config(-2.0, 2.0, -1.0, 1.0, 1.0, 1.0, 4.0, 4.0, 250)
            exchange(port, [(cfg, 1), (Enable(1), 2)], wait=2.0,
                     until=lambda fr: sum(isinstance(f.msg, Ack) for f in fr) >= 2)
            frames = []
            for k in range(30):
                frames += exchange(port, [(Setpoint(0.01 * k, 0.01 * k, 0.5, 0.5, 0, 0, 65535), 3 + k)], wait=0.02)
            frames += exchange(port, [], wait=2.0, until=lambda fr: sum(isinstance(f.msg, State) for f in fr) >= 5)
        finally:
            port.close()
    states = [f.msg for f in frames if isinstance(f.msg, State)]
    assert states and states[-1].tilt > 0.05 and states[-1].pan == 0.0 and states[-1].faults == 0
    r = subprocess.run([sys.executable, str(MOCK_GIMBAL), "--stuck-axis", "roll:0:1"], capture_output=True,
                       text=True, env={"PYTHONPATH": str(REPO)}, timeout=30)
    assert r.returncode == 2 and "--stuck-axis" in r.stderr


def test_drop_everything_means_silence() -> None:
    with MockGimbal("--drop", "1.0", "--seed", "3") as mock:
        port = serial.serial_for_url(mock.url, timeout=0.05)
        try:
            frames = exchange(port, [(Hello(1), 1)], wait=0.3)
        finally:
            port.close()
    assert frames == []


def test_serial_mode_on_a_pty_pair_with_latency() -> None:
    master, slave = os.openpty()
    tty.setraw(slave)
    try:
        with MockGimbal("--serial", os.ttyname(slave), "--latency-ms", "30") as mock:
            assert mock.first_line == os.ttyname(slave)
            os.write(master, codec.encode(Hello(1), 1))
            dec = codec.StreamDecoder()
            frames = []
            deadline = time.monotonic() + 20.0  # the loop ends at the first IDENTITY
            while time.monotonic() < deadline and not any(isinstance(f.msg, Identity) for f in frames):
                if select.select([master], [], [], 0.05)[0]:
                    frames += dec.feed(os.read(master, 4096))
            assert any(isinstance(f.msg, Identity) for f in frames)
            assert mock.terminate() == 0
    finally:
        os.close(master)
        os.close(slave)


def test_from_first_frame_counts_faults_and_disconnect_from_the_hosts_first_frame() -> None:
    with MockGimbal("--from-first-frame", "--fault-at", "0.0:2", "--disconnect-after", "0.6",
                    "--state-hz", "100", tcp=True) as mock:
        port = serial.serial_for_url(mock.url, timeout=0.05)
        try:
            # longer than both timers, and the host said nothing (at least 0.8 s and 20 states, however slow)
            t_silent = time.monotonic()
            silent = exchange(port, [], wait=30.0, until=lambda fr: time.monotonic() - t_silent >= 0.8
                              and sum(isinstance(f.msg, State) for f in fr) >= 20)
            spoken = exchange(port, [(Hello(1), 1)], wait=30.0, until=lambda fr: any(
                isinstance(f.msg, State) and f.msg.mode == MODE_FAULT for f in fr))
            with pytest.raises(serial.SerialException, match="disconnected"):
                exchange(port, [], wait=30.0)  # the disconnect is due 0.6 s after the Hello
        finally:
            port.close()
    quiet = [f.msg for f in silent if isinstance(f.msg, State)]
    assert len(quiet) >= 20 and all(s.faults == 0 for s in quiet)
    states = [f.msg for f in spoken if isinstance(f.msg, State)]
    assert states and states[-1].mode == MODE_FAULT and states[-1].faults == FAULT_ENCODER


@pytest.mark.parametrize("module", ["pivotd.firmware_proto.mock_server", "pivotd.sim.mavlink_server",
                                    "pivotd.sim.dynamixel_server"])
def test_every_simulator_takes_the_shared_fault_options(module):
    """The three device simulators declare their fault injection once (add_fault_arguments) and parse it alike."""
    import importlib

    from pivotd.firmware_proto.mock_server import parse_simulator_args

    build = importlib.import_module(module).build_parser
    args, injector = parse_simulator_args(build(), ["--drop", "0.1", "--latency-ms", "5", "--seed", "3",
                                                    "--fault-at", "1.5:2", "--disconnect-after", "2",
                                                    "--reconnect-after", "1", "--from-first-frame"])
    assert (injector.drop, injector.latency_s) == (0.1, 0.005)
    assert args.fault_at == [(1.5, 2)] and args.from_first_frame and args.reconnect_after == 1.0
    with pytest.raises(SystemExit):
        parse_simulator_args(build(), ["--drop", "1.5"])
    with pytest.raises(SystemExit):
        parse_simulator_args(build(), ["--reconnect-after", "1"])
