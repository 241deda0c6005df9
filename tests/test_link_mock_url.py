"""The in-process ``mock://`` pyserial URL and link behaviour that needs no subprocess."""

import pytest
import serial
from proto_support import link_config, read_log
from support import wait_until

import pivotd.gimbal.link as link_module
from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import MODE_ENABLED, Hello, Identity
from pivotd.gimbal.link import GimbalLink

pytestmark = pytest.mark.slow  # subprocesses / real time


def test_importing_the_link_registers_mock_urls() -> None:
    assert "pivotd.firmware_proto.urlhandler" in serial.protocol_handler_packages
    assert link_module.GimbalLink is GimbalLink


def test_mock_url_answers_hello_and_streams_state() -> None:
    port = serial.serial_for_url("mock://?state_hz=200", timeout=0.3)
    dec, frames = codec.StreamDecoder(), []

    def answered_and_streaming() -> bool:  # read until seen (a loaded machine streams fewer states per second)
        frames.extend(dec.feed(port.read(2000)))
        return any(isinstance(f.msg, Identity) for f in frames) and sum(f.msg.NAME == "STATE" for f in frames) >= 30

    try:
        port.write(codec.encode(Hello(1), 9))
        assert wait_until(answered_and_streaming, 20.0, interval=0.0)
        assert port.in_waiting >= 0
    finally:
        port.close()
    assert any(isinstance(f.msg, Identity) for f in frames)
    assert sum(1 for f in frames if f.msg.NAME == "STATE") >= 30  # ~200 Hz


@pytest.mark.parametrize("url, message", [
    ("mock://?bogus=1", "unknown option(s) bogus"),
    ("mock://?state_hz=fast", "bad option value"),
    ("mock://?state_hz=0", "state_hz must be > 0"),
])
def test_bad_mock_url_options_are_named(url, message) -> None:
    with pytest.raises(serial.SerialException, match=message.replace("(", r"\(").replace(")", r"\)")):
        serial.serial_for_url(url)


def test_link_over_mock_url_tracks_and_logs(tmp_path) -> None:
    log_file = tmp_path / "m.csv"
    link = GimbalLink(f"mock://?state_hz=100&log={log_file}", link_config())
    try:
        link.start()
        assert link.wait_up(5.0), link.last_error

        def arrived(st) -> bool:
            link.send_setpoint(-0.6, 0.4)
            return abs(st.pan + 0.6) < 1e-4 and abs(st.tilt - 0.4) < 1e-4

        st = link.wait_state(arrived, 10.0)
        assert st is not None and st.mode == MODE_ENABLED
    finally:
        link.stop()
    rows = read_log(log_file)
    assert [r["type"] for r in rows if r["dir"] == "rx"][:3] == ["HELLO", "CONFIG", "ENABLE"]
    assert any(r["type"] == "SETPOINT" and float(r["pan"]) == -0.6 for r in rows)


def test_link_reports_a_port_that_cannot_be_opened(tmp_path) -> None:
    url = str(tmp_path / "no-such-tty")
    link = GimbalLink(url, link_config(reconnect_backoff_s=(0.02, 0.05)))
    try:
        link.start()
        assert not link.wait_up(0.5)
        assert link.link_state in ("down", "connecting")
        assert url in link.last_error
        assert link.send_setpoint(0.0, 0.0) is None
        assert link.set_enabled(True) is False
    finally:
        link.stop()
    assert link.link_state == "stopped"


def test_limits_that_do_not_fit_the_wire_are_refused_at_construction() -> None:
    with pytest.raises(ValueError, match="non-finite"):
        GimbalLink("mock://", link_config(vmax_pan=float("nan")))
