"""A map published before pivotd started reaches it from the router's storage (one query at start).

zenohd's storage manager is a plugin of the zenohd binary; here the router is a zenoh-python session in
router mode and its storage a subscriber + queryable on the fleet's key space that keep and serve the latest
sample per key, which is what a storage-manager memory storage does for the queries pivotd sends.
"""

from __future__ import annotations

import json
import queue
import threading

import numpy as np
import zenoh
from bus_support import drain, wait_for
from support import free_tcp_port

from pivotd.bus import messages as m
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.ros import RosNode
from pivotd.bus.session import open_session
from pivotd.bus.topics import BusTopics


class RouterWithStorage:
    """A router whose storage on ``key_expr`` keeps the latest sample of every key and answers queries."""

    def __init__(self, endpoint: str, key_expr: str) -> None:
        conf = zenoh.Config()
        conf.insert_json5("mode", json.dumps("router"))
        conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
        conf.insert_json5("scouting/multicast/enabled", "false")
        self.session = zenoh.open(conf)
        self.stored: dict[str, bytes] = {}
        self._lock = threading.Lock()
        self._sub = self.session.declare_subscriber(key_expr, self._store)
        self._queryable = self.session.declare_queryable(key_expr, self._answer)

    def _store(self, sample: zenoh.Sample) -> None:
        with self._lock:
            self.stored[str(sample.key_expr)] = sample.payload.to_bytes()

    def _answer(self, query: zenoh.Query) -> None:
        with self._lock:
            items = list(self.stored.items())
        for key, payload in items:
            if query.key_expr.intersects(zenoh.KeyExpr(key)):
                query.reply(key, payload)

    def close(self) -> None:
        self._queryable.undeclare()
        self._sub.undeclare()
        self.session.close()


def test_a_daemon_started_after_the_map_was_published_gets_it_from_the_storage():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    router = RouterWithStorage(endpoint, "0/fleet/**")
    mapper_session = bus_session = None
    try:
        mapper_session = open_session("client", connect=[endpoint])
        mapper = RosNode(mapper_session, "mapper")
        points = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0], [7.0, 8.0, 9.5]])
        pub = mapper.publisher("/fleet/landmarks", m.POINT_CLOUD2)
        assert wait_for(lambda: pub.put(m.encode_cloud(1.0, "map", points)) >= 0 and bool(router.stored), 10)
        mapper.close()
        mapper_session.close()  # the mapping node is gone; only the storage holds the map
        mapper_session = None

        bus_session = open_session("client", connect=[endpoint])
        clouds: queue.Queue = queue.Queue()
        topics = BusTopics(namespace="/robot1", landmarks="/fleet/landmarks")  # absolute: shared by the fleet
        with PivotBus(bus_session, topics, node_name="robot1", on_cloud=lambda layer, c: clouds.put((layer, c))):
            got = drain(clouds, 1, timeout=10)
            assert len(got) == 1, "the stored map did not arrive"
            layer, cloud = got[0]
            assert layer == "landmarks"
            np.testing.assert_allclose(cloud.points, points)
            # the namespaced targets topic has nothing stored: no answer, nothing delivered
            assert drain(clouds, 1, timeout=0.5) == []
    finally:
        for s in (mapper_session, bus_session):
            if s is not None:
                s.close()
        router.close()
