"""Zenoh entities for a ROS topic's durability, as rmw_zenoh declares them.

``VOLATILE`` topics use plain Zenoh publishers and subscribers. ``TRANSIENT_LOCAL`` topics use
zenoh-ext's advanced entities, configured like rmw_zenoh's:

* publisher: a cache of the last ``depth`` samples (answered to late subscribers, attachments
  included), publisher detection (a liveliness token that advanced subscribers watch), and for
  ``RELIABLE`` a sporadic heartbeat so subscribers detect and recover missed samples;
* subscriber: history of up to ``depth`` samples per publisher, queried at declaration and again for
  every publisher that appears later (late-publisher detection), subscriber detection, and for
  ``RELIABLE`` recovery driven by the publishers' heartbeats.

So pivotd gets a topic's latest sample whichever side starts first. Advanced publishers without
sample-miss detection stamp samples with the session's clock, which needs Zenoh ``timestamping``
(enabled in sessions pivotd builds, as in rmw_zenoh's default config); with a user Zenoh config
file that leaves it off, a best-effort transient-local publisher numbers its samples instead.
"""

from __future__ import annotations

import logging
from collections.abc import Callable
from typing import Any

import zenoh
import zenoh.ext as zext

from pivotd.bus.qos import QoS

log = logging.getLogger(__name__)

#: Period [s] of the sporadic heartbeat of reliable transient-local publishers.
HEARTBEAT_S = 1.0


def _reliability(qos: QoS) -> zenoh.Reliability:
    return zenoh.Reliability.RELIABLE if qos.reliable else zenoh.Reliability.BEST_EFFORT


def _miss_detection() -> zext.MissDetectionConfig:
    return zext.MissDetectionConfig(heartbeat=None, sporadic_heartbeat=HEARTBEAT_S)


class DataPublisher:
    """A topic's Zenoh publisher: plain (volatile) or advanced (transient local). ``put`` and ``matched``
    behave the same for both."""

    def __init__(self, session: zenoh.Session, key: str, qos: QoS) -> None:
        self.key = key
        self.qos = qos
        common = {"congestion_control": zenoh.CongestionControl.DROP, "reliability": _reliability(qos)}
        self._plain: Any = session.declare_publisher(key, **common)
        self._advanced: Any = None
        if qos.transient_local:
            try:
                self._advanced = self._declare_advanced(session, key, qos, common, qos.reliable)
            except zenoh.ZError as exc:
                if qos.reliable or "timestamping" not in str(exc):
                    self._plain.undeclare()
                    raise
                log.info("%s: Zenoh timestamping is off; the transient-local publisher numbers its samples", key)
                self._advanced = self._declare_advanced(session, key, qos, common, True)

    @staticmethod
    def _declare_advanced(session: zenoh.Session, key: str, qos: QoS, common: dict, miss_detection: bool) -> Any:
        return zext.declare_advanced_publisher(
            session, key, cache=zext.CacheConfig(max_samples=qos.depth), publisher_detection=True,
            sample_miss_detection=_miss_detection() if miss_detection else None, **common)

    def put(self, payload: bytes, attachment: bytes) -> None:
        (self._advanced or self._plain).put(payload, attachment=attachment)

    def matched(self) -> bool:
        """True while at least one Zenoh subscriber matches the key (the plain publisher's matching status;
        for an advanced publisher that plain one only watches and never publishes)."""
        return bool(self._plain.matching_status.matching)

    def undeclare(self) -> None:
        if self._advanced is not None:
            self._advanced.undeclare()
        self._plain.undeclare()


def declare_subscriber(session: zenoh.Session, key: str, callback: Callable[[zenoh.Sample], None], qos: QoS) -> Any:
    """A plain subscriber for a volatile topic, an advanced one with history for a transient-local topic."""
    if not qos.transient_local:
        return session.declare_subscriber(key, callback)
    recovery = zext.RecoveryConfig(periodic_queries=None, heartbeat=True) if qos.reliable else None
    return zext.declare_advanced_subscriber(
        session, key, callback, history=zext.HistoryConfig(detect_late_publishers=True, max_samples=qos.depth),
        recovery=recovery, subscriber_detection=True)
