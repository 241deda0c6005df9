"""``topics.wire: ros2dds_bridge``: pivotd's topics as zenoh-bridge-ros2dds routes a DDS robot's topics.

Golden keys from the bridge's documented mapping (zenoh-plugin-ros2dds ``ros2_utils.rs``,
``ros2_name_to_key_expr``; DEFAULT_CONFIG.json5 ``namespace``): the key of the ROS name ``/<name>`` is ``<name>``
with the bridge's namespace ``/`` and ``<namespace without its leading slash>/<name>`` otherwise, for absolute
names such as ``/tf`` too. Payloads are bare CDR, without attachment; no liveliness tokens. The peer playing the
bridge is a plain Zenoh session of the test (real Zenoh on loopback, scouting off).
"""

from __future__ import annotations

import queue
import time

import numpy as np
import pytest
import zenoh
import zenoh.ext as zext
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.qos import QoS
from pivotd.bus.ros2dds import LEGACY_CACHE_CHUNK, BridgeNode
from pivotd.bus.security import input_key_exprs
from pivotd.bus.topics import WIRE_ROS2DDS_BRIDGE, BusTopics, bridge_key, bridge_topic
from pivotd.errors import ConfigError

BRIDGED = {"wire": WIRE_ROS2DDS_BRIDGE}
LATCHED = QoS.named("reliable", "transient_local", 1)
PATH = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.0]])


def documented_key(bridge_namespace: str, ros2_name: str) -> str:
    """The bridge's rule as documented: ``ros2_name`` starts with '/', the namespace starts with '/'."""
    return ros2_name[1:] if bridge_namespace == "/" else f"{bridge_namespace[1:]}/{ros2_name[1:]}"


# ------------------------------------------------------------------ golden keys

@pytest.mark.parametrize("namespace", ["/", "/robot1", "/fleet/r2"])
def test_every_topic_key_is_the_bridges_key_for_the_robots_own_name(namespace):
    # the robot's DDS names (absolute, as in the bridge's allow lists) and pivotd's config names for them
    robot = {"pose": "/odom", "path": "/plan", "landmarks": "/pivot/landmarks", "targets": "/pivot/targets",
             "joint_states": "/pivot/joint_states", "view_plan": "/pivot/view_plan", "tf": "/tf",
             "tf_static": "/tf_static"}
    for config_names in (robot, {k: v[1:] for k, v in robot.items()}):  # absolute and relative names alike
        t = BusTopics(namespace=namespace, **BRIDGED, **config_names)
        for field, name in robot.items():
            assert bridge_key(getattr(t, field)) == documented_key(namespace, name), (namespace, field)


def test_golden_keys_spelled_out():
    t = BusTopics(namespace="/robot1", **BRIDGED)  # the defaults: relative names
    assert [bridge_key(n) for n in (t.pose, t.path, t.tf, t.tf_static, t.joint_states, t.view_plan)] == [
        "robot1/odom", "robot1/plan", "robot1/tf", "robot1/tf_static", "robot1/pivot/joint_states",
        "robot1/pivot/view_plan"]
    assert bridge_key(BusTopics(**BRIDGED).pose) == "odom"
    assert bridge_key(BusTopics(namespace="/robot1", pose="/amcl_pose", **BRIDGED).pose) == "robot1/amcl_pose"
    # the status key is the same on both wires
    assert BusTopics(**BRIDGED).status_key == BusTopics().status_key == "pivot/pivotd/status"


def test_bridge_names_are_idempotent_and_rmw_zenoh_resolution_is_unchanged():
    assert bridge_topic(bridge_topic("/tf", "/robot1"), "/robot1") == "/robot1/tf"
    assert bridge_topic("/robot1/odom", "/robot1") == "/robot1/odom"  # already routed
    assert bridge_topic("/robot10/odom", "/robot1") == "/robot1/robot10/odom"  # a chunk prefix is not the namespace
    rmw = BusTopics(namespace="/robot1", tf="/tf")
    assert (rmw.tf, rmw.pose) == ("/tf", "/robot1/odom")  # absolute names stay as they are on rmw_zenoh


def test_unknown_wire_is_rejected():
    with pytest.raises(ConfigError, match="wire 'dds' must be one of rmw_zenoh, ros2dds_bridge"):
        BusTopics(wire="dds")


def test_access_control_covers_the_bridge_keys():
    t = BusTopics(namespace="/robot1", pose_source="tf", **BRIDGED)
    assert input_key_exprs(t) == ["robot1/odom", "robot1/pivot/landmarks", "robot1/pivot/targets", "robot1/plan",
                                  "robot1/tf", "robot1/tf_static"]
    assert input_key_exprs(BusTopics(namespace="/robot1"))[0] == "0/robot1/odom/**"


# ------------------------------------------------------------------ the bus on loopback

