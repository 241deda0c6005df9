"""TRANSIENT_LOCAL topics as rmw_zenoh does them: the latest sample reaches pivotd whichever side starts first.

Real Zenoh sessions on loopback. The "other ROS node" is a :class:`RosNode` on its own session with
transient-local QoS, i.e. the same advanced publisher/subscriber configuration rmw_zenoh declares.
"""

import json
import queue

import numpy as np
import zenoh
from bus_support import drain, session_pair, wait_for
from support import free_tcp_port

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.qos import QoS, TopicQoS
from pivotd.bus.session import open_session
from pivotd.bus.topics import BusTopics

LATCHED = QoS.named("reliable", "transient_local", 1)


def _bus(session, events: queue.Queue, qos: TopicQoS | None = None) -> PivotBus:
    return PivotBus(session, BusTopics(), on_path=lambda p: events.put(("path", p)),
                    on_cloud=lambda layer, c: events.put((layer, c)), qos=qos)


def test_map_published_once_before_pivotd_starts_is_received():
    """A mapping node publishes its landmark layer once (transient local); pivotd starts afterwards."""
    with session_pair() as (a, b, _):
        mapper = ros.RosNode(b, "mapper")
        pub = mapper.publisher("/pivot/landmarks", m.POINT_CLOUD2, LATCHED)
        pub.put(m.encode_cloud(1.0, "map", np.zeros((3, 3))))
        pub.put(m.encode_cloud(2.0, "map", np.arange(12.0).reshape(4, 3)))  # the latest: only this one is kept
        events: queue.Queue = queue.Queue()
        bus = _bus(a, events)
        try:
            got = drain(events, 1)
            assert got and got[0][0] == "landmarks"
            np.testing.assert_allclose(got[0][1].points, np.arange(12.0).reshape(4, 3))
            assert bus.counters()["/pivot/landmarks"]["accepted"] == 1
        finally:
            bus.close()
            pub.close()
            mapper.close()


def test_volatile_subscription_misses_what_was_published_before_it():
    """The same scene with a volatile pivotd subscription: only later messages arrive (the control case)."""
    with session_pair() as (a, b, _):
        mapper = ros.RosNode(b, "mapper")
        pub = mapper.publisher("/pivot/landmarks", m.POINT_CLOUD2, LATCHED)
        pub.put(m.encode_cloud(1.0, "map", np.zeros((3, 3))))
        events: queue.Queue = queue.Queue()
        bus = _bus(a, events, TopicQoS(landmarks=QoS(depth=1)))
        try:
            assert wait_for(pub.matched)
            pub.put(m.encode_cloud(3.0, "map", np.ones((5, 3))))
            got = drain(events, 1)
            assert got[0][1].points.shape == (5, 3)  # the first delivery is the live one, not the old map
        finally:
            bus.close()
            pub.close()
            mapper.close()


def test_planner_that_published_before_the_sessions_met_is_detected_late():
    """pivotd is up first; a planner publishes its path while no route exists; then a router joins them."""
    e_pivotd, e_planner = f"tcp/127.0.0.1:{free_tcp_port()}", f"tcp/127.0.0.1:{free_tcp_port()}"
    a = open_session(connect=[e_pivotd])
    b = open_session(listen=[e_planner])
    router = None
    events: queue.Queue = queue.Queue()
    bus = _bus(a, events)
    planner = ros.RosNode(b, "planner")
    pub = planner.publisher("/plan", m.PATH, LATCHED)
    try:
        pub.put(m.encode_path(5.0, "map", [[0, 0, 0], [1, 0, 0]]))
        pub.put(m.encode_path(6.0, "map", [[0, 0, 0], [2, 0, 0], [4, 0, 0]]))
        assert not a.info.peers_zid() and not a.info.routers_zid()  # nothing could have been delivered yet
        cfg = zenoh.Config()
        for key, value in (("mode", "router"), ("listen/endpoints", [e_pivotd]), ("connect/endpoints", [e_planner]),
                           ("scouting/multicast/enabled", False)):
            cfg.insert_json5(key, json.dumps(value))
        router = zenoh.open(cfg)
        got = drain(events, 1, timeout=20)
        assert got and got[0][0] == "path"
        np.testing.assert_allclose(got[0][1].positions[:, 0], [0, 2, 4])
    finally:
        bus.close()
        pub.close()
        planner.close()
        if router is not None:
            router.close()
        b.close()
        a.close()


def test_view_plan_reaches_a_subscriber_that_starts_after_it():
    """pivotd publishes first; a transient-local ROS subscriber that starts later gets the latest plan,
    attachment (sequence, GID) included; a volatile one started at the same time does not."""
    with session_pair() as (a, b, _):
        bus = PivotBus(a, BusTopics())
        late = ros.RosNode(b, "viewer")
        latched: queue.Queue = queue.Queue()
        volatile: queue.Queue = queue.Queue()
        subs = []
        try:
            bus.publish_view_plan(1.0, np.zeros((2, 3)), [[1, 0, 0], [0, 1, 0]])
            bus.publish_view_plan(2.0, np.ones((3, 3)), [[0, 0, 1]] * 3)
            subs.append(late.subscriber("/pivot/view_plan", m.PATH, lambda s: volatile.put(s), QoS(depth=1)))
            subs.append(late.subscriber("/pivot/view_plan", m.PATH, lambda s: latched.put(s), LATCHED))
            sample = drain(latched, 1)[0]
            path = ros.typestore().deserialize_cdr(sample.payload.to_bytes(), m.PATH)
            assert len(path.poses) == 3 and path.header.stamp.sec == 2
            att = ros.Attachment.decode(sample.attachment.to_bytes())
            assert att.sequence == 2 and att.gid == bus.view_plan_publisher.gid
            bus.publish_view_plan(3.0, np.ones((4, 3)), [[0, 0, 1]] * 4)
            first_volatile = ros.typestore().deserialize_cdr(drain(volatile, 1)[0].payload.to_bytes(), m.PATH)
            assert len(first_volatile.poses) == 4  # it never saw the plans published before it
        finally:
            for s in subs:
                s.close()
            late.close()
            bus.close()


def test_transient_local_qos_is_advertised_in_the_liveliness_tokens():
    with session_pair() as (a, b, _):
        tokens: queue.Queue = queue.Queue()
        lv = b.liveliness().declare_subscriber("@ros2_lv/0/**", lambda s: tokens.put(str(s.key_expr)), history=True)
        bus = PivotBus(a, BusTopics())
        try:
            seen: set = set()
            assert wait_for(lambda: seen.update(drain(tokens, tokens.qsize(), 0.05)) or sum(
                ("/MP/" in k or "/MS/" in k) for k in seen) >= 6)
            by_topic = {k.split("/")[9]: (k.split("/")[5], k.split("/")[-1]) for k in seen if len(k.split("/")) > 9}
            assert by_topic["%pivot%view_plan"] == ("MP", ":1:,1:,:,:,,")
            assert by_topic["%plan"] == ("MS", ":1:,1:,:,:,,")
            assert by_topic["%pivot%landmarks"] == ("MS", ":1:,1:,:,:,,")
            assert by_topic["%odom"] == ("MS", "::,10:,:,:,,")
            assert by_topic["%pivot%joint_states"] == ("MP", "::,10:,:,:,,")
        finally:
            bus.close()
            lv.undeclare()
