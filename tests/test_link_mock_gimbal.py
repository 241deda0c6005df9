"""GimbalLink against tools/mock_gimbal as a real subprocess over a pty and over TCP."""

import signal
import time

import pytest
from proto_support import MockGimbal, link_config, read_log

from firmware_proto import codec
from firmware_proto.messages import FAULT_OVERCURRENT, FAULT_WATCHDOG, MODE_DISABLED, MODE_ENABLED, MODE_FAULT, Hello
from pivotd.gimbal.link import GimbalLink

pytestmark = pytest.mark.slow  # subprocesses / real time


def track(link: GimbalLink, pan: float, tilt: float, timeout: float = 20.0):
    """Stream one setpoint per received STATE until the gimbal is at (pan, tilt); return the final state."""
    seen: list = []
    link.subscribe(lambda st: seen.append(st) if len(seen) < 10_000 else None)

    def arrived(st) -> bool:
        link.send_setpoint(pan, tilt)
        return abs(st.pan - pan) < 1e-4 and abs(st.tilt - tilt) < 1e-4 and st.mode == MODE_ENABLED

    return link.wait_state(arrived, timeout)


@pytest.mark.parametrize("tcp", [False, True], ids=["pty", "tcp"])
def test_handshake_tracking_echo_and_disable_on_stop(tmp_path, tcp) -> None:
    log_file = tmp_path / "log.csv"
    with MockGimbal("--log", str(log_file), tcp=tcp) as mock:
        link = GimbalLink(mock.url, link_config())
        try:
            link.start()
            assert link.wait_up(10.0), link.last_error
            assert link.identity.version == 1
            seq = link.send_setpoint(0.3, -0.2)
            assert seq is not None
            echoed = link.wait_state(lambda st: st.last_setpoint_seq == seq, 20.0)
            assert echoed is not None and echoed.rx_time > 0
            final = track(link, 0.3, -0.2)
            assert final is not None and final.faults == 0
            c = link.counters()
            assert c["rtt_samples"] >= 1 and 0 < c["rtt_mean_s"] < 1.0
            assert c["frames_received"] > 0 and c["frames_sent"] > 1 and c["crc_errors"] == 0
        finally:
            link.stop()
        assert link.link_state == "stopped"
        assert mock.terminate() == 0
    rows = read_log(log_file)
    rx = [r["type"] for r in rows if r["dir"] == "rx"]
    assert rx[:3] == ["HELLO", "CONFIG", "ENABLE"]
    assert rows[[i for i, r in enumerate(rows) if r["dir"] == "rx"][-1]]["detail"] == "on=0"  # disabled on stop
    cfg = next(r for r in rows if r["type"] == "CONFIG")
    assert "pan_min=-3000000" in cfg["detail"] and "watchdog_ms=250" in cfg["detail"]


@pytest.mark.parametrize("tcp", [False, True], ids=["pty", "tcp"])
def test_unplug_and_replug_recovers_by_itself(tmp_path, tcp) -> None:
    log_file = tmp_path / "log.csv"
    args = ["--disconnect-after", "1.0", "--reconnect-after", "0.8", "--log", str(log_file)]
    if not tcp:
        args += ["--link", str(tmp_path / "gimbal")]
    with MockGimbal(*args, tcp=tcp) as mock:
        url = mock.url if tcp else str(tmp_path / "gimbal")
        link = GimbalLink(url, link_config(reconnect_backoff_s=(0.05, 0.2)))
        try:
            link.start()
            assert link.wait_up(10.0), link.last_error
            assert track(link, 0.2, 0.1) is not None
            # keep commanding through the unplug; the link must notice and come back up by itself
            deadline = time.monotonic() + 10.0
            while link.counters()["link_losses"] == 0 and time.monotonic() < deadline:
                link.send_setpoint(0.2, 0.1)
                time.sleep(0.02)
            assert link.counters()["link_losses"] == 1
            assert link.wait_up(10.0), link.last_error
            final = track(link, -0.4, 0.3)
            assert final is not None and final.mode == MODE_ENABLED
            assert final.faults & FAULT_WATCHDOG  # the device noticed the outage and latched it
            assert link.clear_fault()
            assert link.wait_state(lambda st: st.faults == 0, 20.0) is not None
            c = link.counters()
            assert c["link_losses"] >= 1 and c["reconnects"] >= 1
        finally:
            link.stop()
        if not tcp:
            assert mock.readline(5.0).startswith("/dev/pts/")  # the replugged pty was announced
    rx = [r["type"] for r in read_log(log_file) if r["dir"] == "rx" and r["type"] != "SETPOINT"]
    assert rx.count("HELLO") >= 2 and rx.count("CONFIG") >= 2 and rx.count("ENABLE") >= 2


def test_watchdog_holds_and_a_setpoint_resumes() -> None:
    with MockGimbal(tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(watchdog_ms=100))
        try:
            link.start()
            assert link.wait_up(10.0)
            assert track(link, 0.5, 0.0) is not None
            held = link.wait_state(lambda st: st.mode == 2, 20.0)  # no more setpoints: holding
            assert held is not None and held.faults & FAULT_WATCHDOG and held.pan_rate == 0.0
            assert track(link, 0.1, 0.0) is not None
        finally:
            link.stop()


