"""Absurd-but-finite bus input: far paths and poses, extreme quaternions and stamps (real Zenoh on loopback)."""

import queue
import time

import numpy as np
import pytest
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import BusTopics

MAX_SEC = 2**31 - 1


@pytest.mark.parametrize(("quat", "expected"), [
    ([0, 0, 0, 1e300], [0, 0, 0, 1]),  # formerly normalised to all-zero (the norm overflowed)
    ([1e-300, 0, 0, 0], [1, 0, 0, 0]),  # the norm underflowed
    ([3e307, 4e307, 0, 0], [0.6, 0.8, 0, 0]),
    ([-1e-320, 0, 0, 1e-320], [-(0.5**0.5), 0, 0, 0.5**0.5]),
])
def test_extreme_quaternions_normalise_safely(quat, expected):
    pose = m.decode_pose(m.encode_odometry(1.0, "map", "b", [0, 0, 0], quat), m.ODOMETRY, "/odom")
    np.testing.assert_allclose(pose.quat, expected, atol=1e-12)
    path = m.decode_path(m.encode_path(1.0, "map", [[0, 0, 0], [1, 0, 0]], [quat, [0, 0, 0, 0]]), "/plan")
    np.testing.assert_allclose(path.quats, [expected, [0, 0, 0, 1]], atol=1e-12)


def test_zero_quaternion_is_still_refused():
    with pytest.raises(m.MessageError) as info:
        m.decode_pose(m.encode_odometry(1.0, "map", "b", [0, 0, 0], [0, 0, 0, 0]), m.ODOMETRY, "/odom")
    assert info.value.reason == "zero_quaternion"


@pytest.mark.parametrize("far", [1e200, -1.0000001e7, 1e308])
def test_far_path_and_pose_are_out_of_range(far):
    with pytest.raises(m.MessageError) as info:
        m.decode_path(m.encode_path(0.0, "map", [[0, 0, 0], [0, far, 0]]), "/plan")
    assert info.value.reason == "out_of_range" and str(info.value).startswith("/plan: path pose 1 has a position")
    with pytest.raises(m.MessageError) as info:
        m.decode_pose(m.encode_odometry(0.0, "map", "b", [far, 0, 0], [0, 0, 0, 1]), m.ODOMETRY, "/odom")
    assert info.value.reason == "out_of_range"
    ok = m.decode_path(m.encode_path(0.0, "map", [[0, 0, 0], [0, 1e7, 0]]), "/plan")  # at the bound: accepted
    assert ok.positions[1, 1] == 1e7


def test_stamps_at_the_end_of_int32_seconds_encode():
    # A pose stamped sec = 2³¹−1, nanosec = 999999999 reads back as 2³¹ s (float): formerly struct.error.
    pose = m.decode_pose(m.encode_odometry(0.0, "map", "b", [0, 0, 0], [0, 0, 0, 1]), m.ODOMETRY, "/odom")
    stamp = MAX_SEC + 0.999999999
    assert stamp == float(2**31)
    plan = m.decode_path(m.encode_view_plan(stamp, "map", np.zeros((1, 3)), np.array([[1.0, 0, 0]])), "/v")
    assert plan.stamp == pytest.approx(MAX_SEC + 0.999999999)
    assert pose.stamp == 0.0
    assert m.seconds_to_stamp(1e300).sec == MAX_SEC and m.seconds_to_stamp(-5).sec == 0


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, _):
        yield a, b


def test_far_path_is_dropped_and_counted_and_the_bus_keeps_accepting(sessions):
    events = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(), on_pose=lambda s: events.put(("pose", s)),
                   on_path=lambda p: events.put(("path", p)), on_cloud=lambda layer, c: events.put((layer, c)))
    remote = ros.RosNode(sessions[1], "remote", node_id=int(time.monotonic_ns() % 1000))
    got = queue.Queue()
    sub = sessions[1].declare_subscriber("0/pivot/view_plan/nav_msgs::msg::dds_::Path_/*",
                                         lambda s: got.put(s.payload.to_bytes()))
    try:
        plan = remote.publisher("/plan", m.PATH)
        odom = remote.publisher("/odom", m.ODOMETRY)
        assert wait_for(plan.matched) and wait_for(odom.matched)
        plan.put(m.encode_path(0.0, "map", [[0, 0, 0], [1e200, 0, 0]]))
        # paths are latest-wins: the next one would replace this one if it came before it was decoded
        assert wait_for(lambda: bus.counters()["/plan"].get("dropped_out_of_range") == 1)
        odom.put(m.encode_odometry(0.0, "map", "b", [0, 0, 0], [0, 0, 0, 1e300]))
        plan.put(m.encode_path(0.0, "map", [[0, 0, 0], [4, 0, 0]]))
        first, second = drain(events, 2)
        kinds = {first[0]: first[1], second[0]: second[1]}
        np.testing.assert_allclose(kinds["path"].positions, [[0, 0, 0], [4, 0, 0]])
        np.testing.assert_allclose(kinds["pose"].quat, [0, 0, 0, 1])
        assert bus.counters()["/plan"]["accepted"] == 1
        assert wait_for(bus.view_plan_publisher.matched)
        bus.publish_view_plan(MAX_SEC + 0.999999999, np.zeros((1, 3)), np.array([[1.0, 0, 0]]))
        assert m.decode_path(drain(got, 1)[0], "/pivot/view_plan").stamp == pytest.approx(2.0**31)
    finally:
        sub.undeclare()
        remote.close()
        bus.close()
