"""Bounded bus input: size limits before decoding, newest-only inboxes, decoding off Zenoh's threads."""

from __future__ import annotations

import logging
import queue
import threading
import time

import numpy as np
import pytest
import zenoh
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.inbox import Decoder, Inbox
from pivotd.bus.large_messages import cloud_with_fields, large_path
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import BusTopics
from pivotd.errors import ConfigError


def test_inbox_keeps_the_newest_per_topic_and_serves_topics_in_order():
    box = Inbox()
    box.add_topic("/odom", 1)
    box.add_topic("/plan", 2)
    assert box.put("/plan", "p1") and box.put("/plan", "p2")
    assert not box.put("/plan", "p3")  # evicts p1
    assert box.put("/odom", "o1")
    assert not box.put("/odom", "o2")  # latest wins
    assert box.pending() == 3
    assert [box.get(0) for _ in range(3)] == [("/odom", "o2"), ("/plan", "p2"), ("/plan", "p3")]
    assert box.get(0.01) is None
    box.close()
    assert not box.put("/odom", "late") and box.get(None) is None
    with pytest.raises(ValueError):
        box.add_topic("/x", 0)


def test_decoder_survives_a_failing_handler_and_stops_on_close():
    box = Inbox()
    box.add_topic("t", 4)
    seen = []
    done = threading.Event()

    def handle(topic, item):
        if item == "bad":
            raise RuntimeError("boom")
        seen.append(item)
        if item == "last":
            done.set()

    dec = Decoder(box, handle, "test-decoder")
    for item in ("a", "bad", "last"):
        box.put("t", item)
    assert done.wait(10)
    dec.close()
    assert seen == ["a", "last"]


def test_payload_limits_are_validated():
    with pytest.raises(ConfigError, match="max_path_bytes must be >= 256"):
        BusTopics(max_path_bytes=10)
    assert BusTopics().max_message_bytes == 2 * BusTopics().max_cloud_bytes


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, _):
        yield a, b


def test_a_large_payload_dropped_or_decoded_is_reported_once_for_the_memory_release(sessions):
    """The daemon gives freed heap back to the OS after a large payload: the bus says when one was seen (too large
    and dropped, or decoded), once, and not for small messages."""
    from pivotd.bus.pivot_bus import LARGE_PAYLOAD_BYTES

    got = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(max_path_bytes=2 * LARGE_PAYLOAD_BYTES), on_path=got.put)
    remote = ros.RosNode(sessions[1], "remote", node_id=int(time.monotonic_ns() % 1000) + 1000)
    try:
        plan = remote.publisher("/plan", m.PATH)
        assert wait_for(plan.matched)

        def put(payload):
            sessions[1].put(plan.key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

        put(m.encode_path(0.0, "map", [[0, 0, 0], [1, 0, 0]]))
        assert got.get(timeout=30).positions.shape == (2, 3)
        assert not bus.large_payload_seen()
        put(large_path(int(1.5 * LARGE_PAYLOAD_BYTES)))  # decoded
        assert got.get(timeout=30).positions.shape[0] > 10_000
        assert bus.large_payload_seen() and not bus.large_payload_seen()
        put(large_path(3 * LARGE_PAYLOAD_BYTES))  # too large: dropped before decoding
        assert wait_for(lambda: bus.counters()["/plan"].get("dropped_too_large") == 1, timeout=30)
        assert bus.large_payload_seen() and not bus.large_payload_seen()
    finally:
        remote.close()
        bus.close()


def test_oversize_and_field_heavy_messages_are_dropped_before_decoding(sessions):
    events = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(max_path_bytes=64 * 1024, max_pose_bytes=1024),
                   on_path=lambda p: events.put(("path", p)), on_pose=lambda p: events.put(("pose", p)),
                   on_cloud=lambda layer, c: events.put((layer, c)))
    remote = ros.RosNode(sessions[1], "remote", node_id=int(time.monotonic_ns() % 1000))
    try:
        plan = remote.publisher("/plan", m.PATH)
        odom = remote.publisher("/odom", m.ODOMETRY)
        targets = remote.publisher("/pivot/targets", m.POINT_CLOUD2)
        landmarks = remote.publisher("/pivot/landmarks", m.POINT_CLOUD2)
        assert all(wait_for(p.matched) for p in (plan, odom, targets, landmarks))
        def put(pub, payload):  # blocking congestion control: on a busy machine the sender must not drop it
            sessions[1].put(pub.key, payload, congestion_control=zenoh.CongestionControl.BLOCK)

        put(plan, large_path(200_000))  # a valid path, 3x the limit
        put(odom, m.encode_odometry(0.0, "map" + "x" * 2000, "b", [0, 0, 0], [0, 0, 0, 1]))  # 2 KB pose
        put(targets, cloud_with_fields(100_000))  # ~5000 PointFields, within the byte limit
        put(landmarks, m.encode_cloud(0.0, "map", np.array([[0.0, 0, 0], [2e7, 0, 0]])))  # a point 20 000 km away
        put(plan, m.encode_path(0.0, "map", [[0, 0, 0], [1, 0, 0]]))

        def through(topic):
            c = bus.counters()[topic]
            return c["accepted"] + sum(v for k, v in c.items() if k.startswith("dropped_"))

        assert wait_for(lambda: through("/plan") == 2 and through("/odom") == 1 and through("/pivot/targets") == 1
                        and through("/pivot/landmarks") == 1, timeout=30), bus.counters()
        c = bus.counters()
        assert c["/plan"] == {"received": 2, "accepted": 1, "dropped_too_large": 1}
        assert c["/odom"] == {"received": 1, "accepted": 0, "dropped_too_large": 1}
        assert c["/pivot/targets"] == {"received": 1, "accepted": 0, "dropped_bad_fields": 1}
        assert c["/pivot/landmarks"] == {"received": 1, "accepted": 0, "dropped_out_of_range": 1}
        got = drain(events, 1)
        assert got[0][0] == "path" and got[0][1].positions.shape == (2, 3)
        assert events.empty()
    finally:
        remote.close()
        bus.close()


