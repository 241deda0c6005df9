"""The pose from TF over real Zenoh: ``/tf`` and ``/tf_static`` (``tf2_msgs/msg/TFMessage`` serialised by rosbags)
published by other rmw_zenoh nodes, composed by pivotd's bus into map-frame poses.

Two peer sessions on loopback, scouting off, free ports. The publishers are :class:`RosNode` entities with tf2's
QoS: ``/tf`` volatile, ``/tf_static`` transient local with depth 1 (a static broadcaster's latched message).
"""

import logging
import queue
import time

import numpy as np
import pytest
from bus_support import session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.qos import QoS
from pivotd.bus.security import input_key_exprs
from pivotd.bus.topics import BusTopics
from pivotd.errors import ConfigError
from pivotd.geometry import quat_to_matrix

TF_TOPICS = BusTopics(pose_source="tf")
DYNAMIC = QoS(depth=100)
STATIC = QoS.named("reliable", "transient_local", 1)
ID = np.array([0.0, 0.0, 0.0, 1.0])


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def compose(t1, q1, t2, q2) -> tuple[np.ndarray, np.ndarray]:
    """(position, rotation matrix) of frame 2 in the parent of frame 1."""
    R1 = quat_to_matrix(q1)
    return R1 @ np.asarray(t2, float) + np.asarray(t1, float), R1 @ quat_to_matrix(q2)


class Node:
    """Another ROS node publishing TF: ``send`` on /tf, ``send_static`` on /tf_static."""

    def __init__(self, session, name: str) -> None:
        self.node = ros.RosNode(session, name)
        self.tf = self.node.publisher("/tf", m.TF_MESSAGE, DYNAMIC)
        self.static = self.node.publisher("/tf_static", m.TF_MESSAGE, STATIC)

    def send(self, *transforms) -> None:
        self.tf.put(m.encode_transforms(list(transforms)))

    def send_static(self, *transforms) -> None:
        self.static.put(m.encode_transforms(list(transforms)))

    def close(self) -> None:
        self.tf.close()
        self.static.close()
        self.node.close()


def _bus(session, poses: queue.Queue, tf_timeout: float = 30.0, topics: BusTopics = TF_TOPICS) -> PivotBus:
    return PivotBus(session, topics, on_pose=poses.put, tf_timeout=tf_timeout)


def _wait_pose(poses: queue.Queue, predicate, timeout: float = 10.0) -> m.PoseSample | None:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        try:
            p = poses.get(timeout=max(0.0, end - time.monotonic()))
        except queue.Empty:
            return None
        if predicate(p):
            return p
    return None


def _tf_status(bus: PivotBus) -> dict:
    assert bus.tf_pose is not None
    return bus.tf_pose.status()


def test_two_link_chain_at_different_rates():
    """map -> odom from a localizer at a tenth of the rate of odom -> base_link from odometry: every pose is the
    composition of the newest of each, stamped with the older (map -> odom) stamp."""
    with session_pair() as (a, b, _):
        slam, odometry = Node(b, "slam"), Node(b, "odometry")
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses)
        try:
            assert wait_for(lambda: slam.tf.matched() and odometry.tf.matched())
            t_mo, q_mo = np.array([3.0, -1.0, 0.0]), yaw_quat(0.3)
            t0 = 1000.0
            last_mo = None
            for k in range(40):
                stamp = t0 + 0.01 * k
                if k % 10 == 0:
                    t_mo = t_mo + np.array([0.05, 0.0, 0.0])  # the localizer's correction moves map -> odom a little
                    last_mo = stamp
                    slam.send((stamp, "map", "odom", t_mo, q_mo))
                odometry.send((stamp, "odom", "base_link", [0.02 * k, 0.01 * k, 0.0], yaw_quat(0.01 * k)))
            k = 39
            want_p, want_R = compose(t_mo, q_mo, [0.02 * k, 0.01 * k, 0.0], yaw_quat(0.01 * k))
            got = _wait_pose(poses, lambda p: np.allclose(p.position, want_p, atol=1e-9))
            assert got is not None, "no pose with the newest transform of each link"
            np.testing.assert_allclose(quat_to_matrix(got.quat), want_R, atol=1e-9)
            assert got.frame_id == "map"
            assert got.stamp == pytest.approx(last_mo)  # the oldest stamp of the chain: map -> odom's
            assert got.stamp < t0 + 0.39
            st = _tf_status(bus)
            assert st["chain"] == ["map", "odom", "base_link"] and st["frames"] == 2
            assert all(v == 0 for k, v in st["dropped"].items() if k != "missing_link")
            counters = bus.counters()
            assert "/odom" not in counters and counters["/tf"]["accepted"] >= 1
        finally:
            bus.close()
            slam.close()
            odometry.close()


