"""PivotBus over real Zenoh sessions on loopback: inputs, drops, outputs, liveliness, status."""

import json
import queue
import time

import numpy as np
import pytest
import zenoh
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import BusTopics
from pivotd.errors import ConfigError
from pivotd.geometry import quat_to_matrix

JOINT_HASH_PREFIX = "RIHS01_a13ee3"


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, _):
        yield a, b


@pytest.fixture
def remote(sessions):
    node = ros.RosNode(sessions[1], "remote", node_id=int(time.monotonic_ns() % 1000))
    yield node
    node.close()


def make_bus(session, **kw):
    events = queue.Queue()
    topics = BusTopics(**{k: v for k, v in kw.items() if k in BusTopics.__dataclass_fields__})
    bus = PivotBus(session, topics, on_pose=lambda s: events.put(("pose", s)),
                   on_path=kw.get("on_path", lambda p: events.put(("path", p))),
                   on_cloud=lambda layer, c: events.put((layer, c)))
    return bus, events


def connected_publisher(node, topic, msgtype):
    pub = node.publisher(topic, msgtype)
    assert wait_for(pub.matched), f"no subscriber matched {topic}"
    return pub


def test_pose_path_and_clouds_are_delivered(sessions, remote):
    bus, events = make_bus(sessions[0])
    try:
        odom = connected_publisher(remote, "/odom", m.ODOMETRY)
        odom.put(m.encode_odometry(100.5, "map", "base_link", [1, 2, 0.5], [0, 0, 0, 1]))
        kind, pose = drain(events, 1)[0]
        assert kind == "pose" and isinstance(pose, m.PoseSample)
        np.testing.assert_allclose(pose.position, [1, 2, 0.5])
        assert pose.stamp == pytest.approx(100.5) and pose.rx_time <= time.monotonic()

        plan = connected_publisher(remote, "/plan", m.PATH)
        plan.put(m.encode_path(1.0, "map", [[0, 0, 0], [1, 0, 0]]))
        kind, path = drain(events, 1)[0]
        assert kind == "path" and path.positions.shape == (2, 3)

        for layer, topic in (("landmarks", "/pivot/landmarks"), ("targets", "/pivot/targets")):
            pub = connected_publisher(remote, topic, m.POINT_CLOUD2)
            pub.put(m.encode_cloud(2.0, "map", np.eye(3), np.array([1.0, 2.0, 3.0])))
            got_layer, cloud = drain(events, 1)[0]
            assert got_layer == layer
            np.testing.assert_allclose(cloud.points, np.eye(3))
            np.testing.assert_allclose(cloud.weights, [1, 2, 3])
        c = bus.counters()
        assert c["/odom"] == {"received": 1, "accepted": 1}
        assert c["/pivot/targets"] == {"received": 1, "accepted": 1}
    finally:
        bus.close()


def test_pose_with_covariance_stamped_topic_is_delivered(sessions, remote):
    bus, events = make_bus(sessions[0], pose="/amcl_pose", pose_type=m.POSE_WITH_COVARIANCE_STAMPED)
    try:
        amcl = connected_publisher(remote, "/amcl_pose", m.POSE_WITH_COVARIANCE_STAMPED)
        amcl.put(m.encode_pose_with_covariance_stamped(5.0, "map", [4, 5, 0], [0, 0, 0, 1], np.eye(6).reshape(36)))
        kind, pose = drain(events, 1)[0]
        assert kind == "pose"
        np.testing.assert_allclose(pose.position, [4, 5, 0])
        assert bus.counters()["/amcl_pose"] == {"received": 1, "accepted": 1}
    finally:
        bus.close()


def settled_count(counters: dict[str, int]) -> int:
    """Messages of one topic that are through: accepted or dropped for any reason."""
    return counters["accepted"] + sum(v for k, v in counters.items() if k.startswith("dropped_"))


