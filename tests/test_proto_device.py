"""Reference device model: state machine, CONFIG validation, watchdog timing, clamping, dynamics."""

import itertools
import zlib
from dataclasses import replace

import pytest

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.device import DeviceInfo, DeviceModel
from pivotd.firmware_proto.messages import (
    FAULT_CLAMPED,
    FAULT_CONFIG,
    FAULT_OVERCURRENT,
    FAULT_WATCHDOG,
    MODE_DISABLED,
    MODE_ENABLED,
    MODE_FAULT,
    MODE_HOLDING,
    NACK_BAD_VALUE,
    NACK_CONFIG_INVALID,
    NACK_FAULT_ACTIVE,
    NACK_NOT_CONFIGURED,
    PROTOCOL_VERSION,
    Ack,
    ClearFault,
    Config,
    Enable,
    Heartbeat,
    Hello,
    Identity,
    Setpoint,
    SetpointV1,
    State,
)

CFG = Config(-2.0, 2.0, -1.0, 0.5, 1.0, 1.0, 4.0, 4.0, 250)


class Rig:
    """A device model driven by an explicit clock, with the host-side decoder. A version-2 SETPOINT sent without a
    validity (``max_age_ms`` 0) gets a fresh one: it echoes the device clock at ``t``, valid for 100 ms."""

    def __init__(self, version: int = PROTOCOL_VERSION, **kw) -> None:
        self.version = version
        self.dev = DeviceModel(info=DeviceInfo(version=version), **kw)
        self.dec = codec.StreamDecoder(version)
        self.seq = 0
        self.t = 0.0
        self.states: list[State] = []

    def frame(self, msg, t: float | None = None) -> bytes:
        """The wire frame of ``msg`` sent at ``t`` (the next seq)."""
        self.t = self.t if t is None else t
        self.seq = (self.seq + 1) & 0xFF
        if isinstance(msg, Setpoint) and msg.max_age_ms == 0:
            msg = replace(msg, state_time_us=round(self.t * 1e6) & 0xFFFFFFFF, max_age_ms=100)
        return codec.encode(msg, self.seq, self.version)

    def send(self, msg, t: float | None = None):
        frame = self.frame(msg, t)
        return self._collect(self.dev.feed(frame, self.t))

    def run_to(self, t: float):
        self.t = t
        return self._collect(self.dev.step(t))

    def _collect(self, data: bytes):
        frames = self.dec.feed(data)
        self.states += [f.msg for f in frames if isinstance(f.msg, State)]
        return [f.msg for f in frames if not isinstance(f.msg, State)]

    def enabled(self, cfg: Config = CFG) -> "Rig":
        (ack,) = self.send(cfg)
        assert ack.status == 0
        (ack,) = self.send(Enable(1))
        assert ack.status == 0
        return self


def test_starts_disabled_and_streams_state_at_a_fixed_rate() -> None:
    rig = Rig(state_hz=50.0)
    rig.run_to(0.0)
    rig.run_to(1.0)
    assert len(rig.states) == 51
    times = [s.device_time_us for s in rig.states]
    assert all(b - a == 20_000 for a, b in itertools.pairwise(times))
    assert {s.mode for s in rig.states} == {MODE_DISABLED}


def test_hello_answers_identity() -> None:
    (ident,) = Rig().send(Hello(1))
    assert isinstance(ident, Identity) and ident.version == PROTOCOL_VERSION


def test_valid_config_is_acked_with_its_crc32() -> None:
    (ack,) = Rig().send(CFG)
    assert ack == Ack(1, Config.TYPE, 0, zlib.crc32(CFG.pack()))