def test_bus_reads_plain_cdr_without_attachment_and_publishes_bare_cdr_on_the_plain_keys():
    t = BusTopics(namespace="/robot1", **BRIDGED)
    poses, paths, joints = queue.Queue(), queue.Queue(), queue.Queue()
    with session_pair() as (a, b, _):
        sub = b.declare_subscriber("robot1/pivot/joint_states",
                                   lambda s: joints.put((str(s.key_expr), s.payload.to_bytes(), s.attachment)))
        bus = PivotBus(a, t, on_pose=poses.put, on_path=paths.put)
        try:
            assert sorted(e.key for e in bus._entities) == [
                "robot1/odom", "robot1/pivot/joint_states", "robot1/pivot/landmarks", "robot1/pivot/targets",
                "robot1/pivot/view_plan", "robot1/plan"]
            odom, plan = b.declare_publisher("robot1/odom"), b.declare_publisher("robot1/plan")
            assert wait_for(lambda: bus.joint_state_publisher.matched() and odom.matching_status.matching
                            and plan.matching_status.matching)
            position, quat = np.array([1.0, 2.0, 0.0]), np.array([0.0, 0.0, 0.0, 1.0])
            pose_cdr = m.encode_odometry(time.time(), "map", "base_link", position, quat)
            odom.put(pose_cdr)  # what the bridge routes: the DDS sample as it is, no attachment
            plan.put(m.encode_path(time.time(), "map", PATH))
            (pose,) = drain(poses, 1)
            np.testing.assert_allclose(pose.position, position)
            (path,) = drain(paths, 1)
            np.testing.assert_allclose(path.positions, PATH)
            bus.publish_joint_state(1700000000.25, 0.1, -0.2, 0.5, 0.0)
            ((key, payload, attachment),) = drain(joints, 1)
            assert key == "robot1/pivot/joint_states" and attachment is None
            assert payload == m.encode_joint_state(1700000000.25, ["pan", "tilt"], [0.1, -0.2], [0.5, 0.0])
            assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian encapsulation header, nothing before it
            msg = ros.typestore().deserialize_cdr(payload, m.JOINT_STATE)
            assert list(msg.name) == ["pan", "tilt"] and list(msg.position) == [0.1, -0.2]
            c = bus.counters()
            assert c["/robot1/odom"]["accepted"] == 1 and c["/robot1/plan"]["accepted"] == 1
        finally:
            bus.close()
            sub.undeclare()


def test_garbage_on_a_plain_key_is_dropped_and_counted_not_taken_for_a_wrong_type():
    t = BusTopics(**BRIDGED)
    with session_pair() as (a, b, _):
        bus = PivotBus(a, t)
        try:
            odom = b.declare_publisher("odom")
            assert wait_for(lambda: odom.matching_status.matching)
            odom.put(b"\x00\x01\x00\x00garbage")
            assert wait_for(lambda: bus.counters()["/odom"].get("received") == 1)
            assert wait_for(lambda: sum(v for k, v in bus.counters()["/odom"].items() if k.startswith("dropped")) == 1)
            assert "dropped_wrong_type" not in bus.counters()["/odom"] and bus.counters()["/odom"]["accepted"] == 0
        finally:
            bus.close()


def test_no_liveliness_tokens_on_the_bridge_wire():
    with session_pair() as (a, b, _):
        def tokens() -> list[str]:
            return [str(r.ok.key_expr) for r in b.liveliness().get(f"{ros.ADMIN_SPACE}/**", timeout=2.0)
                    if r.ok is not None]

        with PivotBus(a, BusTopics()):  # the rmw_zenoh wire declares its node and entities
            assert wait_for(lambda: len(tokens()) > 0)
        assert wait_for(lambda: tokens() == [])
        with PivotBus(a, BusTopics(**BRIDGED)) as bus:
            # the status queryable is declared last: once it answers, every earlier declaration has arrived
            assert wait_for(lambda: any(r.ok is not None for r in b.get(bus.topics.status_key, timeout=2.0)))
            assert tokens() == []


def test_path_latched_by_a_bridge_before_pivotd_starts_arrives():
    """Bridges from 1.5.1: a TRANSIENT_LOCAL DDS writer is routed through an advanced publisher with a cache."""
    paths = queue.Queue()
    with session_pair() as (a, b, _):
        pub = zext.declare_advanced_publisher(b, "robot1/plan", cache=zext.CacheConfig(max_samples=1),
                                              publisher_detection=True)
        pub.put(m.encode_path(1.0, "map", PATH))
        bus = PivotBus(a, BusTopics(namespace="/robot1", **BRIDGED), on_path=paths.put)
        try:
            (path,) = drain(paths, 1)
            np.testing.assert_allclose(path.positions, PATH)
        finally:
            bus.close()
            pub.undeclare()


def test_path_cached_by_a_legacy_bridge_arrives():
    """Bridges before 1.5.1: a PublicationCache answering on ``<key>/@ros2_pub_cache/<zid>`` with the sample's key."""
    paths, queried = queue.Queue(), queue.Queue()
    payload = m.encode_path(1.0, "map", PATH)
    with session_pair() as (a, b, _):
        def answer(query: zenoh.Query) -> None:
            queried.put(str(query.key_expr))
            query.reply("robot1/plan", payload)

        cache = b.declare_queryable(f"robot1/plan/{LEGACY_CACHE_CHUNK}/{b.info.zid()}", answer)
        bus = PivotBus(a, BusTopics(namespace="/robot1", **BRIDGED), on_path=paths.put)
        try:
            (path,) = drain(paths, 1)
            np.testing.assert_allclose(path.positions, PATH)
            assert drain(queried, 1) == [f"robot1/plan/{LEGACY_CACHE_CHUNK}/*"]
        finally:
            bus.close()
            cache.undeclare()


