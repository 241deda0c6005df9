"""Support code for bus tests: free loopback ports, connected Zenoh session pairs, waiting for deliveries."""

from __future__ import annotations

import json
import queue
import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager, suppress

import zenoh
from support import free_tcp_port as free_port
from support import wait_until

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.session import open_session
from pivotd.bus.topics import BusTopics


def open_router(endpoint: str) -> zenoh.Session:
    """A Zenoh router listening on ``endpoint`` (loopback), multicast scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("router"))
    conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def open_client(endpoint: str) -> zenoh.Session:
    """A Zenoh client session connected to the router at ``endpoint``, multicast scouting off."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("client"))
    conf.insert_json5("connect/endpoints", json.dumps([endpoint]))
    conf.insert_json5("scouting/multicast/enabled", "false")
    return zenoh.open(conf)


def wait_for(predicate: Callable[[], bool], timeout: float = 10.0, interval: float = 0.02) -> bool:
    """Poll ``predicate`` until true or ``timeout`` s pass (support.wait_until with bus-test defaults)."""
    return wait_until(predicate, timeout, interval)


def wait_connected(a: zenoh.Session, b: zenoh.Session, timeout: float = 10.0) -> None:
    """Block until sessions ``a`` and ``b`` see each other as peers."""
    zb, za = str(b.info.zid()), str(a.info.zid())
    ok = wait_for(lambda: zb in {str(z) for z in a.info.peers_zid()} and za in {str(z) for z in b.info.peers_zid()},
                  timeout)
    if not ok:
        raise AssertionError("zenoh sessions did not connect on loopback")


@contextmanager
def session_pair() -> Iterator[tuple[zenoh.Session, zenoh.Session, str]]:
    """Two peer sessions on loopback (scouting off): the first listens on a free port, the second connects.

    Yields (listener, connector, endpoint).
    """
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    a = open_session(listen=[endpoint])
    b = None
    try:
        b = open_session(connect=[endpoint])
        wait_connected(a, b)
        yield a, b, endpoint
    finally:
        if b is not None:
            b.close()
        a.close()


def drain(q: queue.Queue, count: int, timeout: float = 10.0) -> list:
    """Take ``count`` items from ``q``, waiting up to ``timeout`` s in total; returns what arrived."""
    out = []
    end = time.monotonic() + timeout
    while len(out) < count:
        left = end - time.monotonic()
        if left <= 0:
            break
        try:
            out.append(q.get(timeout=left))
        except queue.Empty:
            break
    return out


def record_poses(session: zenoh.Session, topics: BusTopics, into: queue.Queue,
                 wrap: Callable[[m.PoseSample], object] = lambda s: s) -> zenoh.Subscriber:
    """Every valid pose published on ``topics.pose``, decoded on Zenoh's thread into ``into`` (as ``wrap(pose)``).

    A lossless test instrument for the tools that publish poses: pivotd's own bus keeps only the newest pose
    while one is being decoded, so it may skip some. Undeclare the returned subscriber when done.
    """
    def on_sample(sample: zenoh.Sample) -> None:
        with suppress(m.MessageError):
            into.put(wrap(m.decode_pose(sample.payload.to_bytes(), topics.pose_type, topics.pose, topics.frame_id,
                                        rx_time=time.monotonic())))

    return session.declare_subscriber(ros.topic_key(topics.domain_id, topics.pose, None, "*"), on_sample)
