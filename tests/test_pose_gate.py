"""Plausibility of inputs: the pose gate (speed, jump, turn rate) and path progress along the accepted trajectory."""

from __future__ import annotations

import math

import numpy as np
import pytest

from pivotd.bus.messages import PoseSample
from pivotd.config.settings import PoseGateConfig
from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner
from pivotd.daemon.pose_gate import PoseGate, PoseVerdict, turn_angle
from pivotd.gimbal.kinematics import JointLimits, Mount
from pivotd.maps.store import MapStore

LIMITS = PoseGateConfig(max_speed=3.0, max_jump=1.0, max_turn_rate=math.radians(180.0))
TIMEOUT = 0.5
IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def pose(t: float, x: float, y: float = 0.0, yaw: float = 0.0) -> PoseSample:
    quat = np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])
    return PoseSample(stamp=t, frame_id="map", position=np.array([x, y, 0.0]), quat=quat, rx_time=t)


def test_a_robot_driving_at_its_speed_is_accepted_throughout():
    gate = PoseGate()
    for k in range(500):  # 10 s at 50 Hz, 2.5 m/s, turning 90°/s
        t = 0.02 * k
        assert gate.check(pose(t, 2.5 * t, yaw=math.radians(90.0) * t), LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED
    assert gate.counters() == {"accepted": 500, "rejected": {"jump": 0, "speed": 0, "turn": 0}}


@pytest.mark.parametrize(("candidate", "verdict"), [
    (pose(1.02, 15.0), PoseVerdict.JUMP),              # teleport
    (pose(1.02, 0.9), PoseVerdict.SPEED),             # under the jump limit, 0.9 m in 20 ms (+ slack): 7.5 m/s
    (pose(1.02, 0.0, yaw=math.pi), PoseVerdict.TURN),  # half a turn in 20 ms
    (pose(1.02, 0.3, yaw=0.3), PoseVerdict.ACCEPTED),
])
def test_each_limit_refuses_what_a_robot_cannot_do(candidate, verdict):
    gate = PoseGate()
    assert gate.check(pose(1.0, 0.0), LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED
    assert gate.check(candidate, LIMITS, TIMEOUT) is verdict


def test_a_second_publisher_cannot_drag_the_pose_away():
    """The robot at x ≈ 5 m and a forger claiming x = 27 m, both at 50 Hz, interleaved: only the robot's poses
    pass, however long the forger keeps going."""
    gate = PoseGate()
    accepted = []
    for k in range(1000):
        t = 0.01 * k
        sample = pose(t, 5.0 + 0.1 * t) if k % 2 == 0 else pose(t, 27.0 - 0.01 * k, yaw=math.pi)
        if gate.check(sample, LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED:
            accepted.append(sample.position[0])
    assert len(accepted) == 500 and max(accepted) < 6.1
    assert gate.counters()["rejected"]["jump"] == 500


def test_refused_poses_do_not_move_the_anchor_and_a_silent_anchor_is_replaced():
    gate = PoseGate()
    gate.check(pose(0.0, 0.0), LIMITS, TIMEOUT)
    for k in range(1, 20):  # 0.38 s of a relocalised robot 4 m away: refused, the anchor stays at 0
        assert gate.check(pose(0.02 * k, 4.0 + 0.01 * k), LIMITS, TIMEOUT) is PoseVerdict.JUMP
    assert gate.check(pose(0.40, 0.5), LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED  # near the anchor: fine
    # no pose accepted for longer than the timeout: the next one starts afresh wherever it is
    assert gate.check(pose(0.40 + TIMEOUT + 0.01, 40.0), LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED
    assert gate.check(pose(0.40 + TIMEOUT + 0.03, 40.02), LIMITS, TIMEOUT) is PoseVerdict.ACCEPTED


def test_turn_angle_is_the_rotation_between_quaternions():
    q = np.array([0.0, 0.0, math.sin(0.25), math.cos(0.25)])  # 0.5 rad about z
    assert turn_angle(IDENTITY, q) == pytest.approx(0.5)
    assert turn_angle(IDENTITY, -q) == pytest.approx(0.5)  # q and -q are the same rotation
    assert turn_angle(q, q) == pytest.approx(0.0, abs=1e-7)


# ------------------------------------------------------------------------------------------ path progress
def planner(max_path_offset: float = 3.0) -> RecedingHorizonPlanner:
    settings = PlannerSettings(fov=math.radians(60.0), spacing=0.5, horizon=5, max_path_offset=max_path_offset)
    return RecedingHorizonPlanner(settings, Mount(), JointLimits())


def progress_after(pl: RecedingHorizonPlanner, *positions) -> list[float]:
    snap = MapStore().snapshot()
    out = []
    for p in positions:
        pl.replan(snap, np.asarray(p, float), IDENTITY, None)
        out.append(pl.progress)
    return out


def test_a_pose_far_from_the_path_does_not_push_progress_ahead():
    """The reported attack: the robot stands at 5 m on a 40 m path; poses next to the path's 27 m point but
    10 m off it, repeated, used to move the progress to 27 m, where it stayed."""
    pl = planner()
    pl.set_path(np.array([[0.0, 0.0, 0.0], [40.0, 0.0, 0.0]]), None, version=1)
    got = progress_after(pl, [5.0, 0, 0], *([[27.0, 10.0, 0.0]] * 20), [5.1, 0, 0])
    assert got[0] == pytest.approx(5.0)
    assert max(got) == pytest.approx(5.1)


def test_progress_advances_by_at_most_the_displacement_plus_the_offset():
    """A hairpin: from (3.5, 0) a step of 1 m across to the return leg at (3.5, 1) finds the point 2 m further
    along the path; progress may advance only 1 m + max_path_offset."""
    hairpin = np.array([[0.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 1.0, 0.0], [0.0, 1.0, 0.0]])
    pl = planner(max_path_offset=0.2)
    pl.set_path(hairpin, None, version=1)
    got = progress_after(pl, [3.5, 0, 0], [3.5, 1.0, 0])
    assert got == pytest.approx([3.5, 3.5 + 1.0 + 0.2])
    free = planner(max_path_offset=10.0)
    free.set_path(hairpin, None, version=1)
    assert progress_after(free, [3.5, 0, 0], [3.5, 1.0, 0]) == pytest.approx([3.5, 5.5])


def test_a_robot_following_the_path_makes_progress_normally():
    pl = planner()
    pl.set_path(np.array([[0.0, 0.0, 0.0], [10.0, 0.0, 0.0], [10.0, 10.0, 0.0]]), None, version=1)
    xs = [[x, 0.3, 0.0] for x in np.arange(0.0, 10.0, 0.4)] + [[10.2, y, 0.0] for y in np.arange(0.4, 10.0, 0.4)]
    got = progress_after(pl, *xs)
    assert np.all(np.diff(got) >= 0) and got[-1] == pytest.approx(10.0 + 9.6, abs=1e-6)