def test_device_fault_blocks_enable_until_cleared() -> None:
    with MockGimbal("--fault-at", "0.0:0", tcp=True) as mock:
        link = GimbalLink(mock.url, link_config())
        try:
            link.start()
            assert link.wait_up(10.0)
            st = link.wait_state(lambda st: st.mode == MODE_FAULT, 20.0)
            assert st is not None and st.faults & FAULT_OVERCURRENT
            assert link.set_enabled(True) is False  # NACK: fault active
            assert link.clear_fault() is True
            assert link.wait_state(lambda st: st.mode == MODE_DISABLED and st.faults == 0, 20.0) is not None
            assert link.set_enabled(True) is True
            assert link.wait_state(lambda st: st.mode == MODE_ENABLED, 20.0) is not None
        finally:
            link.stop()


def test_incompatible_protocol_version_is_refused() -> None:
    with MockGimbal("--protocol-version", "2", tcp=True) as mock:
        link = GimbalLink(mock.url, link_config())
        try:
            link.start()
            assert not link.wait_up(5.0)
            assert link.link_state == "incompatible"
            assert "protocol version 2" in link.last_error and mock.url in link.last_error
            assert link.send_setpoint(0.0, 0.0) is None
        finally:
            link.stop()


def test_rejected_config_is_reported() -> None:
    with MockGimbal(tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(pan_min=1.0, pan_max=-1.0))
        try:
            link.start()
            assert not link.wait_up(5.0)
            assert link.link_state == "incompatible"
            assert "rejected CONFIG: config invalid" in link.last_error
        finally:
            link.stop()


def test_lossy_corrupting_link_loses_no_acked_command_and_accepts_no_corrupted_frame(tmp_path) -> None:
    log_file = tmp_path / "log.csv"
    with MockGimbal("--drop", "0.05", "--corrupt", "0.05", "--seed", "7", "--log", str(log_file), tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(state_timeout_s=2.0))
        received = []
        link.subscribe(received.append)
        sent = {}
        try:
            link.start()
            assert link.wait_up(10.0), link.last_error
            for i in range(12):
                for k in range(10):
                    pan, tilt = 0.01 * (i * 10 + k), -0.005 * k
                    seq = link.send_setpoint(pan, tilt, 0.0, 0.0)
                    assert seq is not None
                    sent.setdefault(seq, []).append((pan, tilt))
                    link.wait_state(lambda st: False, 0.02)
                assert link.clear_fault(), f"CLEAR_FAULT {i} lost"
                assert link.set_enabled(True), f"ENABLE {i} lost"
            c = link.counters()
        finally:
            link.stop(disable=False)
        assert mock.terminate() == 0
    assert c["link_losses"] == 0 and c["ack_failures"] == 0
    assert c["retries"] > 0 and c["decode_drops"] > 0  # faults really happened and were repaired
    rows = read_log(log_file)
    # every SETPOINT the device accepted is exactly one the host sent
    for r in (r for r in rows if r["dir"] == "rx" and r["type"] == "SETPOINT"):
        assert (float(r["pan"]), float(r["tilt"])) in [(round(p, 6), round(t, 6)) for p, t in sent[int(r["seq"])]]
    # every STATE the host accepted is exactly one the device emitted
    emitted = {(int(r["device_time_us"]), float(r["pan"]), float(r["tilt"]), int(r["mode"]), int(r["faults"]))
               for r in rows if r["dir"] == "tx" and r["type"] == "STATE"}
    assert len(received) > 50
    for st in received:
        assert (st.device_time_us, st.pan, st.tilt, st.mode, st.faults) in emitted


def test_silent_device_is_detected_by_the_state_timeout_and_recovered() -> None:
    with MockGimbal(tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(state_timeout_s=0.3, reconnect_backoff_s=(0.05, 0.2)))
        try:
            link.start()
            assert link.wait_up(10.0)
            mock.proc.send_signal(signal.SIGSTOP)  # hung firmware: port open, nothing sent
            try:
                deadline = time.monotonic() + 10.0
                while link.link_state == "up" and time.monotonic() < deadline:
                    time.sleep(0.02)
                assert link.link_state in ("down", "connecting")
                assert "no STATE for 0.3 s" in link.last_error
            finally:
                mock.proc.send_signal(signal.SIGCONT)
            assert link.wait_up(10.0), link.last_error
            assert link.counters()["reconnects"] == 1
            assert track(link, 0.1, 0.1) is not None
        finally:
            link.stop()


def test_link_over_a_spy_url_records_the_handshake_bytes(tmp_path) -> None:
    spy_file = tmp_path / "spy.txt"
    with MockGimbal() as mock:
        link = GimbalLink(f"spy://{mock.url}?file={spy_file}", link_config())
        try:
            link.start()
            assert link.wait_up(10.0), link.last_error
        finally:
            link.stop()
    text = spy_file.read_text()
    tx = [line for line in text.splitlines() if " TX " in line]
    assert tx[0].split()[3:4] == ["00"]  # a lone delimiter flushes any partial frame at the device
    assert codec.encode(Hello(1), 0).hex(" ").upper() in tx[1]  # then HELLO, seq 0
    assert " RX " in text