def test_bad_input_is_dropped_and_counted_never_raised(sessions, remote):
    def failing_path(p):
        raise RuntimeError("daemon bug")

    bus, events = make_bus(sessions[0], max_cloud_points=5, on_path=failing_path)

    def put_one(pub, payload):  # poses are latest-wins: let each be decoded before the next one
        n = bus.counters()["/odom"]["received"] + 1
        pub.put(payload)
        assert wait_for(lambda: settled_count(bus.counters()["/odom"]) == n)

    try:
        odom = connected_publisher(remote, "/odom", m.ODOMETRY)
        put_one(odom, m.encode_odometry(0, "map", "b", [np.nan, 0, 0], [0, 0, 0, 1]))
        put_one(odom, m.encode_odometry(0, "map", "b", [0, 0, 0], [0, 0, 0, 0]))
        put_one(odom, m.encode_odometry(0, "odom", "b", [0, 0, 0], [0, 0, 0, 1]))
        put_one(odom, b"\x00\x01\x00\x00garbage")
        wrong = connected_publisher(remote, "/odom", m.POSE_STAMPED)  # right topic, wrong type
        put_one(wrong, m.encode_pose_stamped(0, "map", [0, 0, 0], [0, 0, 0, 1]))
        cloud = connected_publisher(remote, "/pivot/landmarks", m.POINT_CLOUD2)
        cloud.put(m.encode_cloud(0, "map", np.zeros((6, 3))))
        plan = connected_publisher(remote, "/plan", m.PATH)
        plan.put(m.encode_path(0, "map", [[0, 0, 0]]))
        odom.put(m.encode_odometry(0, "map", "b", [3, 2, 1], [0, 0, 0, 1]))  # still alive afterwards

        def settled():
            c = bus.counters()
            return settled_count(c["/odom"]) == 6 and settled_count(c["/pivot/landmarks"]) == 1 and (
                settled_count(c["/plan"]) == 1)

        assert wait_for(settled)
        c = bus.counters()
        assert c["/odom"] == {"received": 6, "accepted": 1, "dropped_nonfinite": 1, "dropped_zero_quaternion": 1,
                              "dropped_wrong_frame": 1, "dropped_malformed": 1, "dropped_wrong_type": 1}
        assert c["/pivot/landmarks"] == {"received": 1, "accepted": 0, "dropped_oversized": 1}
        assert c["/plan"] == {"received": 1, "accepted": 0, "dropped_callback_error": 1}
        got = drain(events, 1)
        assert got[0][0] == "pose"
        np.testing.assert_allclose(got[0][1].position, [3, 2, 1])
        assert events.empty()
    finally:
        bus.close()


def test_joint_state_reaches_a_wildcard_ros_subscriber(sessions):
    bus, _ = make_bus(sessions[0])
    got = queue.Queue()
    key = "0/pivot/joint_states/sensor_msgs::msg::dds_::JointState_/*"
    sub = sessions[1].declare_subscriber(key, lambda s: got.put((str(s.key_expr), s.payload.to_bytes(),
                                                                 s.attachment.to_bytes())))
    try:
        assert wait_for(bus.joint_state_publisher.matched)
        before = time.time_ns()
        bus.publish_joint_state(50.25, 0.5, -0.25, 0.1, -0.2)
        bus.publish_joint_state(50.5, 0.6, -0.25, 0.1, -0.2)
        samples = drain(got, 2)
        assert len(samples) == 2
        k, payload, att = samples[0]
        assert k == ros.topic_key(0, "/pivot/joint_states", m.JOINT_STATE)
        assert k.split("/")[-1].startswith(JOINT_HASH_PREFIX)
        js = ros.typestore().deserialize_cdr(payload, m.JOINT_STATE)
        assert list(js.name) == ["pan", "tilt"]
        np.testing.assert_allclose(js.position, [0.5, -0.25])
        np.testing.assert_allclose(js.velocity, [0.1, -0.2])
        assert js.header.stamp.sec == 50 and js.header.stamp.nanosec == 250_000_000
        a1, a2 = ros.Attachment.decode(att), ros.Attachment.decode(samples[1][2])
        assert (a1.sequence, a2.sequence) == (1, 2)
        assert a1.gid == a2.gid == bus.joint_state_publisher.gid
        assert before - 10**9 <= a1.source_time_ns <= a2.source_time_ns
    finally:
        sub.undeclare()
        bus.close()


