"""GimbalLink against tools/mock_gimbal as a real subprocess over a pty and over TCP."""

import itertools
import signal
import time

import pytest
from proto_support import MockGimbal, link_config, read_log

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import (
    FAULT_OVERCURRENT,
    FAULT_WATCHDOG,
    MODE_DISABLED,
    MODE_ENABLED,
    MODE_FAULT,
    MODE_HOLDING,
    PROTOCOL_VERSION,
    Hello,
)
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
            assert link.identity.version == PROTOCOL_VERSION == link.protocol_version
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
    with MockGimbal("--protocol-version", "3", tcp=True) as mock:
        link = GimbalLink(mock.url, link_config())
        try:
            link.start()
            assert not link.wait_up(5.0)
            assert link.link_state == "incompatible"
            assert "protocol version 3" in link.last_error and "versions 1 and 2" in link.last_error
            assert mock.url in link.last_error and "\n" not in link.last_error
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
    assert codec.encode(Hello(PROTOCOL_VERSION), 0).hex(" ").upper() in tx[1]  # then HELLO, seq 0
    assert " RX " in text


def _stream_through_a_device_stall(link: GimbalLink, mock: MockGimbal, stall_s: float = 2.0):
    """Sweep pan at 0.5 rad/s with a setpoint every ≥ 10 ms; SIGSTOP the device for ``stall_s`` while streaming, as
    the control loop would go on. Return [(seq, send time)] of every setpoint sent and the receive time of the last
    STATE the host received before the stall."""
    rx: list[float] = []
    link.subscribe(lambda st: rx.append(st.rx_time))
    start = link.state
    sent: list[tuple[int, float]] = []
    t0 = time.monotonic()
    stopped_at = None
    while True:
        now = time.monotonic()
        if stopped_at is None and now - t0 > 0.5:
            mock.proc.send_signal(signal.SIGSTOP)
            stopped_at = time.monotonic()
        if stopped_at is not None and now - stopped_at > stall_s:
            break
        seq = link.send_setpoint(min(2.5, start.pan + 0.5 * (now - t0)), start.tilt, 0.5, 0.0)
        if seq is not None:
            sent.append((seq, now))  # the link judged the silence at a time >= now
        time.sleep(0.01)
    last_rx = max(t for t in rx if t <= stopped_at + 1.0)  # STATEs in flight when it stopped arrive just after
    mock.proc.send_signal(signal.SIGCONT)
    return sent, last_rx


