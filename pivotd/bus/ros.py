"""ROS 2 ``rmw_zenoh`` wire conventions: key expressions, type hashes, attachments, liveliness tokens.

Everything here is pure string/byte formatting except :class:`RosNode`, :class:`RosPublisher` and
:class:`RosSubscriber`, which declare the matching Zenoh entities on an open session.

Formats (rmw_zenoh ``docs/design.md``; docs/ROS2.md §7):

* data key: ``<domain_id>/<topic without outer slashes>/<pkg>::msg::dds_::<Type>_/<type hash>``;
  subscribers put ``*`` in the hash position.
* type hash: ``RIHS01_<sha256 hex>`` (REP-2011), computed by ``rosbags`` from its type definitions.
* attachment (33 bytes): int64 LE sequence number, int64 LE source timestamp [ns since the UNIX
  epoch], one length byte (16), then the 16-byte publisher GID (rmw_zenoh's, :mod:`pivotd.bus.ros_gid`).
* ``TRANSIENT_LOCAL`` publishers and subscriptions are zenoh-ext advanced entities
  (:mod:`pivotd.bus.durable`).
* liveliness token: ``@ros2_lv/<domain>/<zid>/<node_id>/<entity_id>/<kind>/<enclave>/<namespace>/
  <node>[/<topic>/<type>/<hash>/<qos>]`` with ``/`` in names replaced by ``%``.
"""

from __future__ import annotations

import functools
import itertools
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass

import zenoh
from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.store import Typestore

from pivotd.bus.durable import DataPublisher, declare_subscriber
from pivotd.bus.qos import (  # noqa: F401  (re-exported: the rmw QoS names are part of this module's API)
    DURABILITY_TRANSIENT_LOCAL,
    DURABILITY_VOLATILE,
    HISTORY_KEEP_ALL,
    HISTORY_KEEP_LAST,
    RELIABILITY_BEST_EFFORT,
    RELIABILITY_RELIABLE,
    QoS,
)
from pivotd.bus.ros_gid import GID_SIZE, rmw_zenoh_gid
from pivotd.bus.topics import normalize_topic
from pivotd.errors import ConfigError

log = logging.getLogger(__name__)

ADMIN_SPACE = "@ros2_lv"
ATTACHMENT_SIZE = 8 + 8 + 1 + GID_SIZE
_ATTACHMENT = struct.Struct("<qqB")

NODE, PUBLISHER, SUBSCRIPTION = "NN", "MP", "MS"
# What rmw_zenoh on ROS 2 Humble (no type hashes in that distribution) puts in the hash position.
NO_TYPE_HASH = "TypeHashNotSupported"


@functools.cache
def typestore() -> Typestore:
    """The shared rosbags type store (ROS 2 Jazzy definitions, the first distribution with type hashes)."""
    return get_typestore(Stores.ROS2_JAZZY)


@functools.cache
def type_hash(msgtype: str) -> str:
    """RIHS01 type hash (``RIHS01_`` + 64 hex digits) of ``msgtype`` such as ``"sensor_msgs/msg/JointState"``."""
    try:
        return typestore().hash_rihs01(msgtype)
    except KeyError as exc:
        raise ConfigError(f"unknown ROS message type {msgtype!r}") from exc


def dds_type_name(msgtype: str) -> str:
    """DDS type name used in keys: ``"std_msgs/msg/String"`` -> ``"std_msgs::msg::dds_::String_"``."""
    parts = msgtype.strip("/").split("/")
    if len(parts) != 3 or not all(parts):
        raise ConfigError(f"ROS message type {msgtype!r} is not of the form pkg/msg/Type")
    pkg, kind, name = parts
    return f"{pkg}::{kind}::dds_::{name}_"


def ros_type_from_dds(dds_name: str) -> str | None:
    """Inverse of :func:`dds_type_name`; ``None`` when ``dds_name`` is not of that form."""
    parts = dds_name.split("::")
    if len(parts) != 4 or parts[2] != "dds_" or not parts[3].endswith("_") or len(parts[3]) < 2:
        return None
    return f"{parts[0]}/{parts[1]}/{parts[3][:-1]}"


def topic_key(domain_id: int, topic: str, msgtype: str | None, hash_part: str | None = None) -> str:
    """Data key expression for ``topic``.

    ``msgtype`` None puts ``*`` in the type position (any type); ``hash_part`` None puts the RIHS01
    hash of ``msgtype`` (publishers), ``"*"`` any hash (subscribers).
    """
    if domain_id < 0:
        raise ConfigError(f"domain id must be >= 0, got {domain_id}")
    name = normalize_topic(topic)[1:]
    type_part = "*" if msgtype is None else dds_type_name(msgtype)
    if hash_part is None:
        hash_part = "*" if msgtype is None else type_hash(msgtype)
    return f"{domain_id}/{name}/{type_part}/{hash_part}"