def test_latched_view_plan_reaches_late_bridge_subscribers_of_both_generations():
    with session_pair() as (a, b, _):
        bus = PivotBus(a, BusTopics(namespace="/robot1", **BRIDGED))
        try:
            positions, directions = PATH, np.tile([1.0, 0.0, 0.0], (3, 1))
            bus.publish_view_plan(2.0, positions, directions)
            expected = m.encode_view_plan(2.0, "map", positions, directions)
            got = queue.Queue()
            # from 1.5.1: an advanced subscriber with history (a transient-local DDS reader on the robot)
            sub = zext.declare_advanced_subscriber(
                b, "robot1/pivot/view_plan", lambda s: got.put(s.payload.to_bytes()),
                history=zext.HistoryConfig(detect_late_publishers=True, max_samples=1))
            try:
                assert drain(got, 1) == [expected]
            finally:
                sub.undeclare()
            # before 1.5.1: a query of every publication cache, accepting replies on the topic's key
            replies = [r.ok for r in b.get(f"robot1/pivot/view_plan/{LEGACY_CACHE_CHUNK}/*",
                                           target=zenoh.QueryTarget.ALL, accept_replies=zenoh.ReplyKeyExpr.ANY,
                                           timeout=5.0) if r.ok is not None]
            assert [(str(s.key_expr), s.payload.to_bytes()) for s in replies] == [("robot1/pivot/view_plan",
                                                                                   expected)]
        finally:
            bus.close()


def test_bridge_node_publishers_for_added_topics_use_the_bridge_names():
    with session_pair() as (a, _, _):
        node = BridgeNode(a, "/robot1")
        pubs = [node.publisher(topic, m.TF_MESSAGE, QoS(depth=100)) for topic in ("/tf", "/robot1/tf", "tf")]
        try:
            assert [p.key for p in pubs] == ["robot1/tf"] * 3
        finally:
            for p in pubs:
                p.close()


# ------------------------------------------------------------------ the config key

MINIMAL = "name: test-node\nmap:\n  allow_empty: true\n"


def test_config_key_topics_wire(tmp_path):
    from pivotd.config import load_config

    ok = tmp_path / "ok.yaml"
    ok.write_text(MINIMAL + "topics:\n  wire: ros2dds_bridge\n  namespace: /robot1\n  tf: /tf\n")
    t = load_config(ok).topics
    assert (t.wire, t.bridged, bridge_key(t.tf), bridge_key(t.pose)) == ("ros2dds_bridge", True, "robot1/tf",
                                                                          "robot1/odom")
    default = tmp_path / "default.yaml"
    default.write_text(MINIMAL)
    assert load_config(default).topics.wire == "rmw_zenoh"
    bad = tmp_path / "bad.yaml"
    bad.write_text(MINIMAL + "topics:\n  wire: dds\n")
    with pytest.raises(ConfigError) as info:
        load_config(bad)
    message = str(info.value)
    assert message.startswith(f"{bad}:5: topics.wire:") and "ros2dds_bridge" in message and "\n" not in message


def test_a_shared_topic_outside_the_robots_namespace_with_the_root_namespace():
    t = BusTopics(pose="/robot1/odom", landmarks="/fleet/map", **BRIDGED)
    assert (bridge_key(t.pose), bridge_key(t.landmarks)) == ("robot1/odom", "fleet/map")


def test_pose_from_tf_through_the_bridge_with_tf_static_latched_before_pivotd_starts():
    t = BusTopics(namespace="/robot1", pose_source="tf", **BRIDGED)
    poses = queue.Queue()
    ident = np.array([0.0, 0.0, 0.0, 1.0])
    with session_pair() as (a, b, _):
        static = zext.declare_advanced_publisher(b, "robot1/tf_static", cache=zext.CacheConfig(max_samples=1),
                                                 publisher_detection=True)
        static.put(m.encode_transforms([(1.0, "base_footprint", "base_link", np.array([0.0, 0.0, 0.5]), ident)]))
        bus = PivotBus(a, t, on_pose=poses.put, tf_timeout=30.0)
        tf = b.declare_publisher("robot1/tf")
        try:
            assert wait_for(lambda: bus.counters()["/robot1/tf_static"]["accepted"] == 1)
            assert wait_for(lambda: tf.matching_status.matching)
            tf.put(m.encode_transforms([(time.time(), "map", "base_footprint", np.array([1.0, 2.0, 0.0]), ident)]))
            (pose,) = drain(poses, 1)
            np.testing.assert_allclose(pose.position, [1.0, 2.0, 0.5])
        finally:
            bus.close()
            tf.undeclare()
            static.undeclare()
