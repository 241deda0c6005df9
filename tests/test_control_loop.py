"""ControlLoop against a fake of our GimbalInterface and a fake clock: deterministic, no sleeps.

The fake gimbal is a perfect plant (it reports the last setpoint as its state), so a run of N ticks is
N control periods of simulated time; the real link and device are covered in test_control.py.
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from gimbal_fakes import IDENTITY, FakeClock, FakeGimbal, plan_towards, pose_at
from support import REPO

from pivotd.config import load_config
from pivotd.daemon.states import DaemonState
from pivotd.daemon.wiring import build_control_loop
from pivotd.gimbal.interface import GimbalInterface, GimbalMode, LinkState
from pivotd.gimbal.kinematics import Mount, world_direction_to_joints


@pytest.fixture
def rig():
    cfg = load_config(REPO / "config" / "demo.yaml")
    clock = FakeClock()
    gimbal = FakeGimbal(clock)
    fake: GimbalInterface = gimbal  # the fake satisfies the interface the loop depends on
    loop = build_control_loop(cfg, fake, clock=clock)
    return cfg, clock, gimbal, loop


def _run(loop, clock, ticks, pose_fn, plan_fn, faulted=False):
    out = []
    for _ in range(ticks):
        clock.t += loop.settings.rate_hz ** -1
        out.append(loop.tick(clock.t, pose_fn(clock.t), plan_fn(clock.t), faulted=faulted))
    return out


def _max_abs_diff(values, dt):
    return np.abs(np.diff(np.asarray(values), axis=0)).max(axis=0) / dt


def test_tracks_the_plan_within_the_motion_limits(rig):
    cfg, clock, gimbal, loop = rig
    target = np.array([0.5, 0.8, -0.1])
    ticks = _run(loop, clock, 300, pose_at, lambda t: plan_towards(target, t))
    assert {t.mode for t in ticks} == {DaemonState.TRACKING}
    pan, tilt, clamped = world_direction_to_joints(target, IDENTITY, cfg.gimbal.mount, cfg.gimbal.limits)
    assert not clamped
    sp = np.array(gimbal.setpoints)
    np.testing.assert_allclose(sp[-1, :2], [pan, tilt], atol=1e-6)
    # The first setpoint continues from the measured state, not from zero.
    np.testing.assert_allclose(sp[0, :2], [0.2, -0.1], atol=1e-3)
    dt = cfg.control.dt
    vmax = np.array([cfg.motion.pan.max_velocity, cfg.motion.tilt.max_velocity])
    assert np.all(_max_abs_diff(sp[:, :2], dt) <= vmax * 1.001)
    assert np.all(np.abs(sp[:, 2:]).max(axis=0) <= vmax * 1.001)


def test_stale_pose_or_plan_holds_and_stops(rig):
    cfg, clock, gimbal, loop = rig
    _run(loop, clock, 20, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))  # start moving towards +90° pan
    assert abs(gimbal.setpoints[-1][2]) > 0.05  # moving
    old = clock.t
    stale = _run(loop, clock, 200, lambda t: pose_at(old - cfg.control.pose_timeout_s - 0.01),
                 lambda t: plan_towards([0.0, 1.0, 0.0], t))
    assert {t.mode for t in stale} == {DaemonState.HOLDING}
    assert stale[-1].setpoint[2:] == (0.0, 0.0)
    plan_old = plan_towards([1.0, -1.0, 0.0], clock.t - 2 * loop.settings.plan_timeout)
    held = _run(loop, clock, 10, pose_at, lambda t: plan_old)
    assert {t.mode for t in held} == {DaemonState.HOLDING}
    assert held[-1].setpoint[:2] == stale[-1].setpoint[:2]


def test_no_pose_waits_in_place(rig):
    _, clock, gimbal, loop = rig
    ticks = _run(loop, clock, 10, lambda t: None, lambda t: None)
    assert {t.mode for t in ticks} == {DaemonState.WAITING}
    np.testing.assert_allclose(np.array(gimbal.setpoints)[:, :2], [[0.2, -0.1]] * 10, atol=1e-12)


def test_link_down_sends_nothing_and_reseeds_from_the_measured_state(rig):
    _, clock, gimbal, loop = rig
    _run(loop, clock, 30, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))
    gimbal.link_state = LinkState.DOWN
    n = len(gimbal.setpoints)
    down = _run(loop, clock, 10, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))
    assert {t.mode for t in down} == {DaemonState.LINK_DOWN}
    assert len(gimbal.setpoints) == n and all(t.setpoint is None for t in down)
    # The device moved while the link was down (e.g. it was re-powered at its home pose).
    gimbal.state = replace(gimbal.state, pan=-0.4, tilt=0.3, pan_rate=0.0, tilt_rate=0.0)
    gimbal.link_state = LinkState.UP
    up = _run(loop, clock, 1, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))
    assert up[0].mode == DaemonState.TRACKING
    np.testing.assert_allclose(up[0].setpoint[:2], [-0.4, 0.3], atol=0.01)


def test_fault_sends_heartbeats_only(rig):
    _, clock, gimbal, loop = rig
    gimbal.state = replace(gimbal.state, mode=GimbalMode.FAULT)
    ticks = _run(loop, clock, 25, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))
    assert {t.mode for t in ticks} == {DaemonState.FAULT}
    assert gimbal.setpoints == [] and gimbal.heartbeats == 25


def test_park_target_overrides_theplan_towards(rig):
    _, clock, gimbal, loop = rig
    loop.override_target = (0.0, 0.0)
    ticks = _run(loop, clock, 300, pose_at, lambda t: plan_towards([0.0, 1.0, 0.0], t))
    assert {t.mode for t in ticks} == {DaemonState.PARKING}
    np.testing.assert_allclose(gimbal.setpoints[-1], (0.0, 0.0, 0.0, 0.0), atol=1e-9)


def test_reconfigured_mount_changes_the_joint_target(rig):
    """A base yawed by +30° in the body frame needs 30° less pan for the same world direction."""
    cfg, clock, gimbal, loop = rig
    target = np.array([0.3, 1.0, 0.0])
    _run(loop, clock, 300, pose_at, lambda t: plan_towards(target, t))
    pan_before = gimbal.setpoints[-1][0]
    yawed = Mount.from_xyz_rpy(cfg.gimbal.mount.translation, [0.0, 0.0, math.radians(30.0)])
    loop.reconfigure(loop.settings, yawed)
    _run(loop, clock, 300, pose_at, lambda t: plan_towards(target, t))
    assert gimbal.setpoints[-1][0] == pytest.approx(pan_before - math.radians(30.0), abs=2e-3)


def test_pose_latency_is_measured_on_the_injected_clock(rig):
    _, clock, _, loop = rig
    rx = clock.t
    clock.t += 0.004  # the pose arrived 4 ms before this tick
    loop.tick(clock.t, pose_at(rx), plan_towards([1.0, 0.0, 0.0], clock.t))
    assert list(loop.stats.pose_latency) == [pytest.approx(0.004)]


def test_takes_the_pan_branch_the_plan_chose_over_its_horizon(rig):
    """On a ±270° gimbal a direction at pan 200° (≡ −160°) has two reachable joint values. The per-tick
    nearest-branch rule from the start (pan 11°) would take −160°; the plan's joint pans (chosen for the whole horizon,
    pivotd.gimbal.pan_unwrap) say +200°, and the loop goes there."""
    cfg, clock, _, _ = rig
    wide = replace(cfg.gimbal.limits, pan_min=math.radians(-270), pan_max=math.radians(270))
    cfg = replace(cfg, gimbal=replace(cfg.gimbal, limits=wide))
    d = np.array([math.cos(math.radians(200)), math.sin(math.radians(200)), 0.0])
    ends = []
    for pans in (np.full(5, math.radians(200)), None):
        gimbal = FakeGimbal(clock)
        loop = build_control_loop(cfg, gimbal, clock=clock)
        _run(loop, clock, 600, pose_at, lambda t, pans=pans: replace(plan_towards(d, t), pans=pans))
        ends.append(math.degrees(gimbal.setpoints[-1][0]))
    assert ends == [pytest.approx(200.0, abs=0.1), pytest.approx(-160.0, abs=0.1)]