def mangle(name: str) -> str:
    """Replace every ``/`` by ``%`` (liveliness tokens cannot contain ROS names' slashes)."""
    return name.replace("/", "%")


# rmw_zenoh omits every field equal to its own default (reliable, volatile, keep_last 42, infinite times).
_DEFAULT_QOS = QoS(depth=42)


def qos_to_keyexpr(qos: QoS) -> str:
    """Compact QoS string of rmw_zenoh tokens, e.g. ``"::,10:,:,:,,"`` for reliable/volatile/keep_last 10."""

    def opt(value: int, default: int) -> str:
        return "" if value == default else str(value)

    d = _DEFAULT_QOS
    return (
        f"{opt(qos.reliability, d.reliability)}:{opt(qos.durability, d.durability)}:"
        f"{opt(qos.history, d.history)},{opt(qos.depth, d.depth)}:,:,:,,"
    )


def node_token_key(domain_id: int, zid: str, node_id: int, node_name: str, namespace: str = "/",
                   enclave: str = "/") -> str:
    """Liveliness key of a node (entity kind ``NN``; the entity id equals the node id)."""
    return (f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{node_id}/{NODE}/{mangle(enclave)}/{mangle(namespace)}/"
            f"{node_name}")


def entity_token_key(kind: str, domain_id: int, zid: str, node_id: int, entity_id: int, node_name: str,
                     topic: str, msgtype: str, qos: QoS, namespace: str = "/", enclave: str = "/",
                     hash_part: str | None = None) -> str:
    """Liveliness key of a publisher (``MP``) or subscription (``MS``) of ``msgtype`` on ``topic``.

    ``hash_part`` defaults to the RIHS01 hash (:data:`NO_TYPE_HASH` for Humble peers).
    """
    return (
        f"{ADMIN_SPACE}/{domain_id}/{zid}/{node_id}/{entity_id}/{kind}/{mangle(enclave)}/{mangle(namespace)}/"
        f"{node_name}/{mangle(normalize_topic(topic))}/{dds_type_name(msgtype)}/"
        f"{hash_part or type_hash(msgtype)}/{qos_to_keyexpr(qos)}"
    )


def gid_from_key(liveliness_key: str) -> bytes:
    """16-byte GID of an entity from its liveliness key, as rmw_zenoh computes it (:mod:`pivotd.bus.ros_gid`)."""
    return rmw_zenoh_gid(liveliness_key)


@dataclass(frozen=True)
class Attachment:
    """rmw_zenoh publication metadata: sequence number, source time [ns since epoch], 16-byte GID."""

    sequence: int
    source_time_ns: int
    gid: bytes

    def encode(self) -> bytes:
        """The 33-byte wire form."""
        if len(self.gid) != GID_SIZE:
            raise ValueError(f"gid must be {GID_SIZE} bytes, got {len(self.gid)}")
        return _ATTACHMENT.pack(self.sequence, self.source_time_ns, GID_SIZE) + bytes(self.gid)

    @classmethod
    def decode(cls, data: bytes) -> Attachment:
        """Parse the wire form; raises ValueError on a wrong size or GID length prefix."""
        if len(data) != ATTACHMENT_SIZE:
            raise ValueError(f"attachment has {len(data)} bytes, expected {ATTACHMENT_SIZE}")
        seq, stamp, n = _ATTACHMENT.unpack_from(data)
        if n != GID_SIZE:
            raise ValueError(f"attachment gid length prefix is {n}, expected {GID_SIZE}")
        return cls(seq, stamp, bytes(data[_ATTACHMENT.size:]))


