"""The tracking-error supervisor (pivotd.daemon.tracking_error) on synthetic setpoints and measured states."""

from __future__ import annotations

import logging
import math

import pytest

from pivotd.daemon.tracking_error import TrackingErrorSettings, TrackingErrorSupervisor, TrackingState

BOUND = math.radians(10.0)
WINDOW = 0.2
DT = 0.01


def supervisor() -> TrackingErrorSupervisor:
    return TrackingErrorSupervisor(TrackingErrorSettings(BOUND, WINDOW))


def drive(sup, t0, seconds, commanded, measured, state_every=2):
    """Send a setpoint every DT from t0 for ``seconds`` (commanded(t) -> (pan, tilt)) and judge a state measured
    every ``state_every`` periods (measured(t) -> (pan, tilt)); returns the verdicts that entered a fault (t, axes)."""
    faults = []
    n = round(seconds / DT)
    for k in range(n):
        t = t0 + k * DT
        sup.commanded(t, *commanded(t))
        if k % state_every == 0:
            v = sup.judge(t, t, *measured(t))
            if v.entered_fault:
                faults.append((t, v.entered_fault))
    return faults


def test_a_blocked_axis_faults_once_its_error_exceeded_the_bound_for_the_window(caplog):
    """Pan commanded at 1 rad/s, measured stuck at 0: the error passes the bound at 0.175 s, the fault comes one
    window later, names the axis, counts one episode and is logged once."""
    sup = supervisor()
    caplog.set_level(logging.WARNING, logger="pivotd.daemon.tracking_error")
    faults = drive(sup, 0.0, 1.0, lambda t: (1.0 * t, 0.2), lambda t: (0.0, 0.2))
    t_over = BOUND / 1.0
    assert faults and faults[0][1] == (0,)
    assert t_over + WINDOW <= faults[0][0] <= t_over + WINDOW + 3 * DT
    assert sup.state is TrackingState.FAULT and sup.episodes == 1
    assert sup.reason.startswith("pan does not follow") and "> 10.0°" in sup.reason
    assert len([r for r in caplog.records if "tracking error:" in r.getMessage()]) == 1
    assert sup.status()["state"] == "fault" and sup.status()["episodes"] == 1


def test_errors_within_the_bound_or_shorter_than_the_window_do_not_fault():
    sup = supervisor()
    assert not drive(sup, 0.0, 2.0, lambda t: (t, -t), lambda t: (t - 0.9 * BOUND, -t + 0.9 * BOUND))
    # 1.5 bounds of error for half a window, then following again, three times
    for k in range(3):
        t0 = 2.0 + k * WINDOW * 2
        assert not drive(sup, t0, WINDOW / 2, lambda t: (1.5 * BOUND, 0.0), lambda t: (0.0, 0.0))
        assert not drive(sup, t0 + WINDOW / 2, WINDOW, lambda t: (0.0, 0.0), lambda t: (0.0, 0.0))
    assert sup.state is TrackingState.OK and sup.episodes == 0


def test_the_commanded_position_is_the_one_sent_when_the_state_was_measured():
    """A state measured 30 ms before it is judged is compared with the setpoint sent then, not with the newest one:
    transport delay is not tracking error."""
    sup = supervisor()
    for k in range(100):
        t = k * DT
        sup.commanded(t, 2.0 * t, 0.0)  # 2 rad/s: 30 ms of delay would be 3.4° of apparent error
        if k >= 3:
            t_measured = (k - 3) * DT
            assert sup.errors(t_measured, 2.0 * t_measured, 0.0) == pytest.approx((0.0, 0.0), abs=1e-12)
    assert sup.errors(-1.0, 0.0, 0.0) is None  # measured before any setpoint was sent: not judged


