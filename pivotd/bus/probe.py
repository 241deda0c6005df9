"""A bus observer that records what pivotd publishes and the poses it is fed, e.g. for the demo's analysis.

:class:`BusProbe` subscribes with plain Zenoh subscribers (any type hash, no liveliness tokens, so it does
not show up as a ROS node) to the joint states, view plan and status pivotd publishes and to the pose
topic it listens on. It keeps everything it receives (meant for runs of minutes, not for days).
"""

from __future__ import annotations

import json
import logging
import threading
import time
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import zenoh

from pivotd.bus import messages as m
from pivotd.bus.ros import topic_key
from pivotd.bus.session import open_session
from pivotd.bus.topics import BusTopics, bridge_key, normalize_topic

log = logging.getLogger(__name__)


@dataclass
class Observations:
    """A snapshot of what a probe saw: poses (rx time [s], position (3,) [m], quat (4,) (x, y, z, w)),
    measured joints (rx time [s], pan [rad], tilt [rad]) and the latest status document.
    Reception times are ``time.monotonic()``."""

    poses: list[tuple[float, np.ndarray, np.ndarray]] = field(default_factory=list)
    joints: list[tuple[float, float, float]] = field(default_factory=list)
    status: dict = field(default_factory=dict)


class BusProbe:
    """Records pivotd's outputs and inputs on ``session`` for the topics and status key of ``topics``.

    Attributes (append-only, filled on Zenoh threads): ``joints``: (rx time [s], pan [rad], tilt [rad],
    key expression, rmw_zenoh attachment bytes or None) per JointState; ``poses``: (rx time [s], position
    (3,) [m], quat (4,)) per pose pivotd would accept (malformed, non-finite or wrong-frame poses are
    skipped); ``plans``: one :class:`~pivotd.bus.messages.PathMsg` per view plan; ``statuses``: every
    status document. Use :meth:`connect` for a probe with its own session, and :meth:`close` when done.
    """

    def __init__(self, session: zenoh.Session, topics: BusTopics) -> None:
        self.session = session
        self.topics = topics
        self.joints: list[tuple[float, float, float, str, bytes | None]] = []
        self.poses: list[tuple[float, np.ndarray, np.ndarray]] = []
        self.plans: list[m.PathMsg] = []
        self.statuses: list[dict] = []
        self.lock = threading.Lock()
        self._own_session = False
        t = topics
        self._subs: list[Any] = []
        try:
            for key, handler in (
                (_key(t, t.joint_states, m.JOINT_STATE), self._on_joint),
                (_key(t, t.pose, t.pose_type), self._on_pose),
                (_key(t, t.view_plan, m.PATH), self._on_plan),
                (t.status_key, self._on_status),
            ):
                self._subs.append(session.declare_subscriber(key, handler))
        except Exception:
            self.close()
            raise

    @classmethod
    def connect(cls, endpoint: str, topics: BusTopics) -> BusProbe:
        """A probe on a new peer session connected to ``endpoint`` (e.g. ``tcp/127.0.0.1:7447``); closing the
        probe closes the session."""
        session = open_session(connect=[endpoint])
        try:
            probe = cls(session, topics)
        except Exception:
            session.close()
            raise
        probe._own_session = True
        return probe

    # ------------------------------------------------------------------ subscriptions

    def _on_joint(self, sample: zenoh.Sample) -> None:
        rx = time.monotonic()
        try:
            msg = m.deserialize(sample.payload.to_bytes(), m.JOINT_STATE, normalize_topic(self.topics.joint_states))
            pan, tilt = float(msg.position[0]), float(msg.position[1])  # type: ignore[attr-defined]
        except (m.MessageError, IndexError) as exc:
            log.debug("skipped joint state: %s", exc)
            return
        att = sample.attachment.to_bytes() if sample.attachment is not None else None
        with self.lock:
            self.joints.append((rx, pan, tilt, str(sample.key_expr), att))

    def _on_pose(self, sample: zenoh.Sample) -> None:
        t = self.topics
        try:
            pose = m.decode_pose(sample.payload.to_bytes(), t.pose_type, normalize_topic(t.pose), t.frame_id,
                                 t.accept_empty_frame)
        except m.MessageError as exc:
            log.debug("skipped pose: %s", exc)
            return
        with self.lock:
            self.poses.append((pose.rx_time, pose.position, pose.quat))

    def _on_plan(self, sample: zenoh.Sample) -> None:
        try:
            plan = m.decode_path(sample.payload.to_bytes(), normalize_topic(self.topics.view_plan), None)
        except m.MessageError as exc:
            log.debug("skipped view plan: %s", exc)
            return
        with self.lock:
            self.plans.append(plan)

    def _on_status(self, sample: zenoh.Sample) -> None:
        try:
            doc = json.loads(sample.payload.to_bytes())
        except ValueError as exc:
            log.debug("skipped status: %s", exc)
            return
        with self.lock:
            self.statuses.append(doc)

    # ------------------------------------------------------------------ access

    @property
    def status(self) -> dict:
        """The latest status document ({} before the first)."""
        with self.lock:
            return self.statuses[-1] if self.statuses else {}

    def query_status(self, timeout: float = 3.0) -> dict | None:
        """Ask the status queryable; the first answer, or None when none came within ``timeout`` [s]."""
        for reply in self.session.get(self.topics.status_key, timeout=timeout):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        return None

    def observations(self) -> Observations:
        """A copy of the poses, the joints (without key and attachment) and the latest status."""
        with self.lock:
            return Observations(poses=list(self.poses), joints=[j[:3] for j in self.joints],
                                status=self.statuses[-1] if self.statuses else {})

    def close(self) -> None:
        """Undeclare the subscribers (and close the session when :meth:`connect` opened it)."""
        subs, self._subs = self._subs, []
        for sub in subs:
            sub.undeclare()
        if self._own_session:
            self._own_session = False
            self.session.close()

    def __enter__(self) -> BusProbe:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _key(topics: BusTopics, topic: str, msgtype: str) -> str:
    """The data key of ``topic`` on the configured wire (rmw_zenoh: any hash; the bridge: the plain key)."""
    return bridge_key(topic) if topics.bridged else topic_key(topics.domain_id, topic, msgtype, "*")