@pytest.mark.parametrize("bad", [
    Config(1.0, -1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 250),
    Config(-1.0, 1.0, 0.5, 0.5, 1.0, 1.0, 1.0, 1.0, 250),
    Config(-1.0, 1.0, -1.0, 1.0, 0.0, 1.0, 1.0, 1.0, 250),
    Config(-1.0, 1.0, -1.0, 1.0, 1.0, 1.0, -1.0, 1.0, 250),
    Config(-1.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 0),
    Config(-7.0, 1.0, -1.0, 1.0, 1.0, 1.0, 1.0, 1.0, 250),
])
def test_invalid_config_is_nacked_and_flagged(bad) -> None:
    rig = Rig()
    (ack,) = rig.send(bad)
    assert ack.status == NACK_CONFIG_INVALID
    rig.run_to(0.1)
    assert rig.states[-1].faults & FAULT_CONFIG
    (ack,) = rig.send(Enable(1))
    assert ack.status == NACK_NOT_CONFIGURED


def test_enable_needs_config_and_a_valid_value() -> None:
    rig = Rig()
    assert rig.send(Enable(1))[0].status == NACK_NOT_CONFIGURED
    rig.send(CFG)
    assert rig.send(Enable(2))[0].status == NACK_BAD_VALUE
    assert rig.send(Enable(1))[0].status == 0


def test_watchdog_expires_after_watchdog_ms_and_holds() -> None:
    rig = Rig().enabled()
    rig.send(Setpoint(1.0, 0.0), t=0.0)
    rig.run_to(0.24)
    assert rig.dev.mode == MODE_ENABLED
    rig.run_to(0.26)
    assert rig.dev.mode == MODE_HOLDING and rig.dev.faults & FAULT_WATCHDOG
    # rates ramp to zero within amax, then the position is held: it never keeps moving
    rig.run_to(2.0)
    hold = [s for s in rig.states if s.device_time_us > 260_000]
    rates = [abs(s.pan_rate) for s in hold]
    assert all(b <= a + 1e-6 for a, b in itertools.pairwise(rates))
    assert hold[-1].pan_rate == 0.0
    still = [s.pan for s in hold if s.device_time_us > 1_000_000]
    assert max(still) == min(still)


def test_setpoints_and_heartbeats_feed_the_watchdog() -> None:
    rig = Rig().enabled()
    for i in range(20):
        rig.send(Heartbeat() if i % 2 else Setpoint(0.1, 0.0), t=i * 0.2)
        rig.run_to(i * 0.2 + 0.19)
    assert rig.dev.mode == MODE_ENABLED and not rig.dev.faults


def test_setpoint_while_holding_resumes_and_fault_stays_latched() -> None:
    rig = Rig().enabled()
    rig.run_to(0.5)
    assert rig.dev.mode == MODE_HOLDING
    rig.send(Setpoint(0.3, 0.0), t=0.5)
    assert rig.dev.mode == MODE_ENABLED
    rig.run_to(0.6)
    assert rig.states[-1].faults & FAULT_WATCHDOG
    (ack,) = rig.send(ClearFault())
    assert ack.status == 0
    rig.run_to(0.62)
    assert rig.states[-1].faults == 0 and rig.states[-1].mode == MODE_ENABLED


def test_setpoints_are_clamped_to_the_limits() -> None:
    rig = Rig().enabled()
    for i in range(40):
        rig.send(Setpoint(5.0, -3.0), t=i * 0.1)
        rig.run_to(i * 0.1 + 0.09)
    s = rig.states[-1]
    assert s.pan == pytest.approx(CFG.pan_max, abs=1e-5)
    assert s.tilt == pytest.approx(CFG.tilt_min, abs=1e-5)
    assert s.faults & FAULT_CLAMPED
    assert all(CFG.pan_min <= x.pan <= CFG.pan_max and CFG.tilt_min <= x.tilt <= CFG.tilt_max for x in rig.states)