def test_view_plan_is_a_path_of_camera_poses(sessions):
    bus, _ = make_bus(sessions[0])
    got = queue.Queue()
    sub = sessions[1].declare_subscriber("0/pivot/view_plan/nav_msgs::msg::dds_::Path_/*",
                                         lambda s: got.put(s.payload.to_bytes()))
    try:
        assert wait_for(bus.view_plan_publisher.matched)
        dirs = np.array([[1.0, 0, 0], [0, 1.0, 0], [0.6, 0, -0.8]])
        pos = np.array([[0, 0, 1.0], [1, 0, 1], [2, 0, 1]])
        bus.publish_view_plan(9.0, pos, dirs)
        path = m.decode_path(drain(got, 1)[0], "/pivot/view_plan")
        np.testing.assert_allclose(path.positions, pos)
        np.testing.assert_allclose(quat_to_matrix(path.quats)[:, :, 2], dirs, atol=1e-9)
    finally:
        sub.undeclare()
        bus.close()


def test_liveliness_tokens_visible_from_another_session_and_withdrawn(sessions):
    events = queue.Queue()
    # history: tokens declared before this subscription reached the other session are reported too
    lsub = sessions[1].liveliness().declare_subscriber("@ros2_lv/3/**",
                                                       lambda s: events.put((s.kind, str(s.key_expr))),
                                                       history=True)
    bus, _ = make_bus(sessions[0], domain_id=3)
    try:
        zid = str(sessions[0].info.zid())
        expected_pub = ros.entity_token_key(ros.PUBLISHER, 3, zid, 0, bus.joint_state_publisher.entity_id, "pivotd",
                                            "/pivot/joint_states", m.JOINT_STATE, ros.QoS(depth=10))
        node_key = f"@ros2_lv/3/{zid}/0/0/NN/%/%/pivotd"

        def tokens():
            return {str(r.ok.key_expr) for r in sessions[1].liveliness().get("@ros2_lv/3/**", timeout=2.0) if r.ok}

        seen: set[str] = set()

        def all_seven() -> bool:  # a loaded machine may answer a liveliness query before every token arrived
            seen.clear()
            seen.update(tokens())
            own = [k for k in seen if k.startswith(f"@ros2_lv/3/{zid}/")]
            return {node_key, expected_pub} <= seen and len(own) >= 7

        assert wait_for(all_seven)
        keys = set(seen)
        assert any(f"/MS/%/%/pivotd/%odom/nav_msgs::msg::dds_::Odometry_/{ros.type_hash(m.ODOMETRY)}/" in k
                   for k in keys)
        assert any("/MP/%/%/pivotd/%pivot%view_plan/nav_msgs::msg::dds_::Path_/RIHS01_" in k for k in keys)
        assert len([k for k in keys if k.startswith(f"@ros2_lv/3/{zid}/")]) == 7  # node + 4 subs + 2 pubs
        assert wait_for(lambda: any(k == expected_pub for kind, k in list(events.queue)
                                    if kind == zenoh.SampleKind.PUT))
    finally:
        bus.close()
    assert wait_for(lambda: any(k == node_key for kind, k in list(events.queue) if kind == zenoh.SampleKind.DELETE))
    assert wait_for(lambda: not any(k.startswith(f"@ros2_lv/3/{sessions[0].info.zid()}") for k in
                                    {str(r.ok.key_expr) for r in
                                     sessions[1].liveliness().get("@ros2_lv/3/**", timeout=2.0) if r.ok}))
    lsub.undeclare()