def test_the_hold_probes_after_the_window_and_clears_when_the_axis_follows_again(caplog):
    sup = supervisor()
    caplog.set_level(logging.WARNING, logger="pivotd.daemon.tracking_error")
    drive(sup, 0.0, 0.42, lambda t: (1.0 * t, 0.0), lambda t: (0.0, 0.0))
    assert sup.state is TrackingState.FAULT and sup.holds == 1
    sup.restart()  # the loop restarted the axis from its measured state
    t_fault = sup.status_since
    # holding at the measured state: commanded = measured; a window after the fault it probes
    drive(sup, 0.42, t_fault + WINDOW - 0.42 - 2 * DT, lambda t: (0.0, 0.0), lambda t: (0.0, 0.0))
    assert sup.state is TrackingState.FAULT
    drive(sup, t_fault + WINDOW - 2 * DT, 6 * DT, lambda t: (0.0, 0.0), lambda t: (0.0, 0.0))
    assert sup.state is TrackingState.RECOVERING
    # still blocked: the probe runs beyond the bound and holds again at once (no new window, same episode)
    t2 = t_fault + WINDOW + 4 * DT
    faults = drive(sup, t2, 0.25, lambda t: (1.0 * (t - t2), 0.0), lambda t: (0.0, 0.0))
    assert faults and faults[0][0] <= t2 + BOUND + 3 * DT
    assert sup.state is TrackingState.FAULT and sup.episodes == 1 and sup.holds == 2
    sup.restart()
    t3 = t2 + 0.25
    drive(sup, t3, WINDOW, lambda t: (0.0, 0.0), lambda t: (0.0, 0.0))
    assert sup.state is TrackingState.RECOVERING
    # freed: it follows; the error staying within the bound for a window clears the episode
    t4 = t3 + WINDOW
    drive(sup, t4, WINDOW / 2, lambda t: (t - t4, 0.0), lambda t: (t - t4 - 0.01, 0.0))
    assert sup.state is TrackingState.RECOVERING  # not yet a window
    drive(sup, t4 + WINDOW / 2, WINDOW, lambda t: (t - t4, 0.0), lambda t: (t - t4 - 0.01, 0.0))
    assert sup.state is TrackingState.OK and sup.reason == ""
    assert sup.episodes == 1
    msgs = [r.getMessage() for r in caplog.records]
    assert sum("tracking error:" in m for m in msgs) == 1 and sum("tracking error cleared" in m for m in msgs) == 1


@pytest.mark.parametrize("bound,window", [(0.0, 0.2), (-1.0, 0.2), (math.nan, 0.2), (0.1, 0.0), (0.1, math.inf)])
def test_settings_are_validated(bound, window):
    with pytest.raises(ValueError, match="tracking error"):
        TrackingErrorSettings(bound, window)


def test_an_axis_catching_up_with_a_late_stream_is_not_a_fault():
    """On a loaded host the device may get a burst of setpoints late and then close a 15° error at its own limits:
    it moves towards its setpoint (at least half the setpoint's rate), so it follows and is not held. Standing
    still at the same error is a fault."""
    sup = supervisor()
    lag = math.radians(15.0)
    for k in range(100):  # 1 s at 15° behind a setpoint moving at 1 rad/s, the axis moving at 0.8 rad/s
        t = k * DT
        sup.commanded(t, 1.0 * t, 0.0, 1.0, 0.0)
        if k % 2 == 0:
            assert not sup.judge(t, t, 1.0 * t - lag, 0.0, 0.8, 0.0).entered_fault
    assert sup.state is TrackingState.OK and sup.worst_error == pytest.approx(lag)
    faults = []
    for k in range(100, 200):  # the same error, standing still
        t = k * DT
        sup.commanded(t, 1.0, 0.0, 0.0, 0.0)
        if k % 2 == 0 and sup.judge(t, t, 1.0 - lag, 0.0, 0.0, 0.0).entered_fault:
            faults.append(t)
    assert faults and faults[0] == pytest.approx(1.0 + WINDOW, abs=3 * DT)
