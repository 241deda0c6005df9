"""BusProbe over real Zenoh sessions on loopback: records pivotd's outputs and the accepted poses."""

import numpy as np
import pytest
from bus_support import session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.probe import BusProbe
from pivotd.bus.topics import BusTopics

# Not the defaults, so a probe that ignored its topics would see nothing.
TOPICS = BusTopics(domain_id=3, pose="/robot/odom", joint_states="/robot/joints", view_plan="/robot/view",
                   status_key="pivot/robot/status")


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, endpoint):
        yield a, b, endpoint


def test_probe_records_joint_states_poses_plans_and_status(sessions):
    a, b, _ = sessions
    bus = PivotBus(a, TOPICS, node_name="pivotd")
    talker = ros.RosNode(a, "talker", TOPICS.domain_id, node_id=77)
    probe = BusProbe(b, TOPICS)
    try:
        assert wait_for(bus.joint_state_publisher.matched)  # the probe is the only subscriber
        bus.publish_joint_state(1.0, 0.25, -0.5, 0.0, 0.0)
        assert wait_for(lambda: probe.joints)
        _, pan, tilt, key, att = probe.joints[-1]
        assert (pan, tilt) == (0.25, -0.5)
        assert key.startswith("3/robot/joints/sensor_msgs::msg::dds_::JointState_/RIHS01_")
        assert att is not None and len(att) == ros.ATTACHMENT_SIZE

        # pivotd's own subscription matches the pose topic too, so repeat until the probe has one.
        odom = talker.publisher(TOPICS.pose, m.ODOMETRY)
        sent = []
        assert wait_for(lambda: sent.append(odom.put(m.encode_odometry(0, "map", "b", [9, 9, 9], [0, 0, 0, 1])))
                        or probe.poses)
        assert wait_for(lambda: len(probe.poses) == len(sent))
        # What pivotd would drop is skipped; the good pose comes after them from the same publisher.
        odom.put(b"\x00\x01\x00\x00garbage")
        odom.put(m.encode_odometry(0, "map", "b", [np.nan, 0, 0], [0, 0, 0, 1]))
        odom.put(m.encode_odometry(0, "elsewhere", "b", [5, 5, 5], [0, 0, 0, 1]))
        odom.put(m.encode_odometry(0, "map", "b", [1, 2, 3], [0, 0, 0, 2]))
        assert wait_for(lambda: len(probe.poses) == len(sent) + 1)
        assert {tuple(p[1]) for p in probe.poses} == {(9.0, 9.0, 9.0), (1.0, 2.0, 3.0)}
        _, position, quat = probe.poses[-1]
        np.testing.assert_allclose(position, [1, 2, 3])
        np.testing.assert_allclose(quat, [0, 0, 0, 1])

        positions = np.array([[0.0, 0, 1], [1.0, 0, 1]])
        assert wait_for(lambda: bus.publish_view_plan(2.0, positions, np.array([[1.0, 0, 0], [0, 1.0, 0]]))
                        or probe.plans)
        np.testing.assert_allclose(probe.plans[-1].positions, positions)

        assert wait_for(lambda: bus.publish_status({"state": "tracking", "n": 1}) or probe.status)
        assert probe.status["state"] == "tracking" and "bus" in probe.status
        assert probe.query_status()["n"] == 1

        obs = probe.observations()
        assert obs.joints[-1][1:] == (0.25, -0.5) and len(obs.joints[-1]) == 3
        assert len(obs.poses) == len(probe.poses) and obs.status == probe.status
    finally:
        probe.close()
        talker.close()
        bus.close()
    # The probe did not own the session: it stays usable.
    assert b.info.zid() is not None and not b.is_closed()


def test_connected_probe_owns_its_session(sessions):
    a, _, endpoint = sessions
    with PivotBus(a, TOPICS) as bus, BusProbe.connect(endpoint, TOPICS) as probe:
        assert wait_for(lambda: bus.publish_status({"state": "waiting"}) or probe.status)
        session = probe.session
    assert session.is_closed()
