"""DeviceClock: a state's measured time on the host clock, from the device's timestamp."""

from __future__ import annotations

import numpy as np
import pytest

from pivotd.gimbal.device_clock import DeviceClock


def _feed(clock: DeviceClock, device_us: list[int], rx: list[float]) -> list[float]:
    return [clock.measured_at(d, r) for d, r in zip(device_us, rx, strict=True)]


def test_states_read_late_keep_the_time_they_were_measured_at():
    """50 Hz states with 0.1–2 ms transit; then the host stalls for 0.3 s and reads the 15 queued states at once."""
    rng = np.random.default_rng(0)
    clock = DeviceClock()
    host0, dev0 = 1000.0, 123_456_789
    t_meas = [host0 + 0.02 * k for k in range(100)]
    rx = [t + rng.uniform(1e-4, 2e-3) for t in t_meas]
    got = _feed(clock, [dev0 + round((t - host0) * 1e6) for t in t_meas], rx)
    assert np.all(np.array(got) <= np.array(rx))
    assert np.max(np.abs(np.array(got[10:]) - np.array(t_meas[10:]))) < 2.1e-3
    resume = t_meas[-1] + 0.32
    queued = [t_meas[-1] + 0.02 * k for k in range(1, 16)]
    late = _feed(clock, [dev0 + round((t - host0) * 1e6) for t in queued], [resume + 1e-4 * k for k in range(15)])
    assert np.max(np.abs(np.array(late) - np.array(queued))) < 2.1e-3
    assert max(late) < resume - 0.015  # all measured before the host resumed


@pytest.mark.parametrize("ppm", [200.0, -200.0])
def test_the_device_clock_wraps_and_drift_is_followed(ppm):
    clock = DeviceClock(drift=1e-3)
    wrap = 1 << 32
    start = wrap - 500_000  # 0.5 s before the 32-bit wrap
    rate = 1.0 + ppm * 1e-6  # the device clock runs fast or slow
    got, truth = [], []
    for k in range(3000):  # 60 s at 50 Hz
        t = 5.0 + 0.02 * k
        dev = (start + round(0.02 * k * rate * 1e6)) % wrap
        got.append(clock.measured_at(dev, t + 5e-4))
        truth.append(t)
    err = np.array(got) - np.array(truth)
    assert np.max(np.abs(err)) < 2e-3  # across the wrap, and 12 ms of accumulated drift followed


def test_a_device_clock_that_runs_backwards_is_a_reboot():
    clock = DeviceClock()
    _feed(clock, [10_000_000, 10_020_000, 10_040_000], [50.0, 50.02, 50.04])
    assert clock.measured_at(20_000, 51.0) == pytest.approx(51.0)  # rebooted: a fresh mapping
    assert clock.measured_at(40_000, 51.02) == pytest.approx(51.02)


def test_reset_forgets_the_device():
    clock = DeviceClock()
    _feed(clock, [1_000_000, 1_020_000], [10.0, 10.02])
    clock.reset()
    assert clock.measured_at(1_040_000, 99.0) == pytest.approx(99.0)
