"""Stored samples at start: one Zenoh query on a subscription's key, answered by whatever stores the topic.

A fleet keeps its shared map in the router's storage (zenohd's storage manager, docs/FLEET.md). A daemon that
starts after the map was published asks the network once with ``get`` on the key it subscribes to; the storage
answers with the latest map, which goes through the same handler as a live sample. A live sample that arrived
first wins: stored answers are dropped once the topic has received anything.
"""

from __future__ import annotations

import logging
from collections.abc import Callable

import zenoh

log = logging.getLogger(__name__)

#: How long the query for stored samples stays open [s] (replies are handled as they come, nothing waits).
FETCH_TIMEOUT_S = 5.0


def fetch_stored(session: zenoh.Session, key: str, on_sample: Callable[[zenoh.Sample], None],
                 received: Callable[[], int], timeout: float = FETCH_TIMEOUT_S) -> None:
    """Query ``key`` once without blocking; hand each stored sample to ``on_sample`` while ``received()`` (the
    topic's count of samples handled so far) is still 0."""

    def on_reply(reply: zenoh.Reply) -> None:
        sample = reply.ok
        if sample is None or received() > 0:
            return
        log.info("%s: taking the stored sample", sample.key_expr)
        on_sample(sample)

    try:
        session.get(key, on_reply, target=zenoh.QueryTarget.ALL, timeout=timeout)
    except zenoh.ZError as exc:  # a closing session: nothing stored to fetch
        log.debug("%s: query for stored samples failed: %s", key, exc)
