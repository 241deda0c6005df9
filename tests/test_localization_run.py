"""Whole runs: reproducible from the seed, and every policy's commanded stream inside the motion limits."""

import math
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pivotd.localization.benchmark import BenchSettings, run_scene, truncate_scene
from pivotd.localization.camera import CameraModel
from pivotd.localization.policies import PolicyName, make_policy
from pivotd.localization.scenes import build_scene
from pivotd.localization.simulate import run_policy
from pivotd.localization.stack import joints_to_world_direction, load_config, setpoint_dynamics
from pivotd.localization.world import World

pytestmark = pytest.mark.slow  # seconds of CPU in all: `make test`, not `make test-fast`

REPO = Path(__file__).resolve().parent.parent
DEMO = REPO / "config" / "demo.yaml"


def _settings(scene: str, policies: tuple[PolicyName, ...], seed: int) -> BenchSettings:
    return BenchSettings(scenes=(scene,), policies=policies, seeds=(seed,), camera=CameraModel(),
                         cfg=load_config(DEMO), fif_dir=REPO / "tests" / "data" / "fif", max_duration=4.0)


def test_a_run_is_reproducible_from_its_seed():
    st = _settings("corridor", (PolicyName.FORWARD, PolicyName.PIVOT, PolicyName.RANDOM), 5)
    a, b = run_scene(st, "corridor"), run_scene(st, "corridor")
    for p in ("forward", "pivot", "random"):
        ra, rb = a.runs[p][0], b.runs[p][0]
        assert (ra.success, ra.median_t, ra.median_r, ra.no_pose, ra.longest_failure) == (
            rb.success, rb.median_t, rb.median_r, rb.no_pose, rb.longest_failure)
        np.testing.assert_array_equal(a.errors[p][0], b.errors[p][0])
        np.testing.assert_array_equal(a.errors[p][1], b.errors[p][1])
    np.testing.assert_array_equal(a.centres, b.centres)
    c = run_scene(replace(st, seeds=(6,)), "corridor")
    assert not np.array_equal(a.errors["forward"][0], c.errors["forward"][0])  # another seed, another scene


def test_host_stalls_do_not_change_a_run(rooms_world):
    """The control loop runs on the simulated clock: a policy that holds the host up for longer than the
    loop's stall threshold (as a loaded machine does) commands exactly the same stream."""
    import time

    from pivotd.daemon.control import ControlSettings

    class Stalling:
        def __init__(self, inner, stalls: int) -> None:
            self.inner, self.stalls = inner, stalls

        def __getattr__(self, name):
            return getattr(self.inner, name)

        def update(self, *args):
            if self.stalls > 0:
                self.stalls -= 1
                time.sleep(1.5 * ControlSettings().stall_s)
            return self.inner.update(*args)

    calm = run_policy(rooms_world, make_policy(PolicyName.PIVOT, rooms_world, seed=2))
    stalled = run_policy(rooms_world, Stalling(make_policy(PolicyName.PIVOT, rooms_world, seed=2), stalls=3))
    np.testing.assert_array_equal(calm.setpoints, stalled.setpoints)
    np.testing.assert_array_equal(calm.directions, stalled.directions)


def test_procedural_scenes_depend_on_the_seed_only():
    for name in ("rooms", "corridor", "warehouse"):
        a, b, c = build_scene(name, 1, REPO), build_scene(name, 1, REPO), build_scene(name, 2, REPO)
        np.testing.assert_array_equal(a.landmarks, b.landmarks)
        np.testing.assert_array_equal(a.route, b.route)
        assert a.landmarks.shape != c.landmarks.shape or not np.array_equal(a.landmarks, c.landmarks)


@pytest.fixture(scope="module")
def rooms_world() -> World:
    scene = truncate_scene(build_scene("rooms", 3, REPO), 6.0)
    return World(load_config(DEMO), scene, CameraModel())


