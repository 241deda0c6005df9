"""The demo's verdict on setpoint dynamics over a DYNAMIXEL wire: goal positions in ticks of 0.088°, no rates.

Finite differences of ticks show the wire's quantisation (one tick between two periods reads as hundreds of deg/s²),
not the motion: the summary judges the setpoints sent, as recorded, and reports the ticks apart. The verdict and the
percentages printed beside it agree.
"""

from __future__ import annotations

import dataclasses
import re

import numpy as np
import pytest

from pivotd.config import load_config
from pivotd.gimbal.dynamixel_table import angle_to_ticks, ticks_to_angle
from pivotd.gimbal.motion import MotionGenerator
from pivotd.sim.analysis import DeviceLog, dynamics_lines, dynamics_report
from pivotd.sim.launch import REPO


@pytest.fixture(scope="module")
def cfg():
    base = load_config(REPO / "config" / "demo.yaml")
    return dataclasses.replace(base, gimbal=dataclasses.replace(base.gimbal, backend="dynamixel"))


def commanded_stream(cfg) -> tuple[np.ndarray, np.ndarray]:
    """Setpoints (angles, rates) of the demo's real Ruckig generator swinging between three targets at its limits."""
    gen = MotionGenerator(cfg.control.dt, cfg.motion.pan, cfg.motion.tilt, cfg.gimbal.limits)
    angles, rates = [], []
    for target in ([1.0, 0.4], [-1.2, -0.3], [0.3, 0.6]):
        gen.set_target(np.array(target))
        for _ in range(300):
            s = gen.step()
            angles.append(s.position.copy())
            rates.append(s.velocity.copy())
    return np.array(angles), np.array(rates)


def device_log(angles: np.ndarray) -> DeviceLog:
    """What the servo simulator logs for these setpoints: goal positions rounded to ticks, no rates."""
    goals = np.array([[ticks_to_angle(angle_to_ticks(a)) for a in row] for row in angles])
    n = goals.shape[0]
    empty = np.zeros(0)
    return DeviceLog(np.arange(n) * 0.01, goals, np.full((n, 2), np.nan), np.arange(n) * 0.01, empty,
                     np.zeros((0, 2)), np.zeros(0, int), np.zeros(0, int), [])


def printed_percentages(lines: list[str]) -> list[float]:
    return [float(x) for line in lines if "worst velocity" in line for x in re.findall(r"\(([\d.]+)%", line)]


def test_a_stream_within_the_limits_is_judged_within_them_with_percentages_up_to_the_allowance(cfg):
    angles, rates = commanded_stream(cfg)
    report = dynamics_report(cfg, device_log(angles), (angles, rates))
    lines = dynamics_lines(report)
    shares = printed_percentages(lines)
    assert len(shares) == 6
    # the generator drives the axes at their limits (so the figures are not trivially small) and not beyond
    assert max(shares) >= 99.0 and max(shares) <= 100.1, lines
    assert report["within_limits"] and lines[-2].endswith(": yes"), lines
    assert any(line.startswith("  judged: the setpoints sent") for line in lines), lines
    # the ticks are reported apart, in words: the wire's resolution, the goal positions it carried
    wire = next(line for line in lines if line.startswith("  wire:"))
    assert f"{angles.shape[0]} goal positions in ticks of 0.0879°" in wire, wire
    # (the figure that contradicted the verdict: differences of those ticks read as several times the limits)
    ticks_only = dynamics_report(cfg, device_log(angles))
    assert max(ticks_only["acceleration_ratio"]) > 2.0
    assert "quantisation, not the motion" in ticks_only["dynamics_source"]


def test_a_stream_beyond_the_jerk_limit_is_judged_beyond_it_with_the_percentage_shown(cfg):
    # from standing still the pan rate ramps at a_max at once: within the acceleration limit, but the acceleration
    # steps from 0 to a_max in one period (a jerk of a_max / dt, 15 times the demo's limit)
    dt, pan = cfg.control.dt, cfg.motion.pan
    k = np.arange(300)
    rates = np.zeros((k.size, 2))
    rates[:, 0] = np.minimum(pan.max_acceleration * dt * np.maximum(k - 50, 0), 0.5 * pan.max_velocity)
    angles = np.zeros_like(rates)
    angles[:, 0] = np.cumsum(rates[:, 0]) * dt
    report = dynamics_report(cfg, device_log(angles), (angles, rates))
    lines = dynamics_lines(report)
    assert not report["within_limits"] and lines[-2].endswith(": NO"), lines
    pan_line = next(line for line in lines if line.startswith("  pan"))
    velocity, acceleration, jerk = (float(x) for x in re.findall(r"\(([\d.]+)%", pan_line))
    assert velocity == pytest.approx(50.0, abs=0.1) and acceleration == pytest.approx(100.0, abs=0.1), pan_line
    assert jerk == pytest.approx(100 * pan.max_acceleration / dt / pan.max_jerk, rel=1e-3), pan_line
