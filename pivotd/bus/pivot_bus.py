"""The daemon-facing bus facade: ROS 2 topics in and out over Zenoh, plus the JSON status key.

:class:`PivotBus` declares one rmw_zenoh node (with ``topics.wire: ros2dds_bridge``: the plain keys of
zenoh-bridge-ros2dds, :mod:`pivotd.bus.ros2dds`) with subscriptions for the pose (the pose topic, or with
``topics.pose_source: tf`` the ``/tf`` and ``/tf_static`` topics the pose is composed from, :mod:`pivotd.bus.tf_pose`),
path, landmarks and targets, publishers for joint states and the view plan, and a plain Zenoh publisher + queryable for
status. The map layers also take the latest stored sample at start (:mod:`pivotd.bus.stored`).
Subscription callbacks run on Zenoh's threads and only check the message type and the payload
size (``topics.max_*_bytes``) before queueing the raw payload (:mod:`pivotd.bus.inbox`, newest kept);
two decoding threads (poses; paths and clouds) decode, validate and hand the typed message to the
daemon's callback. Anything wrong is dropped, counted and logged (rate limited).
"""

from __future__ import annotations

import contextlib
import json
import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import numpy as np
import zenoh

from pivotd.bus import messages as m
from pivotd.bus.inbox import Decoder, Inbox
from pivotd.bus.qos import QoS, TopicQoS
from pivotd.bus.ratelimit import RateLimitedLog
from pivotd.bus.ros import Attachment, RosNode, RosPublisher, msgtype_of_key
from pivotd.bus.ros2dds import BridgeNode, BridgePublisher
from pivotd.bus.stored import fetch_stored
from pivotd.bus.tf_pose import TfPose
from pivotd.bus.topics import CLOCK_TOPIC, BusTopics, normalize_topic

log = logging.getLogger(__name__)

CLOUD_LAYERS = ("landmarks", "targets")
#: Payloads each input topic may hold while waiting to be decoded. Every input is a state whose newest
#: message supersedes the older ones (pose, path, a whole cloud layer), so only the newest is kept.
INBOX_CAPACITY = 1
#: A payload at least this large [bytes] was reassembled by Zenoh in many small buffers; once it is dropped or
#: decoded, :meth:`PivotBus.large_payload_seen` says so, and the daemon gives the freed heap back to the OS.
LARGE_PAYLOAD_BYTES = 1 << 20
#: Largest ``/clock`` payload [bytes] (a Clock is 12 bytes of CDR).
MAX_CLOCK_BYTES = 256
#: QoS of the ``/clock`` subscription: rclcpp's ``ClockQoS`` (best effort, keep last 1).
CLOCK_QOS = QoS.named("best_effort", "volatile", 1)
#: Payloads ``/tf`` and ``/tf_static`` may each hold while waiting to be decoded: unlike the other inputs, one TF
#: topic carries many frame pairs from many publishers, so a message does not supersede the one before it.
TF_INBOX_CAPACITY = 64