def test_static_link_published_before_pivotd_starts_is_used_and_never_stale():
    """robot_state_publisher latches map -> odom on /tf_static before pivotd runs; odometry then streams."""
    with session_pair() as (a, b, _):
        static, odometry = Node(b, "static_tf"), Node(b, "odometry")
        static.send_static((5.0, "map", "odom", [10.0, 0.0, 0.0], yaw_quat(np.pi / 2)))
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses, tf_timeout=0.3)
        try:
            stamp = [100.0]

            def step() -> bool:  # stream odometry until a pose arrives
                stamp[0] += 0.01
                odometry.send((stamp[0], "odom", "base_link", [1.0, 0.0, 0.0], ID))
                return bus.tf_pose.status()["composed"] > 0

            assert wait_for(step, timeout=15.0)
            got = _wait_pose(poses, lambda p: True)
            np.testing.assert_allclose(got.position, [10.0, 1.0, 0.0], atol=1e-9)
            assert got.stamp > 100.0  # the static link's stamp (5.0) does not count as the oldest
            assert bus.counters()["/tf_static"]["accepted"] == 1
            time.sleep(0.5)  # longer than tf_timeout: a static link does not age
            odometry.send((200.0, "odom", "base_link", [2.0, 0.0, 0.0], ID))
            got = _wait_pose(poses, lambda p: p.stamp == pytest.approx(200.0))
            assert got is not None
            np.testing.assert_allclose(got.position, [10.0, 2.0, 0.0], atol=1e-9)
            assert _tf_status(bus)["dropped"]["stale"] == 0
        finally:
            bus.close()
            static.close()
            odometry.close()


def test_broken_chain_gives_no_pose_is_counted_and_logged_once(caplog):
    with session_pair() as (a, b, _):
        odometry, slam = Node(b, "odometry"), Node(b, "slam")
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses)
        try:
            assert wait_for(odometry.tf.matched)
            with caplog.at_level(logging.WARNING, logger="pivotd.bus.tf_pose"):
                for k in range(5):
                    odometry.send((1.0 + k, "odom", "base_link", [1.0, 0.0, 0.0], ID))
                assert wait_for(lambda: _tf_status(bus)["dropped"]["missing_link"] == 5)
            assert poses.empty()
            warnings = [r.getMessage() for r in caplog.records if "no transform chain" in r.getMessage()]
            assert warnings == ["TF: no transform chain map -> base_link: 'base_link' reaches up to 'odom', 'map' to "
                                "'map' (dropped; logged once)"]
            slam.send((6.0, "map", "odom", [0.0, 5.0, 0.0], ID))
            got = _wait_pose(poses, lambda p: True)
            assert got is not None
            np.testing.assert_allclose(got.position, [1.0, 5.0, 0.0], atol=1e-9)
            assert got.stamp == 5.0  # odom -> base_link's last stamp is now the oldest
        finally:
            bus.close()
            odometry.close()
            slam.close()


def test_nan_and_non_unit_quaternion_are_dropped_and_counted_per_reason():
    with session_pair() as (a, b, _):
        node = Node(b, "odometry")
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses)
        try:
            assert wait_for(node.tf.matched)
            node.send((1.0, "map", "base_link", [np.nan, 0.0, 0.0], ID),
                      (1.0, "map", "laser", [0.0, 0.0, 0.0], [0.0, 0.0, 0.0, 2.0]))
            node.send((2.0, "map", "base_link", [1.0, 2.0, 3.0], ID))
            got = _wait_pose(poses, lambda p: True)
            assert got is not None and got.stamp == 2.0
            c = bus.counters()["/tf"]
            assert c["dropped_nonfinite"] == 1 and c["dropped_non_unit_quaternion"] == 1 and c["accepted"] == 2
            st = _tf_status(bus)
            assert st["dropped"]["nonfinite"] == 1 and st["dropped"]["non_unit_quaternion"] == 1
            assert st["frames"] == 1
        finally:
            bus.close()
            node.close()