@pytest.mark.parametrize("policy", [p for p in PolicyName if p != PolicyName.TELEPORT])
def test_every_limited_policy_obeys_joint_and_motion_limits(rooms_world, policy):
    cfg = rooms_world.cfg
    pol = make_policy(policy, rooms_world, seed=4)
    assert pol.limited
    traj = run_policy(rooms_world, pol)
    sp = traj.setpoints
    assert sp.shape[0] == int(rooms_world.scene.duration / traj.dt + 1e-9) + 1 > 500
    rep = setpoint_dynamics(sp[:, :2], traj.dt, cfg.motion.pan, cfg.motion.tilt, rates=sp[:, 2:], resolution=0.0)
    assert rep.worst_ratio <= 1.0 + 1e-6, (rep.velocity_ratio, rep.acceleration_ratio, rep.jerk_ratio)
    lim = cfg.gimbal.limits
    assert lim.pan_min - 1e-9 <= sp[:, 0].min() and sp[:, 0].max() <= lim.pan_max + 1e-9
    assert lim.tilt_min - 1e-9 <= sp[:, 1].min() and sp[:, 1].max() <= lim.tilt_max + 1e-9
    if policy != PolicyName.FORWARD:
        assert np.ptp(sp[:, 0]) > np.radians(5.0)  # the policy does steer the gimbal
    else:
        assert np.abs(sp[:, :2]).max() < 1e-9


def test_only_the_teleporting_oracle_ignores_the_limits(rooms_world):
    unlimited = [p for p in PolicyName if not make_policy(p, rooms_world, 0).limited]
    assert unlimited == [PolicyName.TELEPORT]
    traj = run_policy(rooms_world, make_policy(PolicyName.TELEPORT, rooms_world, 0))
    assert traj.setpoints.shape[0] == 0  # no commanded stream: it teleports to its best view every frame
    assert traj.directions.shape == (traj.times.shape[0], 3)


def test_the_achievable_oracle_sees_at_least_what_the_limited_policies_see(rooms_world):
    """The oracle's frames are its executed setpoints; it sees about as much as the teleport and more than every
    policy bound by the same limits (in-image landmarks per frame, on average)."""
    from pivotd.localization.camera import camera_rotation, in_view_counts

    def mean_in_view(traj) -> float:
        R = camera_rotation(traj.directions)
        return float(np.mean([in_view_counts(rooms_world.camera, R[i:i + 1], c, rooms_world.scene.landmarks[
            rooms_world.sight(i, c)])[0] for i, c in enumerate(traj.centres)]))

    oracle = run_policy(rooms_world, make_policy(PolicyName.ORACLE, rooms_world, 0))
    assert oracle.directions.shape == (oracle.times.shape[0], 3)
    frame_ticks = np.round(oracle.times / oracle.dt).astype(int)
    sp = oracle.setpoints[frame_ticks]
    expect = np.array([joints_to_world_direction(p, t, q, rooms_world.mount) for (p, t), q in
                       zip(sp[:, :2], rooms_world.body_poses(oracle.times)[1], strict=True)])
    np.testing.assert_allclose(oracle.directions, expect, atol=1e-9)
    seen = {p: mean_in_view(run_policy(rooms_world, make_policy(p, rooms_world, 0)))
            for p in (PolicyName.FORWARD, PolicyName.PIVOT, PolicyName.TELEPORT)}
    ours = mean_in_view(oracle)
    assert ours > seen[PolicyName.FORWARD] and ours >= 0.95 * seen[PolicyName.PIVOT]
    assert ours <= seen[PolicyName.TELEPORT] * 1.02


def test_event_driven_pivot_replans_once_per_waypoint_and_stays_within_the_limits(rooms_world):
    cfg = replace(rooms_world.cfg, planner=replace(rooms_world.cfg.planner, replan_on_waypoint=True))
    world = World(cfg, rooms_world.scene, rooms_world.camera)
    ticks = make_policy(PolicyName.PIVOT, rooms_world, 0)
    events = make_policy(PolicyName.PIVOT, world, 0)
    t_ticks, t_events = run_policy(rooms_world, ticks), run_policy(world, events)
    sc = rooms_world.scene
    length = float(np.sum(np.linalg.norm(np.diff(sc.route, axis=0), axis=1)))
    spacing = cfg.planner.waypoint_spacing
    # 5 Hz: one replan per tick; on waypoints: one per spacing moved (or per max interval), plus the first
    assert t_ticks.decisions == int(sc.duration * cfg.planner.replan_hz + 1e-9) + 1
    most = math.ceil(length / spacing) + math.ceil(sc.duration / cfg.planner.replan_max_interval) + 1
    assert t_events.decisions <= most
    assert t_events.decisions < 0.5 * t_ticks.decisions
    sp = t_events.setpoints
    rep = setpoint_dynamics(sp[:, :2], t_events.dt, cfg.motion.pan, cfg.motion.tilt, rates=sp[:, 2:], resolution=0.0)
    assert rep.worst_ratio <= 1.0 + 1e-6
    assert np.ptp(sp[:, 0]) > np.radians(5.0)