def test_status_publication_and_queryable(sessions):
    bus, _ = make_bus(sessions[0], status_key="pivot/robot7/status")
    got = queue.Queue()
    sub = sessions[1].declare_subscriber("pivot/robot7/status", lambda s: got.put(s.payload.to_bytes()))
    try:
        def query():
            return [json.loads(r.ok.payload.to_bytes()) for r in sessions[1].get("pivot/robot7/status", timeout=2.0)
                    if r.ok]

        assert wait_for(lambda: len(query()) == 1)
        first = query()[0]
        # before the first status: the daemon names itself (`pivotd status --all` and fleets key on the name)
        assert first["state"] == "starting" and first["name"] == bus.node_name and "/odom" in first["bus"]
        assert wait_for(lambda: bus.status_publisher.matching_status.matching)
        bus.publish_status({"state": "tracking", "pose_age_s": np.float64(0.25), "dir": np.array([1.0, 0, 0])})
        pushed = json.loads(drain(got, 1)[0])
        assert pushed["state"] == "tracking" and pushed["pose_age_s"] == 0.25 and pushed["dir"] == [1.0, 0, 0]
        assert pushed["bus"]["/odom"]["received"] == 0
        assert query() == [pushed]
        bus.publish_status({"state": "holding", "bus": "own"})
        assert query()[0] == {"state": "holding", "bus": "own"}
    finally:
        sub.undeclare()
        bus.close()


@pytest.mark.parametrize("kw", [{"pose_type": "std_msgs/msg/String"}, {"max_cloud_points": 0},
                                {"domain_id": -1}, {"pose": "bad topic"}, {"status_key": "/pivot/x/"},
                                {"status_key": "pivot/*/status"}])
def test_bad_topics_config(kw):
    with pytest.raises(ConfigError):
        BusTopics(**kw)


def test_humble_publishers_are_received_and_humble_mode_publishes_without_hash(sessions):
    humble = ros.RosNode(sessions[1], "humble_talker", node_id=900, humble=True)
    events = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(humble=True), on_pose=events.put)
    try:
        odom = connected_publisher(humble, "/odom", m.ODOMETRY)
        assert odom.key == "0/odom/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported"
        assert "/nav_msgs::msg::dds_::Odometry_/TypeHashNotSupported/" in odom.token_key
        odom.put(m.encode_odometry(0, "map", "b", [1, 1, 1], [0, 0, 0, 1]))
        np.testing.assert_allclose(drain(events, 1)[0].position, [1, 1, 1])
        assert bus.joint_state_publisher.key.endswith("/sensor_msgs::msg::dds_::JointState_/TypeHashNotSupported")
    finally:
        bus.close()
        humble.close()


def test_publishing_after_close_is_a_quiet_no_op(sessions):
    bus, _ = make_bus(sessions[0])
    bus.close()
    bus.publish_joint_state(0.0, 0.0, 0.0, 0.0, 0.0)
    bus.publish_view_plan(0.0, np.zeros((1, 3)), np.array([[1.0, 0, 0]]))
    bus.publish_status({"state": "stopped", "obj": object})
    bus.close()


def test_raw_hook_sees_accepted_inputs_and_outputs(sessions, remote):
    raw = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(), on_raw=lambda t, ty, b: raw.put((t, ty, b)))
    try:
        odom = connected_publisher(remote, "/odom", m.ODOMETRY)
        good = m.encode_odometry(0, "map", "b", [1, 0, 0], [0, 0, 0, 1])
        odom.put(m.encode_odometry(0, "odom", "b", [1, 0, 0], [0, 0, 0, 1]))  # dropped: not recorded
        odom.put(good)
        assert drain(raw, 1) == [("/odom", m.ODOMETRY, good)]
        bus.publish_joint_state(1.0, 0.1, 0.2, 0.0, 0.0)
        topic, msgtype, payload = drain(raw, 1)[0]
        assert (topic, msgtype) == ("/pivot/joint_states", m.JOINT_STATE)
        assert list(ros.typestore().deserialize_cdr(payload, m.JOINT_STATE).name) == ["pan", "tilt"]
        assert raw.empty()
    finally:
        bus.close()
