"""zenoh-bridge-ros2dds wire conventions: topics of a DDS robot as the bridge routes them to Zenoh.

The bridge (github.com/eclipse-zenoh/zenoh-plugin-ros2dds, docs/ROS2.md §DDS robots) maps each DDS topic to
the plain key ``<namespace>/<topic>`` (:func:`pivotd.bus.topics.bridge_key`; no domain, type or hash) with the
bare CDR payload, sends no attachment and ignores the attachments of what it routes to DDS, and declares no
rmw_zenoh liveliness tokens. :class:`BridgeNode` offers :class:`~pivotd.bus.ros.RosNode`'s ``publisher`` and
``subscriber`` on those keys, so :class:`~pivotd.bus.pivot_bus.PivotBus` forks only where it makes its node.

``TRANSIENT_LOCAL`` topics: bridges from 1.5.1 route them through zenoh-ext's advanced publisher (a cache and
publisher detection) and advanced subscriber (history, late-publisher detection), the entities
:mod:`pivotd.bus.durable` declares; earlier bridges through a ``PublicationCache`` whose queryable is on
``<key>/@ros2_pub_cache/<bridge zid>`` and a querying subscriber that asks ``<key>/@ros2_pub_cache/*``
(:data:`LEGACY_CACHE_CHUNK`). pivotd does both: a transient-local subscription also asks the legacy queryables
once at start, and a transient-local publisher also answers on its own legacy queryable.
"""

from __future__ import annotations

import collections
import itertools
import logging
import threading
from collections.abc import Callable
from typing import Any

import zenoh

from pivotd.bus.durable import DataPublisher, declare_subscriber
from pivotd.bus.qos import QoS
from pivotd.bus.topics import bridge_key, bridge_topic, normalize_namespace

log = logging.getLogger(__name__)

#: The chunk after a topic's key under which bridges before 1.5.1 serve their cache of transient-local samples.
LEGACY_CACHE_CHUNK = "@ros2_pub_cache"
#: How long the start-up query of the legacy caches stays open [s] (the bridge's default query timeout).
LEGACY_QUERY_TIMEOUT_S = 5.0


def legacy_cache_selector(key: str, zid: str = "*") -> str:
    """Key of the legacy publication cache queryable of ``key``: ``<key>/@ros2_pub_cache/<zid>``."""
    return f"{key}/{LEGACY_CACHE_CHUNK}/{zid}"


class BridgeNode:
    """Publishers and subscribers on the keys zenoh-bridge-ros2dds with ``namespace`` uses (no node token).

    Topic names go through :func:`~pivotd.bus.topics.bridge_topic`, so names already routed (under the
    namespace) and the robot's own names both land on the bridge's key.
    """

    def __init__(self, session: zenoh.Session, namespace: str = "/") -> None:
        self.session = session
        self.namespace = normalize_namespace(namespace)

    def publisher(self, topic: str, msgtype: str, qos: QoS | None = None) -> BridgePublisher:
        return BridgePublisher(self, topic, msgtype, qos or QoS())

    def subscriber(self, topic: str, msgtype: str, callback: Callable[[zenoh.Sample], None],
                   qos: QoS | None = None, any_type: bool = False) -> BridgeSubscriber:
        """``any_type`` is accepted for :class:`~pivotd.bus.ros.RosNode`'s signature: the bridge's keys carry no
        type, so every message on the topic arrives anyway."""
        return BridgeSubscriber(self, topic, msgtype, callback, qos or QoS())

    def close(self) -> None:
        """Nothing to withdraw: the bridge's keys have no node liveliness token."""


class BridgePublisher:
    """Publishes bare CDR payloads on a topic's bridge key, without attachment.

    Transient local: the advanced publisher's cache (bridges from 1.5.1) and a queryable on the legacy cache key
    answering the last ``qos.depth`` payloads (earlier bridges).
    """

    def __init__(self, node: BridgeNode, topic: str, msgtype: str, qos: QoS) -> None:
        self.topic = bridge_topic(topic, node.namespace)
        self.msgtype = msgtype
        self.key = bridge_key(self.topic)
        self.qos = qos
        self._seq = itertools.count(1)
        self._lock = threading.Lock()
        self._last: collections.deque[bytes] = collections.deque(maxlen=qos.depth)
        self._pub = DataPublisher(node.session, self.key, qos)
        self._queryable: Any = None
        if qos.transient_local:
            try:
                self._queryable = node.session.declare_queryable(
                    legacy_cache_selector(self.key, str(node.session.info.zid())), self._answer)
            except Exception:
                self._pub.undeclare()
                raise

    def put(self, cdr: bytes) -> int:
        """Publish one serialized message; returns its sequence number (counted here, not sent)."""
        payload = bytes(cdr)
        with self._lock:
            seq = next(self._seq)
            self._pub.put(payload, attachment=None)
            if self._queryable is not None:
                self._last.append(payload)
        return seq

    def _answer(self, query: zenoh.Query) -> None:
        with self._lock:
            payloads = list(self._last)
        for payload in payloads:
            try:
                query.reply(self.key, payload)
            except zenoh.ZError as exc:
                log.debug("%s: legacy cache reply failed: %s", self.key, exc)

    def matched(self) -> bool:
        """True while at least one Zenoh subscriber matches this publisher's key."""
        return self._pub.matched()

    def close(self) -> None:
        for entity in (self._queryable, self._pub):
            if entity is not None:
                try:
                    entity.undeclare()
                except zenoh.ZError as exc:  # session already closed
                    log.debug("undeclare failed: %s", exc)


class BridgeSubscriber:
    """Subscribes to a topic's bridge key; transient local also with history and one query of the legacy caches.

    Legacy cache replies reach ``callback`` only while no live or history sample has (the newest state wins).
    """

    def __init__(self, node: BridgeNode, topic: str, msgtype: str, callback: Callable[[zenoh.Sample], None],
                 qos: QoS) -> None:
        self.topic = bridge_topic(topic, node.namespace)
        self.msgtype = msgtype
        self.key = bridge_key(self.topic)
        self.qos = qos
        self._callback = callback
        self._seen = threading.Event()
        self._sub = declare_subscriber(node.session, self.key, self._on_sample, qos)
        if qos.transient_local:
            try:
                node.session.get(legacy_cache_selector(self.key), self._on_reply, target=zenoh.QueryTarget.ALL,
                                 consolidation=zenoh.ConsolidationMode.NONE, accept_replies=zenoh.ReplyKeyExpr.ANY,
                                 timeout=LEGACY_QUERY_TIMEOUT_S)
            except zenoh.ZError as exc:  # a closing session: nothing cached to fetch
                log.debug("%s: query of the bridge's cache failed: %s", self.key, exc)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        self._seen.set()
        self._callback(sample)

    def _on_reply(self, reply: zenoh.Reply) -> None:
        sample = reply.ok
        if sample is None or self._seen.is_set():
            return
        log.info("%s: taking the sample cached by the bridge", self.key)
        self._callback(sample)

    def close(self) -> None:
        try:
            self._sub.undeclare()
        except zenoh.ZError as exc:
            log.debug("undeclare failed: %s", exc)