def test_reparented_frame_and_a_second_parent_from_another_publisher():
    """A second publisher claiming odom under another parent is refused while the first one's link lives; the
    first publisher moving odom under a new parent is a reparenting, and the pose follows the new chain."""
    with session_pair() as (a, b, _):
        slam, odometry, rogue = Node(b, "slam"), Node(b, "odometry"), Node(b, "rogue")
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses)
        try:
            assert wait_for(lambda: slam.tf.matched() and odometry.tf.matched() and rogue.tf.matched())
            slam.send((1.0, "map", "odom", [1.0, 0.0, 0.0], ID))
            odometry.send((1.0, "odom", "base_link", [0.0, 1.0, 0.0], ID))
            assert _wait_pose(poses, lambda p: np.allclose(p.position, [1.0, 1.0, 0.0])) is not None
            rogue.send((1.1, "world", "odom", [50.0, 0.0, 0.0], ID))
            assert wait_for(lambda: bus.counters()["/tf"].get("dropped_two_parents", 0) == 1)
            odometry.send((1.2, "odom", "base_link", [0.0, 2.0, 0.0], ID))
            assert _wait_pose(poses, lambda p: p.stamp == pytest.approx(1.0) and
                              np.allclose(p.position, [1.0, 2.0, 0.0])) is not None
            # the localizer re-attaches odom to 'world', itself under map (one message, parent first)
            slam.send((2.0, "map", "world", [0.0, 0.0, 10.0], ID), (2.0, "world", "odom", [2.0, 0.0, 0.0], ID))
            odometry.send((2.0, "odom", "base_link", [0.0, 3.0, 0.0], ID))
            got = _wait_pose(poses, lambda p: np.allclose(p.position, [2.0, 3.0, 10.0]))
            assert got is not None
            st = _tf_status(bus)
            assert st["chain"] == ["map", "world", "odom", "base_link"]
            assert st["transforms"]["reparented"] == 1 and st["dropped"]["two_parents"] == 1
        finally:
            bus.close()
            for n in (slam, odometry, rogue):
                n.close()


def test_stale_map_to_odom_gives_no_pose():
    """map -> odom stops; odometry goes on: once the link is older than tf_timeout no pose is made (the daemon
    then holds as for a silent pose topic)."""
    with session_pair() as (a, b, _):
        slam, odometry = Node(b, "slam"), Node(b, "odometry")
        poses: queue.Queue = queue.Queue()
        bus = _bus(a, poses, tf_timeout=0.3)
        try:
            assert wait_for(lambda: slam.tf.matched() and odometry.tf.matched())
            slam.send((1.0, "map", "odom", [0.0, 0.0, 0.0], ID))
            odometry.send((1.0, "odom", "base_link", [1.0, 0.0, 0.0], ID))
            assert _wait_pose(poses, lambda p: p.stamp == 1.0) is not None
            time.sleep(0.6)
            odometry.send((1.7, "odom", "base_link", [2.0, 0.0, 0.0], ID))
            assert wait_for(lambda: _tf_status(bus)["dropped"]["stale"] >= 1)
            assert wait_for(lambda: bus.counters()["/tf"]["accepted"] == 3)
            assert all(p.stamp != 1.7 and not np.allclose(p.position, [2.0, 0.0, 0.0]) for p in list(poses.queue))
        finally:
            bus.close()
            slam.close()
            odometry.close()


def test_topic_source_is_unchanged_and_tf_topics_are_inputs_only_for_tf():
    assert BusTopics().pose_source == "topic"
    assert not any("tf" in k for k in input_key_exprs(BusTopics()))
    assert {"0/tf/**", "0/tf_static/**"} <= set(input_key_exprs(TF_TOPICS))
    assert BusTopics(pose_source="tf", namespace="/robot1").tf_static == "/robot1/tf_static"
    with pytest.raises(ConfigError, match="pose_source"):
        BusTopics(pose_source="amcl")
    with pytest.raises(ConfigError, match="must differ"):
        BusTopics(map_frame="base_link")


def test_pose_from_tf_keys_load_and_bad_ones_name_file_line_and_key(tmp_path):
    from pivotd.config import load_config

    good = tmp_path / "tf.yaml"
    good.write_text("map:\n  allow_empty: true\ntopics:\n  namespace: /robot1\n  pose_source: tf\n"
                    "  base_frame: base_footprint\n  tf_max_frames: 64\n  max_tf_bytes: 4096\n")
    t = load_config(good).topics
    assert (t.pose_source, t.map_frame, t.base_frame, t.tf, t.tf_static, t.tf_max_frames, t.max_tf_bytes) == (
        "tf", "map", "base_footprint", "/robot1/tf", "/robot1/tf_static", 64, 4096)
    assert "0/robot1/tf_static/**" in input_key_exprs(t)
    for body, message in (("  pose_source: amcl\n", ":4: topics.pose_source: must be one of topic, tf"),
                          ("  map_frame: base_link\n", ":3: topics.base_frame: must differ from map_frame"),
                          ("  tf_max_frames: 0\n", ":4: topics.tf_max_frames: must be"),
                          ("  max_tf_bytes: 10\n", ":4: topics.max_tf_bytes: must be")):
        bad = tmp_path / "bad.yaml"
        bad.write_text("map:\n  allow_empty: true\ntopics:\n" + body)
        with pytest.raises(ConfigError, match=message.replace(".", r"\.")):
            load_config(bad)
