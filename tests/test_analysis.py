"""Run analysis: setpoint dynamics by finite differences, per-frame visibility counts."""

import math

import numpy as np

from pivotd.gimbal.motion import AxisLimits
from pivotd.sim.analysis import setpoint_dynamics, visible_counts


def test_dynamics_of_a_known_cubic():
    dt = 0.01
    t = np.arange(0, 1, dt)
    jerk = 2.0  # rad/s³: p = j t³ / 6
    pos = np.column_stack([jerk * t**3 / 6, -0.5 * jerk * t**3 / 6])
    rates = np.column_stack([jerk * t**2 / 2, -0.5 * jerk * t**2 / 2])
    lim = AxisLimits(max_velocity=1.0, max_acceleration=2.0, max_jerk=2.0)
    rep = setpoint_dynamics(pos, dt, lim, lim, rates=rates)
    np.testing.assert_allclose(rep.max_jerk, [2.0, 1.0], rtol=1e-9)
    np.testing.assert_allclose(rep.max_acceleration, [jerk * t[-1], 0.5 * jerk * t[-1]], rtol=0.02)
    assert rep.within_limits
    tight = AxisLimits(max_velocity=1.0, max_acceleration=2.0, max_jerk=1.9)
    assert not setpoint_dynamics(pos, dt, tight, tight, rates=rates).within_limits
    # From positions alone the same figures come out (exact data: no rounding here).
    np.testing.assert_allclose(setpoint_dynamics(pos, dt, lim, lim).max_jerk, [2.0, 1.0], rtol=1e-6)
    # travel: p(0.99) per axis (monotone); near top speed: rate > 0.9 rad/s, i.e. t > √0.9 for pan only
    np.testing.assert_allclose(rep.travel, np.abs(pos[-1]), rtol=1e-9)
    assert rep.near_top_speed[1] == 0.0
    assert rep.near_top_speed[0] == np.mean(rates[:, 0] > 0.9)


def test_wire_rounding_is_within_the_allowance():
    dt = 0.01
    t = np.arange(0, 2, dt)
    pos = np.column_stack([0.3 * np.sin(t), 0.1 * np.cos(t)])
    lim = AxisLimits(max_velocity=0.31, max_acceleration=0.31, max_jerk=0.31)
    rounded = np.round(pos * 1e6) / 1e6
    rep = setpoint_dynamics(rounded, dt, lim, lim)
    assert rep.max_jerk.max() > 0.31  # rounding alone pushes the raw figure over the limit ...
    assert rep.within_limits  # ... but not beyond the allowance for micro-radian angles


def test_visible_counts_cone_and_range():
    pts = np.array([[1.0, 0, 0], [1.0, 0.1, 0], [0, 1.0, 0], [10.0, 0, 0], [0.05, 0, 0]])
    cams = np.zeros((2, 3))
    dirs = np.array([[1.0, 0, 0], [0, 1.0, 0]])
    n = visible_counts(pts, cams, dirs, math.radians(15), min_range=0.1, max_range=5.0)
    assert n.tolist() == [2, 1]