def test_tracking_respects_rate_and_acceleration_limits_with_some_lag() -> None:
    rig = Rig(state_hz=100.0).enabled()
    for i in range(30):
        rig.send(Setpoint(1.5, 0.4), t=i * 0.1)
        rig.run_to(i * 0.1 + 0.099)
    pans = [s.pan_rate for s in rig.states]
    assert max(abs(v) for v in pans) <= CFG.vmax_pan + 1e-6
    dv = [abs(b - a) for a, b in itertools.pairwise(pans)]
    assert max(dv) <= CFG.amax_pan * 0.01 + 1e-5
    assert rig.states[-1].pan == pytest.approx(1.5, abs=1e-4)
    assert rig.states[-1].tilt == pytest.approx(0.4, abs=1e-4)
    assert rig.states[10].pan < 1.0  # it took time to get there


def test_setpoints_ignored_while_disabled_but_seq_echoed() -> None:
    rig = Rig()
    rig.send(CFG)
    rig.send(Setpoint(1.0, 0.0), t=0.0)
    rig.run_to(1.0)
    assert rig.states[-1].pan == 0.0 and rig.states[-1].last_setpoint_seq == rig.seq


def test_severe_fault_enters_fault_mode_until_cleared() -> None:
    rig = Rig().enabled()
    rig.dev.inject_fault(FAULT_OVERCURRENT)
    rig.run_to(0.1)
    assert rig.states[-1].mode == MODE_FAULT and rig.states[-1].faults & FAULT_OVERCURRENT
    assert rig.send(Enable(1))[0].status == NACK_FAULT_ACTIVE
    rig.send(Setpoint(1.0, 0.0))
    assert rig.dev.mode == MODE_FAULT
    assert rig.send(ClearFault())[0].status == 0
    assert rig.dev.mode == MODE_DISABLED and rig.dev.faults == 0
    assert rig.send(Enable(1))[0].status == 0


def test_enable_starts_from_the_current_position() -> None:
    rig = Rig().enabled()
    for i in range(10):
        rig.send(Setpoint(0.8, 0.0), t=i * 0.1)
        rig.run_to(i * 0.1 + 0.09)
    rig.send(Enable(0))
    rig.run_to(2.0)
    pan = rig.states[-1].pan
    rig.send(Enable(1))
    rig.run_to(2.2)
    assert rig.states[-1].pan == pytest.approx(pan, abs=1e-6)


# ------------------------------------------------------------------ setpoint validity (protocol version 2)
def _stale(pan: float, state_time_s: float, max_age_ms: int = 100) -> Setpoint:
    """A setpoint echoing the STATE of device time ``state_time_s``, valid for ``max_age_ms``."""
    return Setpoint(pan, 0.0, 0.5, 0.0, 0, round(state_time_s * 1e6), max_age_ms)


def test_stale_setpoint_does_not_wake_a_held_device() -> None:
    rig = Rig().enabled()
    rig.send(Setpoint(0.2, 0.0), t=0.0)
    rig.run_to(1.0)
    assert rig.dev.mode == MODE_HOLDING
    held, seq = rig.states[-1].pan, rig.dev.last_setpoint_seq
    # the setpoints a stalled device finds queued when it resumes: computed from a state of t=0.02 s
    burst = b"".join(rig.frame(_stale(0.2 + 0.01 * i, 0.02), t=2.0) for i in range(50))
    rig._collect(rig.dev.feed(burst, 2.0))
    rig.run_to(3.0)
    assert rig.dev.stale_setpoints == 50
    assert rig.dev.mode == MODE_HOLDING
    assert rig.dev.last_setpoint_seq == seq  # the echo names the last setpoint executed
    after = [s for s in rig.states if s.device_time_us >= 2_000_000]
    assert {s.mode for s in after} == {MODE_HOLDING}
    assert max(abs(s.pan - held) for s in after) == 0.0 and max(abs(s.pan_rate) for s in after) == 0.0
    # a fresh one resumes tracking
    rig.send(Setpoint(0.5, 0.0), t=3.0)
    assert rig.dev.mode == MODE_ENABLED and rig.dev.pan.target == 0.5


