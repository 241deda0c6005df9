"""The gimbal link's state timeout judges the device's silence only while this process ran
(pivotd.gimbal.supervisor.SilenceClock): a stall of the host is counted as one, not as a silent device."""

from __future__ import annotations

import pytest

from pivotd.gimbal.supervisor import SilenceClock


class Clock:
    def __init__(self) -> None:
        self.t = 100.0

    def __call__(self) -> float:
        return self.t


def test_a_stall_of_the_host_does_not_count_against_the_state_timeout_and_is_counted():
    clock = Clock()
    silence = SilenceClock(0.25, clock)
    last_rx = clock.t
    for _ in range(10):  # running, states arrive
        clock.t += 0.02
        last_rx = clock.t
        assert silence.silent(last_rx) == 0.0
    clock.t += 3.0  # the process was stopped for 3 s: no state was read, none could be
    assert silence.silent(last_rx) == pytest.approx(0.0) and silence.stalls == 1
    for k in range(1, 6):  # running again, still no state: now the silence counts
        clock.t += 0.02
        assert silence.silent(last_rx) == pytest.approx(0.02 * k)
    clock.t += 0.02
    last_rx = clock.t  # the states queued during the stall are read
    assert silence.silent(last_rx) == 0.0 and silence.stalls == 1


def test_a_device_that_stops_while_the_host_runs_times_out_however_loaded_the_host_is():
    clock = Clock()
    silence = SilenceClock(0.25, clock)
    last_rx = clock.t
    silent = 0.0
    while silent <= 0.5:  # a loaded host: the watching loop runs every 0.2 s instead of 0.02 s
        clock.t += 0.2
        silent = silence.silent(last_rx)
    assert clock.t - last_rx == pytest.approx(0.6) and silence.stalls == 0
    # a real loss just after a stall is judged on the time since the stall
    clock.t += 1.0
    assert silence.silent(last_rx) == pytest.approx(0.6) and silence.stalls == 1
