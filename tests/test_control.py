"""ControlLoop against a real GimbalLink on the in-process mock:// device: tracking, stale inputs, faults."""

import math
import time

import numpy as np
import pytest
from support import REPO, wait_until

from pivotd.bus.messages import PoseSample
from pivotd.config import load_config
from pivotd.daemon.planner import Plan
from pivotd.daemon.wiring import build_control_loop, build_link_config
from pivotd.gimbal.kinematics import world_direction_to_joints
from pivotd.gimbal.link import GimbalLink

pytestmark = pytest.mark.slow  # subprocesses / real time

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def plan_looking(direction, created=None, n=5):
    pos = np.column_stack([np.arange(n) * 0.5, np.zeros(n), np.full(n, 0.9)])
    d = np.tile(np.asarray(direction, float) / np.linalg.norm(direction), (n, 1))
    return Plan(created=time.monotonic() if created is None else created, positions=pos, directions=d,
                body_quats=np.tile(IDENTITY, (n, 1)), visible=np.zeros(n, int), s=np.arange(n) * 0.5,
                map_version=0, path_version=1, solve_s=0.0)


def pose(rx_time=None):
    return PoseSample(stamp=time.time(), frame_id="map", position=np.array([0.0, 0.0, 0.7]), quat=IDENTITY,
                      rx_time=time.monotonic() if rx_time is None else rx_time)


@pytest.fixture
def rig():
    cfg = load_config(REPO / "config" / "demo.yaml")
    link = GimbalLink("mock://?state_hz=100", build_link_config(cfg))
    link.start()
    assert link.wait_up(10)
    assert wait_until(lambda: link.state is not None and link.state.mode == 1, 5)
    loop = build_control_loop(cfg, link)
    yield cfg, link, loop
    link.stop()


def run(loop, seconds, pose_fn, plan_fn, faulted=False, until=None):
    """Tick for ``seconds``, or (with ``until``, a predicate on the tick) until it holds, at most ``seconds``."""
    out = []
    t_end = time.monotonic() + seconds
    while time.monotonic() < t_end:
        now = time.monotonic()
        out.append(loop.tick(now, pose_fn(), plan_fn(), faulted=faulted))
        if until is not None and until(out[-1]):
            break
        time.sleep(loop.settings.rate_hz ** -1)
    return out


def test_tracks_the_plan_direction(rig):
    cfg, link, loop = rig
    target = np.array([0.5, 0.8, -0.1])
    plan = plan_looking(target)
    pan, tilt, clamped = world_direction_to_joints(target, IDENTITY, cfg.gimbal.mount, cfg.gimbal.limits)
    assert not clamped
    # the generator advances one period per tick: tick until it arrives (a loaded machine ticks less per second)
    ticks = run(loop, 60.0, pose, lambda: plan_looking(target, created=time.monotonic()),
                until=lambda t: t.mode == "tracking" and abs(t.setpoint[0] - pan) < 1e-3
                and abs(t.setpoint[1] - tilt) < 1e-3 and abs(t.setpoint[2]) < 1e-6 and abs(t.setpoint[3]) < 1e-6)
    assert ticks[-1].mode == "tracking"
    sp = ticks[-1].setpoint
    assert abs(sp[0] - pan) < 1e-3 and abs(sp[1] - tilt) < 1e-3
    assert wait_until(lambda: abs(link.state.pan - pan) < math.radians(0.5), 3)
    assert plan.directions.shape == (5, 3)


def test_stale_pose_and_stale_plan_stop_the_gimbal(rig):
    _, _, loop = rig
    run(loop, 0.3, pose, lambda: plan_looking([0.0, 1.0, 0.0]))  # start moving towards +90° pan
    old_pose = pose(rx_time=time.monotonic() - 10.0)
    ticks = run(loop, 1.5, lambda: old_pose, lambda: plan_looking([0.0, 1.0, 0.0]))
    assert {t.mode for t in ticks} == {"holding"}
    assert abs(ticks[-1].setpoint[2]) < 1e-9 and abs(ticks[-1].setpoint[3]) < 1e-9
    # A fresh pose with a plan older than plan_timeout holds as well.
    old_plan = plan_looking([1.0, -1.0, 0.0], created=time.monotonic() - 2 * loop.settings.plan_timeout)
    ticks = run(loop, 0.5, pose, lambda: old_plan)
    assert {t.mode for t in ticks} == {"holding"}


def test_faulted_gimbal_gets_no_setpoints(rig):
    _, link, loop = rig
    before = link.counters()["setpoints_sent"]
    ticks = run(loop, 0.3, pose, lambda: plan_looking([0.0, 1.0, 0.0]), faulted=True)
    assert {t.mode for t in ticks} == {"fault"} and all(t.setpoint is None for t in ticks)
    assert link.counters()["setpoints_sent"] == before