def test_stale_setpoint_while_enabled_neither_moves_nor_feeds_the_watchdog() -> None:
    rig = Rig().enabled()
    rig.send(Setpoint(0.1, 0.0), t=1.0)
    for i in range(1, 6):  # old by 200 ms on arrival, valid for 100 ms
        rig.send(_stale(1.5, 1.0 + i * 0.05 - 0.2), t=1.0 + i * 0.05)
    assert rig.dev.pan.target == 0.1 and rig.dev.stale_setpoints == 5
    rig.run_to(1.26)
    assert rig.dev.mode == MODE_HOLDING and rig.dev.faults & FAULT_WATCHDOG  # fed only at t = 0


def test_setpoint_validity_boundary_on_the_device_clock() -> None:
    rig = Rig().enabled()
    rig.send(_stale(0.3, 0.5, max_age_ms=100), t=0.6)  # exactly 100 ms old: still valid
    assert rig.dev.pan.target == 0.3 and rig.dev.stale_setpoints == 0
    rig.send(_stale(0.4, 0.5, max_age_ms=100), t=0.600001)
    assert rig.dev.pan.target == 0.3 and rig.dev.stale_setpoints == 1
    rig.send(_stale(0.4, 0.7, max_age_ms=100), t=0.65)  # a state time from the future is not fresh either
    assert rig.dev.pan.target == 0.3 and rig.dev.stale_setpoints == 2


def test_stale_setpoints_are_logged_apart_from_executed_ones() -> None:
    rows = []
    rig = Rig(on_message=lambda d, m, seq, now: rows.append((d, m.NAME, seq)))
    rig.enabled()
    rig.send(Setpoint(0.1, 0.0), t=0.0)
    rig.send(_stale(0.2, 0.0), t=1.0)
    sp = [(d, seq) for d, name, seq in rows if name == "SETPOINT"]
    assert sp == [("rx", 3), ("stale", 4)]


def test_version_1_device_executes_the_version_1_setpoint_and_drops_version_2_frames() -> None:
    rig = Rig(version=1).enabled()
    (ident,) = rig.send(Hello(2))
    assert ident.version == 1
    rig.send(SetpointV1(0.3, 0.0), t=0.0)
    assert rig.dev.pan.target == 0.3 and rig.dev.mode == MODE_ENABLED
    rig.dev.feed(codec.encode(Setpoint(0.6, 0.0, 0.0, 0.0, 0, 0, 100), 9), 0.0)
    assert rig.dev.pan.target == 0.3 and rig.dev.decoder.drops["version"] == 1


def test_a_stuck_axis_does_not_move_reports_its_position_and_no_fault_then_tracks_from_there() -> None:
    """inject_stuck_axis: the pan axis is held mechanically (a blocked gimbal): it does not move while setpoints
    ask it to, its encoder reports the stuck position at rate 0, no fault bit is set and the mode stays ENABLED;
    tilt moves on. Freed, it tracks its target from where it stood."""
    rig = Rig().enabled()
    rig.dev.inject_stuck_axis("pan", 0.5, now=0.0)
    for k in range(1, 50):
        rig.send(Setpoint(0.01 * k, -0.01 * k, 1.0, -1.0), t=0.01 * k)
    rig.run_to(0.5)
    stuck = [s for s in rig.states if 0 < s.device_time_us <= 500_000]
    assert {(s.pan, s.pan_rate) for s in stuck} == {(0.0, 0.0)}
    assert {s.mode for s in stuck} == {MODE_ENABLED} and {s.faults for s in stuck} == {0}
    assert stuck[-1].tilt < -0.3  # the other axis followed
    for k in range(30):
        rig.send(Setpoint(0.49, -0.49, 0.0, 0.0), t=0.5 + 0.05 * k)
    rig.run_to(2.0)
    assert rig.states[-1].pan == pytest.approx(0.49, abs=1e-3)  # freed: it went to its target
    with pytest.raises(ValueError, match="axis must be"):
        rig.dev.inject_stuck_axis("roll", 1.0)