class RosNode:
    """A ROS 2 node as seen by rmw_zenoh peers: a ``NN`` liveliness token plus its entities.

    ``node_id`` distinguishes several nodes sharing one session; entity ids count up from 10 like rclcpp's.
    ``humble`` publishes :data:`NO_TYPE_HASH` instead of RIHS01 hashes, as rmw_zenoh does on ROS 2 Humble.
    """

    def __init__(self, session: zenoh.Session, name: str, domain_id: int = 0, namespace: str = "/",
                 node_id: int = 0, humble: bool = False) -> None:
        if not name or not all(c.isalnum() or c == "_" for c in name) or name[0].isdigit():
            raise ConfigError(f"invalid ROS node name {name!r} (letters, digits and '_' only)")
        self.session = session
        self.name = name
        self.domain_id = int(domain_id)
        self.namespace = namespace if namespace.startswith("/") else "/" + namespace
        self.node_id = node_id
        self.humble = bool(humble)
        self.zid = str(session.info.zid())
        self._ids = itertools.count(10)
        self._ids_lock = threading.Lock()
        self.token_key = node_token_key(self.domain_id, self.zid, node_id, name, self.namespace)
        self._token = session.liveliness().declare_token(self.token_key)

    def hash_for(self, msgtype: str) -> str:
        """Type hash this node advertises and publishes under for ``msgtype``."""
        return NO_TYPE_HASH if self.humble else type_hash(msgtype)

    def next_entity_id(self) -> int:
        with self._ids_lock:
            return next(self._ids)

    def publisher(self, topic: str, msgtype: str, qos: QoS | None = None) -> RosPublisher:
        return RosPublisher(self, topic, msgtype, qos or QoS())

    def subscriber(self, topic: str, msgtype: str, callback: Callable[[zenoh.Sample], None],
                   qos: QoS | None = None, any_type: bool = False) -> RosSubscriber:
        return RosSubscriber(self, topic, msgtype, callback, qos or QoS(), any_type=any_type)

    def close(self) -> None:
        """Withdraw the node's liveliness token (entities are closed by their owners)."""
        _undeclare(self._token)


class RosPublisher:
    """Publishes CDR payloads on a topic with the rmw_zenoh key, attachment and ``MP`` liveliness token."""

    def __init__(self, node: RosNode, topic: str, msgtype: str, qos: QoS) -> None:
        self.topic = normalize_topic(topic)
        self.msgtype = msgtype
        self.key = topic_key(node.domain_id, self.topic, msgtype, node.hash_for(msgtype))
        self.entity_id = node.next_entity_id()
        self.token_key = entity_token_key(PUBLISHER, node.domain_id, node.zid, node.node_id, self.entity_id,
                                          node.name, self.topic, msgtype, qos, node.namespace,
                                          hash_part=node.hash_for(msgtype))
        self.gid = gid_from_key(self.token_key)
        self.qos = qos
        self._pub = DataPublisher(node.session, self.key, qos)  # advanced (cache) when transient local
        self._token = node.session.liveliness().declare_token(self.token_key)
        self._seq = itertools.count(1)
        self._lock = threading.Lock()

    def put(self, cdr: bytes) -> int:
        """Publish one serialized message; returns the sequence number used."""
        with self._lock:
            seq = next(self._seq)
            att = Attachment(seq, time.time_ns(), self.gid).encode()
            self._pub.put(bytes(cdr), attachment=att)
        return seq

    def matched(self) -> bool:
        """True while at least one Zenoh subscriber matches this publisher's key."""
        return self._pub.matched()

    def publish(self, message: object) -> int:
        """Serialize a rosbags message object of this publisher's type and publish it."""
        return self.put(bytes(typestore().serialize_cdr(message, self.msgtype)))

    def close(self) -> None:
        _undeclare(self._token)
        _undeclare(self._pub)


class RosSubscriber:
    """Subscribes to a topic (``*`` hash) and advertises a ``MS`` liveliness token.

    With ``any_type`` the data key also has ``*`` in the type position, so messages of a wrong type
    arrive too and can be counted instead of being invisible; the callback sees the sample's key.
    """

    def __init__(self, node: RosNode, topic: str, msgtype: str, callback: Callable[[zenoh.Sample], None],
                 qos: QoS, any_type: bool = False) -> None:
        self.topic = normalize_topic(topic)
        self.msgtype = msgtype
        self.key = topic_key(node.domain_id, self.topic, None if any_type else msgtype, "*")
        self.entity_id = node.next_entity_id()
        self.token_key = entity_token_key(SUBSCRIPTION, node.domain_id, node.zid, node.node_id, self.entity_id,
                                          node.name, self.topic, msgtype, qos, node.namespace,
                                          hash_part=node.hash_for(msgtype))
        self.qos = qos
        self._sub = declare_subscriber(node.session, self.key, callback, qos)  # with history when transient local
        self._token = node.session.liveliness().declare_token(self.token_key)

    def close(self) -> None:
        _undeclare(self._token)
        _undeclare(self._sub)


def msgtype_of_key(key: str) -> str | None:
    """ROS type named by a data key expression (third chunk from the end), or None."""
    parts = str(key).split("/")
    return ros_type_from_dds(parts[-2]) if len(parts) >= 4 else None


def _undeclare(entity: object) -> None:
    try:
        entity.undeclare()  # type: ignore[attr-defined]
    except zenoh.ZError as exc:  # session already closed
        log.debug("undeclare failed: %s", exc)