class PivotBus:
    """pivotd's presence on the bus. Construct with an open session; call :meth:`close` when done.

    Callbacks: ``on_pose(PoseSample)``, ``on_path(PathMsg)``, ``on_cloud(layer, CloudMsg)`` with layer
    ``"landmarks"`` or ``"targets"``. They run on the bus's decoding threads (poses on one, paths and clouds on
another) and should be short. ``on_raw(topic, msgtype,
    cdr)`` (e.g. for an MCAP recorder) sees every accepted input and every published ROS message; on the
    publishing side it runs on the caller's thread. ``tf_timeout`` [s]: with the pose from TF, a dynamic link of
    the chain not received for this long makes the pose stale (the daemon passes ``control.pose_timeout_s``).
    """

    def __init__(self, session: zenoh.Session, topics: BusTopics, node_name: str = "pivotd",
                 on_pose: Callable[[m.PoseSample], None] | None = None,
                 on_path: Callable[[m.PathMsg], None] | None = None,
                 on_cloud: Callable[[str, m.CloudMsg], None] | None = None,
                 on_raw: Callable[[str, str, bytes], None] | None = None, qos: TopicQoS | None = None,
                 tf_timeout: float = 0.5) -> None:
        self.topics = topics
        self.qos = qos = qos or TopicQoS()
        self.session = session
        self._on_pose, self._on_path, self._on_cloud, self._on_raw = on_pose, on_path, on_cloud, on_raw
        self._lock = threading.Lock()
        self._counters: dict[str, dict[str, int]] = {}
        self._ratelog = RateLimitedLog(log)
        self._status_json = b""
        self._closed = False
        self._large_seen = threading.Event()
        self.node_name = node_name
        # the wire fork: rmw_zenoh's keys, attachments and tokens, or zenoh-bridge-ros2dds's plain keys
        self.node: RosNode | BridgeNode = (
            BridgeNode(session, topics.namespace) if topics.bridged
            else RosNode(session, node_name, topics.domain_id, topics.namespace, humble=topics.humble))
        self._entities: list[Any] = []
        self._takers: dict[str, Callable[[bytes, float], None]] = {}
        self._msgtypes: dict[str, str] = {}
        self._own_gids: set[str] = set()  # this bus's publishers on its input topics: their samples are not inputs
        self.map_publisher: RosPublisher | None = None  # declared by the first publish_map()
        self._sim_time: float | None = None  # [s] the last /clock received (topics.use_sim_time)
        # Poses are decoded on their own thread so that a large path or cloud never delays them.
        self._pose_inbox, self._bulk_inbox = Inbox(), Inbox()
        self._decoders: list[Decoder] = []
        self.tf_pose: TfPose | None = None
        m.warm_up()
        try:
            if topics.pose_from_tf:
                self.tf_pose = TfPose(topics.map_frame, topics.base_frame, tf_timeout, topics.tf_max_frames,
                                      self._count, on_pose)
                # /tf_static first: the decoder serves topics in that order, so a busy /tf cannot starve it
                for topic, static, topic_qos in ((topics.tf_static, True, qos.pose_tf_static),
                                                 (topics.tf, False, qos.pose_tf)):
                    self._entities.append(self.node.subscriber(topic, m.TF_MESSAGE, self._handler(
                        topic, m.TF_MESSAGE, self._tf_taker(topic, static), self._pose_inbox, topics.max_tf_bytes,
                        TF_INBOX_CAPACITY, with_source=True), topic_qos, any_type=True))
            else:
                self._entities.append(self.node.subscriber(topics.pose, topics.pose_type, self._handler(
                    topics.pose, topics.pose_type, self._take_pose, self._pose_inbox, topics.max_pose_bytes),
                    qos.pose, any_type=True))
            self._entities.append(self.node.subscriber(topics.path, m.PATH, self._handler(
                topics.path, m.PATH, self._take_path, self._bulk_inbox, topics.max_path_bytes), qos.path,
                any_type=True))
            for layer in CLOUD_LAYERS:
                topic = getattr(topics, layer)
                handler = self._handler(topic, m.POINT_CLOUD2, self._cloud_taker(layer), self._bulk_inbox,
                                        topics.max_cloud_bytes)
                sub = self.node.subscriber(topic, m.POINT_CLOUD2, handler, getattr(qos, layer), any_type=True)
                self._entities.append(sub)
                fetch_stored(session, sub.key, handler, lambda t=sub.topic: self._received(t))
            if topics.use_sim_time:
                self._entities.append(self.node.subscriber(CLOCK_TOPIC, m.CLOCK, self._handler(
                    CLOCK_TOPIC, m.CLOCK, self._take_clock, self._pose_inbox, MAX_CLOCK_BYTES), CLOCK_QOS,
                    any_type=True))
            self._decoders = [Decoder(self._pose_inbox, self._decode, f"{node_name}-pose-decoder"),
                              Decoder(self._bulk_inbox, self._decode, f"{node_name}-bulk-decoder")]
            # Public for observers (liveliness, matching); publish through the methods below.
            self.joint_state_publisher = self.node.publisher(topics.joint_states, m.JOINT_STATE, qos.joint_states)
            self.view_plan_publisher = self.node.publisher(topics.view_plan, m.PATH, qos.view_plan)
            self._entities += [self.joint_state_publisher, self.view_plan_publisher]
            self.status_publisher = session.declare_publisher(topics.status_key)
            self._status_queryable = session.declare_queryable(topics.status_key, self._answer_status, complete=True)
        except Exception:
            self.close()
            raise
        clock = (CLOCK_TOPIC,) if topics.use_sim_time else ()
        for topic in (*self.pose_topics, topics.path, topics.landmarks, topics.targets, *clock):
            self._counters.setdefault(normalize_topic(topic), {"received": 0, "accepted": 0})

    # ------------------------------------------------------------------ inputs

    @property
    def pose_topics(self) -> tuple[str, ...]:
        """The topics the pose comes from: the pose topic, or ``tf`` and ``tf_static``."""
        t = self.topics
        return (normalize_topic(t.tf), normalize_topic(t.tf_static)) if t.pose_from_tf else (normalize_topic(t.pose),)

    def _handler(self, topic: str, msgtype: str, take: Callable[..., None], inbox: Inbox, max_bytes: int,
                 capacity: int = INBOX_CAPACITY, with_source: bool = False) -> Callable[[zenoh.Sample], None]:
        """The Zenoh callback of an input topic: type and size checks only, then the raw payload goes to
        ``inbox`` for the decoding thread (nothing is decoded on Zenoh's thread). ``take(payload, rx)``, or with
        ``with_source`` ``take(payload, rx, source)`` with the publisher's GID in hex ("" without an rmw_zenoh
        attachment)."""
        name = normalize_topic(topic)
        self._takers[name] = take
        self._msgtypes[name] = msgtype
        inbox.add_topic(name, capacity)
        bridged = self.topics.bridged

        def on_sample(sample: zenoh.Sample) -> None:
            if self._own_gids and _publisher_id(sample) in self._own_gids:
                return  # what this bus published itself (the map on the landmarks topic)
            rx = time.monotonic()
            self._count(name, "received")
            got = msgtype if bridged else msgtype_of_key(str(sample.key_expr))  # the bridge's keys name no type
            if got != msgtype:
                self._drop(name, "wrong_type", f"{name}: message of type {got or '?'} on a {msgtype} topic")
                return
            size = len(sample.payload)
            if size >= LARGE_PAYLOAD_BYTES:
                self._large_seen.set()
            if size > max_bytes:
                self._drop(name, "too_large", f"{name}: payload of {size} bytes exceeds the {max_bytes}-byte limit")
                return
            item = (sample.payload.to_bytes(), rx, *((_publisher_id(sample),) if with_source else ()))
            if not inbox.put(name, item) and not self._closed:
                # normal under load: every input is a state, the newer message supersedes the undecoded one
                self._count(name, "superseded")
                log.debug("%s: a newer message superseded one not yet decoded", name)

        return on_sample

    def _decode(self, name: str, item: tuple) -> None:
        """Decode one queued payload (decoding thread): typed message to the daemon's callback, counted. ``item``:
        (payload, reception time [s]) and, for the TF topics, the publisher's id."""
        payload, rx, *extra = item
        try:
            self._takers[name](payload, rx, *extra)
            if self._on_raw is not None:
                self._on_raw(name, self._msgtypes[name], payload)
        except m.MessageError as exc:
            self._drop(name, exc.reason, f"dropped message: {exc}")
            return
        except Exception as exc:  # a failing daemon callback must not stop the decoding thread
            self._count(name, "dropped_callback_error")
            self._ratelog.warning(f"{name}:callback", f"{name}: handler failed: {exc!r}")
            log.debug("handler failure", exc_info=True)
            return
        finally:
            if len(payload) >= LARGE_PAYLOAD_BYTES:
                self._large_seen.set()  # its decoding temporaries are free now too
        self._count(name, "accepted")

    def large_payload_seen(self) -> bool:
        """Whether a payload of at least :data:`LARGE_PAYLOAD_BYTES` arrived or was decoded since the last call
        (which clears it): the moment to give freed memory back to the OS."""
        seen = self._large_seen.is_set()
        self._large_seen.clear()
        return seen

    def _drop(self, name: str, reason: str, message: str) -> None:
        self._count(name, f"dropped_{reason}")
        self._ratelog.warning(f"{name}:{reason}", message)

    def _take_pose(self, payload: bytes, rx: float) -> None:
        t = self.topics
        sample = m.decode_pose(payload, t.pose_type, normalize_topic(t.pose), t.frame_id, t.accept_empty_frame, rx)
        if self._on_pose is not None:
            self._on_pose(sample)

    def _tf_taker(self, topic: str, static: bool) -> Callable[[bytes, float, str], None]:
        name = normalize_topic(topic)

        def take(payload: bytes, rx: float, source: str) -> None:
            assert self.tf_pose is not None
            self.tf_pose.take(name, payload, rx, static, source)

        return take

    def _take_clock(self, payload: bytes, rx: float) -> None:
        t = m.decode_clock(payload, CLOCK_TOPIC)
        if self._sim_time is None:
            log.info("%s: simulation time %.3f s received; stamps follow it", CLOCK_TOPIC, t)
        self._sim_time = t

    def now(self) -> float | None:
        """The time [s] to stamp published messages with: the wall clock (UNIX epoch), or with
        ``topics.use_sim_time`` the last ``/clock`` received (None before the first, as a ROS node's time is
        0 until then)."""
        return self._sim_time if self.topics.use_sim_time else time.time()

    def _take_path(self, payload: bytes, rx: float) -> None:
        t = self.topics
        path = m.decode_path(payload, normalize_topic(t.path), t.frame_id, t.accept_empty_frame)
        if self._on_path is not None:
            self._on_path(path)

    def _cloud_taker(self, layer: str) -> Callable[[bytes, float], None]:
        def take(payload: bytes, rx: float) -> None:
            t = self.topics
            cloud = m.decode_cloud(payload, normalize_topic(getattr(t, layer)), t.frame_id, t.max_cloud_points,
                                   t.accept_empty_frame)
            if self._on_cloud is not None:
                self._on_cloud(layer, cloud)

        return take

    def _count(self, topic: str, what: str) -> None:
        with self._lock:
            c = self._counters.setdefault(topic, {"received": 0, "accepted": 0})
            c[what] = c.get(what, 0) + 1

    def _received(self, topic: str) -> int:
        with self._lock:
            return self._counters.get(topic, {}).get("received", 0)

    def counters(self) -> dict[str, dict[str, int]]:
        """Per input topic: ``received``, ``accepted``, ``superseded`` (replaced by a newer message before it was
        decoded: normal, not a drop; present once it happened) and ``dropped_<reason>`` counts (a copy).

        Reasons: ``wrong_type``, ``too_large`` (above the payload limit, not decoded), ``callback_error`` and the
        decoders' reasons (:class:`~pivotd.bus.messages.MessageError`). On the TF topics, the transforms the TF tree
        drops are counted too, one per transform (:data:`~pivotd.bus.tf_tree.TRANSFORM_DROPS`: ``loop``,
        ``two_parents``, ...)."""
        with self._lock:
            return {topic: dict(c) for topic, c in self._counters.items()}

    # ------------------------------------------------------------------ outputs

    def publish_joint_state(self, stamp: float, pan: float, tilt: float, pan_rate: float, tilt_rate: float) -> None:
        """Publish the measured gimbal state: angles [rad], rates [rad/s], stamp [s since the epoch]."""
        payload = m.encode_joint_state(stamp, list(self.topics.joint_names), [pan, tilt], [pan_rate, tilt_rate])
        self._put(self.joint_state_publisher, payload)

    def publish_view_plan(self, stamp: float, positions: np.ndarray, directions: np.ndarray) -> None:
        """Publish the view plan: camera positions (N, 3) [m] and unit view directions (N, 3) in the map frame."""
        frame = self.topics.frame_id or "map"
        self._put(self.view_plan_publisher, m.encode_view_plan(stamp, frame, positions, directions))

    def publish_map(self, stamp: float, points: np.ndarray, weights: np.ndarray | None) -> None:
        """Latch map landmarks (N, 3) [m] in the map frame with their weights (N,) on the landmarks topic: a
        ``PointCloud2`` (float32 x, y, z, weight) with the landmarks subscription's QoS (transient local by default,
        so a display started later gets it). This bus ignores it as input (its own publisher's GID), and it is not
        recorded (``on_raw``): a recording's landmarks-topic cloud is a map received over the bus."""
        if self._closed or self.topics.bridged:  # behind the bridge its own samples could not be told apart
            return
        if self.map_publisher is None:
            pub = self.node.publisher(self.topics.landmarks, m.POINT_CLOUD2, self.qos.landmarks)
            self._entities.append(pub)
            self._own_gids.add(pub.gid.hex())
            self.map_publisher = pub
        frame = self.topics.frame_id or "map"
        self._put(self.map_publisher, m.encode_cloud(stamp, frame, points, weights), record=False)

    def add_publisher(self, topic: str, msgtype: str, qos: QoS) -> RosPublisher | BridgePublisher:
        """Declare another ROS publisher of pivotd's node (closed with the bus); publish with :meth:`put`."""
        pub = self.node.publisher(topic, msgtype, qos)
        self._entities.append(pub)
        return pub

    def put(self, pub: RosPublisher | BridgePublisher, payload: bytes) -> None:
        """Publish a CDR payload on a publisher of this bus (recorded like the bus's own outputs)."""
        self._put(pub, payload)

    def _put(self, pub: Any, payload: bytes, record: bool = True) -> None:
        # Publishing races with close() at shutdown; a closed bus or session drops the message quietly.
        if self._closed:
            return
        try:
            pub.put(payload)
            if record and self._on_raw is not None:
                self._on_raw(pub.topic, pub.msgtype, payload)
        except zenoh.ZError as exc:
            self._ratelog.warning(f"put:{pub.topic}", f"{pub.topic}: publish failed: {exc}")

    def publish_status(self, status: dict) -> None:
        """Publish ``status`` as JSON on the status key and keep it as the queryable's answer.

        The bus adds its counters under ``"bus"`` unless the dict already has that key. numpy values become
        numbers/lists, other non-JSON values their ``str()``.
        """
        doc = dict(status)
        doc.setdefault("bus", self.counters())
        if self.tf_pose is not None:
            doc.setdefault("tf", self.tf_pose.status())
        payload = json.dumps(doc, default=_json_default, separators=(",", ":")).encode()
        with self._lock:
            self._status_json = payload
        if self._closed:
            return
        try:
            self.status_publisher.put(payload, encoding=zenoh.Encoding.APPLICATION_JSON)
        except zenoh.ZError as exc:
            self._ratelog.warning("put:status", f"{self.topics.status_key}: publish failed: {exc}")

    def _answer_status(self, query: zenoh.Query) -> None:
        with self._lock:
            payload = self._status_json
        if not payload:
            payload = json.dumps({"name": self.node_name, "state": "starting", "bus": self.counters()}).encode()
        try:
            query.reply(self.topics.status_key, payload, encoding=zenoh.Encoding.APPLICATION_JSON)
        except zenoh.ZError as exc:
            self._ratelog.warning("status-query", f"status query reply failed: {exc}")

    # ------------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Undeclare every publisher, subscriber, queryable and liveliness token (the session stays open)."""
        if self._closed:
            return
        self._closed = True
        for entity in reversed(self._entities):
            entity.close()
        for decoder in self._decoders:
            decoder.close()
        for attr in ("_status_queryable", "status_publisher"):
            obj = getattr(self, attr, None)
            if obj is not None:
                with contextlib.suppress(zenoh.ZError):
                    obj.undeclare()
        self.node.close()

    def __enter__(self) -> PivotBus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _publisher_id(sample: zenoh.Sample) -> str:
    """The GID (hex) in a sample's rmw_zenoh attachment; "" when it has none."""
    att = sample.attachment
    if att is None:
        return ""
    try:
        return Attachment.decode(att.to_bytes()).gid.hex()
    except ValueError:
        return ""


def _json_default(obj: object) -> Any:
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    return str(obj)  # enums, paths, ...: readable rather than fatal