@pytest.mark.parametrize("version", [2, 1])
def test_a_device_stall_finds_no_burst_of_setpoints_when_it_resumes(tmp_path, caplog, version) -> None:
    """The device process freezes for 2 s while the host streams, then resumes. The host stops sending as soon as
    the device is silent (a few state periods, not the 0.5 s state timeout): few setpoints are queued. A
    version-2 device drops each of them as stale (older than its validity on the device clock) and stays held,
    where it executed ~50 in a burst before; a version-1 device (documented fallback: one warning) executes the few
    the host's rule let through."""
    log_file = tmp_path / "gimbal.csv"
    with MockGimbal("--log", str(log_file), "--protocol-version", str(version), tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(reconnect_backoff_s=(0.05, 0.2)))
        try:
            with caplog.at_level("WARNING", logger="pivotd.gimbal.link"):
                link.start()
                assert link.wait_up(10.0), link.last_error
                assert link.protocol_version == version
                assert track(link, 0.0, 0.1) is not None
                silence = link.silence_s()
                assert silence == pytest.approx(0.1, abs=1e-3)  # 5 state periods at 50 Hz, not the 0.5 s state timeout
                sent, last_rx = _stream_through_a_device_stall(link, mock)
                into_silence = [(seq, t) for seq, t in sent if t > last_rx]
                # each setpoint sent had a STATE at most `silence` old; they were sent >= 10 ms apart
                assert all(t - last_rx <= silence for _, t in into_silence)
                assert len(into_silence) <= silence / 0.01 + 1
                assert link.counters()["setpoints_withheld"] > 0
                # the host declares the link lost and comes back by itself after the device resumes
                assert link.wait_up(10.0), link.last_error
                back = link.wait_state(lambda st: st.mode == MODE_HOLDING, 5.0)
                assert back is not None
            warnings = [r.getMessage() for r in caplog.records if r.levelname == "WARNING" and "speaks protocol" in
                        r.getMessage()]
            assert len(warnings) == (1 if version == 1 else 0)  # once, not at the reconnect again
            assert link.counters()["reconnects"] == 1
        finally:
            link.stop()
        assert mock.terminate() == 0
    rows = read_log(log_file)
    # what the device found queued when it resumed: sent after it stopped (up to a state period before the last
    # STATE the host received, which was then in flight)
    queued = {seq for seq, t in sent if t > last_rx - 0.05}
    executed = [r for r in rows if r["dir"] == "rx" and r["type"] == "SETPOINT"]
    stale = [r for r in rows if r["dir"] == "stale"]
    if version == 2:
        # only those are dropped as stale (a loaded host may have sent none into the silence: nothing then queued)
        assert {int(r["seq"]) for r in stale} <= queued
        for r in executed:  # no setpoint was executed past its validity
            age, max_age = (int(kv.split("=")[1]) for kv in r["detail"].split())
            assert age <= max_age * 1000
        # the device resumed where more than a second passed between two frames it received
        rx = [r for r in rows if r["dir"] in ("rx", "stale")]
        resumed_at = next(float(b["t_s"]) for a, b in itertools.pairwise(rx) if float(b["t_s"]) - float(a["t_s"]) > 1.0)
        assert not [r for r in executed if float(r["t_s"]) >= resumed_at]
        # it held still from the resume on: reconnect, ENABLE and DISABLE start from where it stands
        pans = [float(r["pan"]) for r in rows if r["dir"] == "tx" and r["type"] == "STATE"
                and float(r["t_s"]) >= resumed_at]
        assert pans and max(pans) - min(pans) <= 1e-6
    else:
        assert not stale
        # the burst it executed on resuming (the first setpoints after a gap of more than a second of its clock,
        # before the host's new handshake) is bounded by the host's silence rule: ~50 before it
        rx = [r for r in rows if r["dir"] == "rx"]
        resume = next(i for i in range(1, len(rx)) if float(rx[i]["t_s"]) - float(rx[i - 1]["t_s"]) > 1.0)
        burst = []
        for r in rx[resume:]:
            if r["type"] != "SETPOINT":
                break
            burst.append(int(r["seq"]))
        assert set(burst) <= queued and len(burst) <= silence / 0.01 + 1 + 5  # + those in flight at the stop
        assert all(r["detail"] == "" for r in executed)  # version-1 setpoints: no validity on the wire


def test_a_short_device_silence_withholds_setpoints_and_leaves_a_seq_gap_before_the_next() -> None:
    """The device stops answering for a little more than 5 state periods (well within the state timeout, 5 s here:
    the link stays up). The host sends nothing from 5 state periods on; the first setpoint once the device speaks
    again skips the withheld seq, so the break of the stream shows on the wire (the control loop restarts it from a
    measured state there)."""
    with MockGimbal(tcp=True) as mock:
        link = GimbalLink(mock.url, link_config(state_timeout_s=5.0))
        try:
            link.start()
            assert link.wait_up(10.0), link.last_error
            assert track(link, 0.2, 0.0) is not None
            last = link.send_setpoint(0.2, 0.0)
            assert last is not None
            mock.proc.send_signal(signal.SIGSTOP)
            try:
                deadline = time.monotonic() + 5.0
                while link.counters()["setpoints_withheld"] == 0 and time.monotonic() < deadline:
                    seq = link.send_setpoint(0.2, 0.0)
                    last = last if seq is None else seq
                    time.sleep(0.01)
                assert link.counters()["setpoints_withheld"] == 1
            finally:
                mock.proc.send_signal(signal.SIGCONT)
            resumed = time.monotonic()
            assert link.wait_state(lambda st: st.rx_time > resumed, 5.0) is not None
            after = link.send_setpoint(0.2, 0.0)
            assert after == (last + 2) & 0xFF  # the withheld one took last + 1
            assert link.link_state == "up" and link.counters()["link_losses"] == 0
            assert link.counters()["silences"] == 1
        finally:
            link.stop()
