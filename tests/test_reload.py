"""SIGHUP reload: which settings apply live, and the planner process and the control loop agreeing after it."""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np
import pytest
from gimbal_fakes import IDENTITY, FakeClock, FakeGimbal, pose_at
from support import REPO

from pivotd.config import load_config
from pivotd.daemon.reload import apply_reload, plan_reload
from pivotd.daemon.wiring import build_control_loop
from pivotd.daemon.worker import PlannerWorker, RequestError, WorkerError
from pivotd.gimbal.kinematics import JointLimits, Mount, camera_position

NEW_MOUNT = Mount.from_xyz_rpy([-0.1, 0.05, 0.4], [0.0, 0.0, math.radians(20.0)])


@pytest.fixture(scope="module")
def cfg():
    return load_config(REPO / "config" / "demo.yaml")


def test_unchanged_config_changes_nothing(cfg):
    plan = plan_reload(cfg, load_config(REPO / "config" / "demo.yaml"))
    assert plan.applied == () and plan.needs_restart == () and plan.config == cfg


def test_live_settings_apply_and_restart_only_settings_keep_their_running_values(cfg):
    loaded = replace(
        cfg,
        name="other",
        zenoh=replace(cfg.zenoh, listen=("tcp/127.0.0.1:9999",)),
        pivot=replace(cfg.pivot, lam=0.1),
        planner=replace(cfg.planner, replan_hz=2.0),
        gimbal=replace(cfg.gimbal, mount=NEW_MOUNT, port="socket://127.0.0.1:1", watchdog_ms=500,
                       limits=JointLimits(-1.0, 1.0, -0.5, 0.5), park_tilt=0.1),
        control=replace(cfg.control, rate_hz=200.0),
    )
    plan = plan_reload(cfg, loaded)
    assert set(plan.applied) == {"pivot.lam", "planner.replan_hz", "gimbal.mount", "gimbal.park_tilt"}
    assert set(plan.needs_restart) == {"name", "topics.status_key", "zenoh.listen", "gimbal.port",
                                       "gimbal.watchdog_ms", "gimbal.limits", "control.rate_hz"}
    eff = plan.config
    assert eff.pivot.lam == 0.1 and eff.planner.replan_hz == 2.0
    assert eff.gimbal.mount == NEW_MOUNT and eff.gimbal.park_tilt == 0.1
    assert (eff.name, eff.zenoh, eff.topics, eff.control) == (cfg.name, cfg.zenoh, cfg.topics, cfg.control)
    assert (eff.gimbal.port, eff.gimbal.limits, eff.gimbal.watchdog_ms) == (
        cfg.gimbal.port, cfg.gimbal.limits, cfg.gimbal.watchdog_ms)


@pytest.fixture(scope="module")
def worker(cfg):
    w = PlannerWorker(cfg)
    yield w
    w.close()


@pytest.mark.slow
def test_reloaded_mount_reaches_the_planner_and_the_control_loop(cfg, worker):
    clock = FakeClock()
    gimbal = FakeGimbal(clock)
    control = build_control_loop(cfg, gimbal, clock=clock)
    position = np.array([2.0, 0.0, 0.7])
    yaw90 = np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    before = worker.replan(position, yaw90, None, timeout=60.0)
    np.testing.assert_allclose(before.positions[0], camera_position(position, yaw90, cfg.gimbal.mount), atol=1e-9)

    reload = plan_reload(cfg, replace(cfg, gimbal=replace(cfg.gimbal, mount=NEW_MOUNT)))
    apply_reload(reload, worker, control)

    after = worker.replan(position, yaw90, None, timeout=60.0)
    np.testing.assert_allclose(after.positions[0], camera_position(position, yaw90, NEW_MOUNT), atol=1e-9)
    assert control.mount == NEW_MOUNT
    # The control loop locates itself on the new plan with the same camera centre the planner used.
    pose_t = clock.t
    tick = control.tick(clock.t, replace(pose_at(pose_t, yaw90), position=position), replace(after, created=clock.t))
    assert tick.setpoint is not None
    assert after.locate(camera_position(position, yaw90, control.mount))[0] == pytest.approx(0.0, abs=1e-9)
    apply_reload(plan_reload(reload.config, cfg), worker, control)  # back to the module's config
    assert control.mount == cfg.gimbal.mount


@pytest.mark.slow
def test_refused_reload_changes_neither_side(cfg, worker, tmp_path):
    control = build_control_loop(cfg, FakeGimbal(FakeClock()))
    bad_map = tmp_path / "bad.txt"
    bad_map.write_text("1 2\n")
    loaded = replace(cfg, map=replace(cfg.map, file=bad_map), gimbal=replace(cfg.gimbal, mount=NEW_MOUNT))
    with pytest.raises(RequestError, match=r"bad\.txt"):
        apply_reload(plan_reload(cfg, loaded), worker, control)
    assert control.mount == cfg.gimbal.mount
    plan = worker.replan(np.array([2.0, 0.0, 0.7]), IDENTITY, None, timeout=60.0)
    np.testing.assert_allclose(plan.positions[0], camera_position(np.array([2.0, 0.0, 0.7]), IDENTITY,
                                                                  cfg.gimbal.mount), atol=1e-9)


@pytest.mark.slow
def test_a_late_reply_is_never_taken_for_the_next_request(worker):
    """A request that gave up waiting leaves its reply in the pipe; the next request must skip it."""
    stale_before = worker.stale_replies
    with pytest.raises(WorkerError, match="did not answer 'replan'"):
        worker.replan(np.array([2.0, 0.0, 0.7]), IDENTITY, None, timeout=0.0)
    info = worker.reload(worker_config := load_config(REPO / "config" / "demo.yaml"))  # answered with "map"
    assert info.landmarks > 0 and worker_config.map.file is not None
    assert worker.stale_replies == stale_before + 1
    plan = worker.replan(np.array([2.0, 0.0, 0.7]), IDENTITY, None, timeout=60.0)
    assert plan.directions.shape[1] == 3


def test_the_gimbal_backend_and_its_connection_need_a_restart(cfg):
    from pivotd.config.settings import MavlinkConfig

    loaded = replace(cfg, gimbal=replace(cfg.gimbal, backend="mavlink", port="udpout:127.0.0.1:14550",
                                         mavlink=MavlinkConfig(system_id=7), park_tilt=0.2))
    plan = plan_reload(cfg, loaded)
    assert set(plan.needs_restart) == {"gimbal.backend", "gimbal.port", "gimbal.mavlink"}
    assert plan.applied == ("gimbal.park_tilt",)
    assert (plan.config.gimbal.backend, plan.config.gimbal.mavlink) == (cfg.gimbal.backend, cfg.gimbal.mavlink)
