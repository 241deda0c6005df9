"""The host's silence rule shared by the streaming gimbal backends (pivotd.gimbal.silence.SilenceRule): the state
period from the device's own stamps, the silence bound between its floor and the state timeout, the counters."""

from __future__ import annotations

import pytest

from pivotd.gimbal.silence import SilenceRule


def rule() -> SilenceRule:
    return SilenceRule(periods=5.0, min_s=0.1, timeout_s=0.5, name="test://")


def counters() -> dict[str, int]:
    return {"setpoints_withheld": 0, "heartbeats_withheld": 0, "silences": 0}


def test_the_bound_is_the_state_timeout_until_the_period_is_known_then_periods_of_it_within_floor_and_cap():
    r = rule()
    assert r.period_s is None and r.silence_s() == 0.5
    r.note(1_000_000)
    assert r.period_s is None and r.silence_s() == 0.5  # one stamp is no interval
    for k in range(1, 10):  # 25 Hz with millisecond stamps (time_boot_ms) and jitter: the smallest interval counts
        r.note(1_000_000 + 40_000 * k + (1000 if k % 2 else 0))
    assert r.period_s == pytest.approx(0.039)
    assert r.silence_s() == pytest.approx(5 * 0.039)
    fast = rule()
    for k in range(10):  # 200 Hz: 5 periods are 25 ms, below the floor
        fast.note(5000 * k)
    assert fast.silence_s() == 0.1
    slow = rule()
    for k in range(10):  # 2 Hz: 5 periods are 2.5 s, beyond the state timeout
        slow.note(500_000 * k)
    assert slow.silence_s() == 0.5


def test_the_device_clock_wrapping_counts_forwards_and_a_restarted_or_repeated_stamp_is_no_interval():
    r = rule()
    r.note(0xFFFFFFFF - 9_999)
    r.note(10_000)  # wrapped at 2^32 µs: 20 ms later
    assert r.period_s == pytest.approx(0.02)
    r.note(5_000)  # backwards: a reboot
    r.note(5_000)  # the same stamp again
    assert list(r._intervals) == [20_000]
    r.reset()  # a new connection: the next stamp pairs with none before it (the estimate stays until replaced)
    r.note(900_000_000)
    assert list(r._intervals) == [] and r.period_s == pytest.approx(0.02)


def test_silent_counts_each_withheld_frame_and_each_silence_once():
    r, n = rule(), counters()
    for k in range(10):
        r.note(20_000 * k)
    assert not r.silent(10.0, 9.95, True, n, "setpoints_withheld")
    assert r.silent(10.0, 9.85, True, n, "setpoints_withheld")
    assert r.silent(10.01, 9.85, True, n, "heartbeats_withheld")
    assert n == {"setpoints_withheld": 1, "heartbeats_withheld": 1, "silences": 1}
    assert not r.silent(10.1, 10.05, True, n, "setpoints_withheld")  # it answered again
    assert r.silent(10.3, 10.05, True, n, "setpoints_withheld")  # a second silence
    assert n["silences"] == 2
    assert r.silent(0.0, 0.0, False, n, "setpoints_withheld")  # no state yet: nothing is sent