def test_a_slow_path_consumer_never_delays_poses(sessions, caplog):
    """Paths and clouds are decoded and handed over on their own thread: while the daemon's path callback is
    busy, poses keep arriving; the paths that came meanwhile are replaced by the newest (counted)."""
    caplog.set_level(logging.DEBUG, logger="pivotd.bus.pivot_bus")
    release = threading.Event()
    poses = queue.Queue()
    paths = []

    def slow_path(p):
        paths.append(p)
        release.wait(30)

    bus = PivotBus(sessions[0], BusTopics(), on_path=slow_path, on_pose=poses.put)
    remote = ros.RosNode(sessions[1], "remote2", node_id=int(time.monotonic_ns() % 1000))
    try:
        plan = remote.publisher("/plan", m.PATH)
        odom = remote.publisher("/odom", m.ODOMETRY)
        assert wait_for(plan.matched) and wait_for(odom.matched)
        plan.put(m.encode_path(0.0, "map", [[0, 0, 0], [1, 0, 0]]))
        assert wait_for(lambda: len(paths) == 1)  # the path thread is now blocked in the callback
        for k in range(3):
            sessions[1].put(plan.key, m.encode_path(0.0, "map", [[0, 0, 0], [2.0 + k, 0, 0]]),
                            congestion_control=zenoh.CongestionControl.BLOCK)
        for k in range(5):
            odom.put(m.encode_odometry(0.0, "map", "b", [float(k), 0, 0], [0, 0, 0, 1]))
            assert drain(poses, 1), "a pose was held up behind the path"
        # the two paths replaced before decoding are superseded, not dropped
        assert wait_for(lambda: bus.counters()["/plan"].get("superseded", 0) == 2)
        assert not any(k.startswith("dropped_") for k in bus.counters()["/plan"]), bus.counters()["/plan"]
        superseded = [r for r in caplog.records if "superseded" in r.getMessage()]
        assert len(superseded) == 2 and {r.levelno for r in superseded} == {logging.DEBUG}, superseded
        release.set()
        assert wait_for(lambda: len(paths) == 2)
        np.testing.assert_allclose(paths[1].positions[-1], [4.0, 0, 0])  # the newest one
    finally:
        release.set()
        remote.close()
        bus.close()
