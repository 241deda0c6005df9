"""Typed decode/encode of pivotd's ROS 2 messages (CDR through ``rosbags``), with validation.

Decoders turn a CDR payload into a small frozen dataclass or raise :class:`MessageError`, whose
``reason`` is a short token used for per-topic drop counters: ``malformed`` (not CDR of the type),
``wrong_type``, ``nonfinite`` (NaN/inf pose or path), ``zero_quaternion``, ``wrong_frame``,
``oversized`` (cloud above the point limit), ``bad_fields`` (cloud without float x/y/z), ``empty``
(path without poses), ``out_of_range`` (a pose, path or cloud position beyond ±MAX_COORDINATE m).

Frames: ``frame_id`` is compared with the expected frame ignoring a leading ``/``. An empty
``frame_id`` is accepted as the expected frame unless ``accept_empty_frame`` is False. ``None`` as the
expected frame accepts any frame.

Encoders return CDR bytes (little-endian, 4-byte encapsulation header) ready for
:meth:`pivotd.bus.ros.RosPublisher.put`.
"""

from __future__ import annotations

import struct
import time
from dataclasses import dataclass

import numpy as np

from pivotd.bus.ros import typestore
from pivotd.bus.tf_tree import TransformRecord
from pivotd.bus.topics import ODOMETRY as ODOMETRY
from pivotd.bus.topics import POSE_STAMPED as POSE_STAMPED
from pivotd.bus.topics import POSE_TYPES as POSE_TYPES
from pivotd.bus.topics import POSE_WITH_COVARIANCE_STAMPED as POSE_WITH_COVARIANCE_STAMPED
from pivotd.bus.topics import TF_MESSAGE as TF_MESSAGE
from pivotd.errors import PivotdError
from pivotd.geometry import MAX_COORDINATE, matrix_to_quat, optical_frame_from_direction, safe_unit_quats

PATH = "nav_msgs/msg/Path"
POINT_CLOUD2 = "sensor_msgs/msg/PointCloud2"
JOINT_STATE = "sensor_msgs/msg/JointState"
DIAGNOSTIC_ARRAY = "diagnostic_msgs/msg/DiagnosticArray"
CLOCK = "rosgraph_msgs/msg/Clock"

_FLOAT32, _FLOAT64 = 7, 8  # sensor_msgs/PointField datatypes
_MAX_STAMP_NS = (2**31 - 1) * 1_000_000_000 + 999_999_999
_FIELD_DTYPES = {_FLOAT32: "f4", _FLOAT64: "f8"}
#: PointFields a cloud may declare (x, y, z, weight and whatever else a sender packs); more is refused before
#: decoding, since each field becomes a Python object.
MAX_CLOUD_FIELDS = 64


class MessageError(PivotdError):
    """A dropped message: one-line reason naming the topic; ``reason`` is the counter token."""

    def __init__(self, topic: str, reason: str, detail: str) -> None:
        super().__init__(f"{topic}: {detail}")
        self.topic = topic
        self.reason = reason


@dataclass(frozen=True)
class PoseSample:
    """Body pose in the map frame. stamp [s] (header time); position (3,) [m]; quat (4,) unit (x, y, z, w);
    rx_time: ``time.monotonic()`` at reception [s]."""

    stamp: float
    frame_id: str
    position: np.ndarray
    quat: np.ndarray
    rx_time: float


@dataclass(frozen=True)
class PathMsg:
    """Translation path. stamp [s]; positions (N, 3) [m]; quats (N, 4) unit (x, y, z, w), identity where
    the sender left a zero quaternion (planners often do)."""

    stamp: float
    frame_id: str
    positions: np.ndarray
    quats: np.ndarray


@dataclass(frozen=True)
class CloudMsg:
    """Landmarks or targets. stamp [s]; points (N, 3) float64 [m] (non-finite points dropped);
    weights (N,) float64 or None when the cloud has no ``weight`` field."""

    stamp: float
    frame_id: str
    points: np.ndarray
    weights: np.ndarray | None


# --------------------------------------------------------------------------------------------- conversions


def stamp_to_seconds(stamp: object) -> float:
    """builtin_interfaces/Time -> seconds."""
    return float(stamp.sec) + 1e-9 * float(stamp.nanosec)  # type: ignore[attr-defined]


def seconds_to_stamp(t: float) -> object:
    """Seconds -> builtin_interfaces/Time (rounded to whole nanoseconds; clamped to [0, 2³¹ s − 1 ns])."""
    t = float(t)
    t = min(max(t, 0.0), 2.0**31) if t == t else 0.0  # builtin_interfaces/Time holds int32 sec; NaN -> 0
    ns = min(round(t * 1e9), _MAX_STAMP_NS)
    return _t("builtin_interfaces/msg/Time")(sec=ns // 1_000_000_000, nanosec=ns % 1_000_000_000)


def _t(name: str) -> type:
    return typestore().types[name]


def deserialize(payload: bytes | memoryview, msgtype: str, topic: str) -> object:
    """CDR payload -> rosbags message object; :class:`MessageError` ``malformed`` on any failure."""
    data = bytes(payload)
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        raise MessageError(topic, "malformed", f"not a CDR {msgtype} payload ({len(data)} bytes, bad header)")
    try:
        return typestore().deserialize_cdr(data, msgtype)
    except Exception as exc:  # rosbags raises SerdeError, but garbage may surface as other errors
        raise MessageError(topic, "malformed", f"cannot decode {msgtype}: {' '.join(str(exc).split())}") from exc


def serialize(message: object, msgtype: str) -> bytes:
    """rosbags message object -> CDR little-endian bytes with the encapsulation header."""
    return bytes(typestore().serialize_cdr(message, msgtype))


def _norm_frame(frame: str) -> str:
    return frame.strip().lstrip("/")


def check_frame(frame_id: str, expected: str | None, topic: str, accept_empty: bool = True) -> str:
    """Validated frame id (the expected one when empty and accepted); raises ``wrong_frame``."""
    if expected is None:
        return frame_id
    if not frame_id.strip():
        if accept_empty:
            return expected
        raise MessageError(topic, "wrong_frame", f"empty frame_id, expected {expected!r}")
    if _norm_frame(frame_id) != _norm_frame(expected):
        raise MessageError(topic, "wrong_frame", f"frame_id {frame_id!r}, expected {expected!r}")
    return frame_id


def _pose_arrays(pose: object, topic: str, what: str) -> tuple[np.ndarray, np.ndarray]:
    p, q = pose.position, pose.orientation  # type: ignore[attr-defined]
    position = np.array([p.x, p.y, p.z], dtype=float)
    quat = np.array([q.x, q.y, q.z, q.w], dtype=float)
    if not (np.all(np.isfinite(position)) and np.all(np.isfinite(quat))):
        raise MessageError(topic, "nonfinite", f"{what} has a NaN or infinite value")
    if np.max(np.abs(position)) > MAX_COORDINATE:
        raise MessageError(topic, "out_of_range", f"{what} position beyond ±{MAX_COORDINATE:g} m")
    unit, usable = safe_unit_quats(quat)
    if not usable[0]:
        raise MessageError(topic, "zero_quaternion", f"{what} has a zero quaternion")
    return position, unit[0]


# --------------------------------------------------------------------------------------------- decoders


def decode_pose(payload: bytes, msgtype: str, topic: str, expected_frame: str | None = "map",
                accept_empty_frame: bool = True, rx_time: float | None = None) -> PoseSample:
    """Decode a ``nav_msgs/msg/Odometry``, ``geometry_msgs/msg/PoseStamped`` or
    ``geometry_msgs/msg/PoseWithCovarianceStamped`` payload (the covariance is not used)."""
    rx = time.monotonic() if rx_time is None else rx_time
    if msgtype not in POSE_TYPES:
        raise MessageError(topic, "wrong_type", f"unsupported pose type {msgtype}")
    msg = deserialize(payload, msgtype, topic)
    pose = msg.pose if msgtype == POSE_STAMPED else msg.pose.pose  # type: ignore[attr-defined]
    frame = check_frame(msg.header.frame_id, expected_frame, topic, accept_empty_frame)  # type: ignore[attr-defined]
    position, quat = _pose_arrays(pose, topic, "pose")
    stamp = stamp_to_seconds(msg.header.stamp)  # type: ignore[attr-defined]
    return PoseSample(stamp=stamp, frame_id=frame, position=position, quat=quat, rx_time=rx)


def decode_transforms(payload: bytes, topic: str, rx_time: float, static: bool = False,
                      source: str = "") -> list[TransformRecord]:
    """The transforms of a ``tf2_msgs/msg/TFMessage`` payload as they were sent (validated by
    :meth:`pivotd.bus.tf_tree.TfTree.add`, which counts what it drops); ``malformed`` when it is not CDR of it."""
    msg = deserialize(payload, TF_MESSAGE, topic)
    out = []
    for tf in msg.transforms:  # type: ignore[attr-defined]
        tr, rot = tf.transform.translation, tf.transform.rotation
        out.append(TransformRecord(tf.header.frame_id, tf.child_frame_id, stamp_to_seconds(tf.header.stamp),
                                   np.array([tr.x, tr.y, tr.z], dtype=float),
                                   np.array([rot.x, rot.y, rot.z, rot.w], dtype=float), rx_time, static, source))
    return out


def encode_transforms(transforms: list[tuple[float, str, str, np.ndarray, np.ndarray]]) -> bytes:
    """``tf2_msgs/msg/TFMessage`` CDR of (stamp [s], parent, child, translation (3,) [m], rotation (4,) (x, y, z, w))
    tuples (the rotation is sent as given, unnormalised)."""
    vec, quat = _t("geometry_msgs/msg/Vector3"), _t("geometry_msgs/msg/Quaternion")
    msgs = []
    for stamp, parent, child, translation, rotation in transforms:
        p = [float(v) for v in np.asarray(translation, float).reshape(3)]
        q = [float(v) for v in np.asarray(rotation, float).reshape(4)]
        msgs.append(_t("geometry_msgs/msg/TransformStamped")(
            header=_header(stamp, parent), child_frame_id=child,
            transform=_t("geometry_msgs/msg/Transform")(translation=vec(x=p[0], y=p[1], z=p[2]),
                                                        rotation=quat(x=q[0], y=q[1], z=q[2], w=q[3]))))
    return serialize(_t(TF_MESSAGE)(transforms=msgs), TF_MESSAGE)


def decode_path(payload: bytes, topic: str, expected_frame: str | None = "map",
                accept_empty_frame: bool = True) -> PathMsg:
    """Decode a ``nav_msgs/msg/Path`` payload (at least one pose, finite positions).

    Read directly from the CDR bytes (:func:`path_arrays`, one pass, no object per pose): a path of 50 000
    poses decodes in tens of milliseconds instead of seconds.
    """
    stamp, frame_id, positions, quats = path_arrays(payload, topic)
    frame = check_frame(frame_id, expected_frame, topic, accept_empty_frame)
    if positions.shape[0] == 0:
        raise MessageError(topic, "empty", "path has no poses")
    if not np.all(np.isfinite(positions)):
        bad = int(np.argmax(~np.all(np.isfinite(positions), axis=1)))
        raise MessageError(topic, "nonfinite", f"path pose {bad} has a NaN or infinite position")
    far = np.max(np.abs(positions), axis=1) > MAX_COORDINATE
    if far.any():
        raise MessageError(topic, "out_of_range", f"path pose {int(np.argmax(far))} has a position beyond "
                                                  f"±{MAX_COORDINATE:g} m")
    unit, usable = safe_unit_quats(quats)
    quats = np.where(usable[:, None], unit, np.array([0.0, 0.0, 0.0, 1.0]))
    return PathMsg(stamp=stamp, frame_id=frame, positions=positions, quats=quats)


class _Reader:
    """Bounds-checked reads from a CDR body (alignment relative to the body's start)."""

    def __init__(self, payload: bytes | memoryview, topic: str) -> None:
        data = memoryview(payload).cast("B")
        if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
            raise MessageError(topic, "malformed", f"not a CDR {PATH} payload ({len(data)} bytes, bad header)")
        self.body, self.pos, self.topic = data[4:], 0, topic
        self.order = "<" if data[1] == 1 else ">"

    def need(self, size: int, align: int) -> int:
        at = (self.pos + align - 1) // align * align
        if at + size > len(self.body):
            raise MessageError(self.topic, "malformed", f"cannot decode {PATH}: truncated at byte {at + 4}")
        self.pos = at + size
        return at

    def u32(self) -> int:
        return int(struct.unpack_from(self.order + "I", self.body, self.need(4, 4))[0])

    def string(self) -> str:
        size = self.u32()
        at = self.need(size, 1)
        raw = bytes(self.body[at:at + size])
        if size == 0 or raw[-1] != 0:
            raise MessageError(self.topic, "malformed", f"cannot decode {PATH}: bad string at byte {at + 4}")
        try:
            return raw[:-1].decode()
        except UnicodeDecodeError as exc:
            raise MessageError(self.topic, "malformed", f"cannot decode {PATH}: {exc}") from None


_MIN_POSE_RECORD = 8 + 4 + 1 + 56  # stamp, frame_id length, its NUL, 7 float64 (before padding)


def path_arrays(payload: bytes | memoryview, topic: str) -> tuple[float, str, np.ndarray, np.ndarray]:
    """(stamp [s], frame_id, positions (N, 3), quats (N, 4) as sent) of a ``nav_msgs/msg/Path`` CDR payload;
    ``malformed`` when the bytes do not hold what the counts say."""
    r = _Reader(payload, topic)
    sec, nanosec = struct.unpack_from(r.order + "iI", r.body, r.need(8, 4))
    stamp = float(sec) + 1e-9 * float(nanosec)
    frame_id = r.string()
    n = r.u32()
    if n * _MIN_POSE_RECORD > len(r.body) - r.pos:
        raise MessageError(topic, "malformed", f"cannot decode {PATH}: {n} poses cannot fit in {len(r.body)} bytes")
    values = np.empty((n, 7))
    fmt = r.order + "7d"
    body, order = r.body, r.order + "I"
    i = 0
    while i < n:  # records differ only in their frame_id length and padding
        start = r.pos
        r.need(8, 4)
        size_at = r.need(4, 4)
        size = struct.unpack_from(order, body, size_at)[0]
        r.need(size, 1)
        values_at = r.need(56, 8)
        values[i] = struct.unpack_from(fmt, body, values_at)
        i += 1
        # the first record may be padded differently from the others: try the strided read after two
        if i in (1, 2) and i < n and (rest := _uniform_records(r, n - i, start, size_at, size, values_at)) is not None:
            values[i:] = rest
            break
    return stamp, frame_id, values[:, :3].copy(), values[:, 3:].copy()


def _uniform_records(r: _Reader, count: int, first: int, size_at: int, size: int,
                     values_at: int) -> np.ndarray | None:
    """The 7 float64 of the ``count`` pose records after the one just read (which starts at ``first``), read as
    one strided array when every one has its frame_id length and alignment (the usual case); None otherwise (or
    when the bytes do not hold them), to be read one by one."""
    start = (r.pos + 3) // 4 * 4  # the second record's stamp
    stride = (values_at + 56) - first + (start - r.pos) if start % 8 == first % 8 else None
    if stride is None or stride % 8 or start + stride * count > len(r.body):
        return None
    rows = np.frombuffer(r.body, np.uint8, count=stride * count, offset=start).reshape(count, stride)
    lengths = rows[:, size_at - first:size_at - first + 4].copy().view(r.order + "u4").reshape(count)
    if not np.all(lengths == size):
        return None
    r.pos = start + stride * count
    raw = rows[:, values_at - first:values_at - first + 56].copy()
    return raw.view(r.order + "f8").reshape(count, 7).astype(np.float64)


def decode_cloud(payload: bytes, topic: str, expected_frame: str | None = "map", max_points: int = 2_000_000,
                 accept_empty_frame: bool = True) -> CloudMsg:
    """Decode a ``sensor_msgs/msg/PointCloud2`` with float x, y, z and an optional float ``weight``.

    Honours ``point_step``, ``row_step``, ``is_bigendian`` and padding; drops points (and weights)
    with a non-finite coordinate or a non-finite or negative weight.
    """
    # Cheap guard before decoding: even generously padded points (256 bytes) cannot need more than this.
    if len(payload) > 64 * 1024 + 256 * max_points:
        raise MessageError(topic, "oversized", f"cloud payload of {len(payload)} bytes exceeds the "
                                               f"{max_points}-point limit")
    fields = cloud_field_count(payload)
    if fields is not None and fields > MAX_CLOUD_FIELDS:
        raise MessageError(topic, "bad_fields", f"cloud declares {fields} fields, limit is {MAX_CLOUD_FIELDS}")
    msg = deserialize(payload, POINT_CLOUD2, topic)
    frame = check_frame(msg.header.frame_id, expected_frame, topic, accept_empty_frame)  # type: ignore[attr-defined]
    points, weights = cloud_arrays(msg, topic, max_points)
    return CloudMsg(stamp=stamp_to_seconds(msg.header.stamp), frame_id=frame,  # type: ignore[attr-defined]
                    points=points, weights=weights)


def cloud_field_count(payload: bytes | memoryview) -> int | None:
    """Number of PointFields a PointCloud2 CDR payload declares, read without decoding it (None when the
    payload is too short or not CDR: the decoder then reports it)."""
    data = memoryview(payload)
    if len(data) < 4 or data[0] != 0 or data[1] not in (0, 1):
        return None
    order = "little" if data[1] == 1 else "big"
    body = data[4:]  # CDR alignment is relative to the end of the encapsulation header
    pos = 8  # header.stamp: sec, nanosec
    if len(body) < pos + 4:
        return None
    pos += 4 + int.from_bytes(body[pos:pos + 4], order)  # header.frame_id: length (with NUL), bytes
    pos = (pos + 3) & ~3
    pos += 8  # height, width
    if len(body) < pos + 4:
        return None
    return int.from_bytes(body[pos:pos + 4], order)


def cloud_arrays(msg: object, topic: str, max_points: int) -> tuple[np.ndarray, np.ndarray | None]:
    """(points (N, 3) float64, weights (N,) | None) of a decoded PointCloud2, finite points only."""
    height, width = int(msg.height), int(msg.width)  # type: ignore[attr-defined]
    n = height * width
    if n > max_points:
        raise MessageError(topic, "oversized", f"cloud has {n} points, limit is {max_points}")
    step, row_step = int(msg.point_step), int(msg.row_step)  # type: ignore[attr-defined]
    fields = {f.name: f for f in msg.fields}  # type: ignore[attr-defined]
    order = ">" if msg.is_bigendian else "<"  # type: ignore[attr-defined]
    layout = {}
    for name in ("x", "y", "z", "weight"):
        f = fields.get(name)
        if f is None:
            if name != "weight":
                raise MessageError(topic, "bad_fields", f"cloud has no {name!r} field")
            continue
        if f.datatype not in _FIELD_DTYPES or f.count < 1:
            raise MessageError(topic, "bad_fields", f"cloud field {name!r} is not float32/float64 "
                                                    f"(datatype {f.datatype}, count {f.count})")
        size = 4 if f.datatype == _FLOAT32 else 8
        if f.offset + size > step:
            raise MessageError(topic, "malformed", f"cloud field {name!r} at offset {f.offset} exceeds "
                                                   f"point_step {step}")
        layout[name] = (int(f.offset), order + _FIELD_DTYPES[f.datatype], size)
    data = np.asarray(msg.data, dtype=np.uint8).reshape(-1)  # type: ignore[attr-defined]
    if n and (row_step < width * step or data.size < row_step * height):
        raise MessageError(topic, "malformed", f"cloud data of {data.size} bytes does not hold {height}x{width} "
                                               f"points (point_step {step}, row_step {row_step})")
    if n == 0:
        return np.zeros((0, 3)), (np.zeros(0) if "weight" in layout else None)
    rows = data[: row_step * height].reshape(height, row_step)[:, : width * step].reshape(n, step)

    def column(name: str) -> np.ndarray:
        off, dt, size = layout[name]
        return np.ascontiguousarray(rows[:, off:off + size]).view(dt).reshape(n).astype(np.float64)

    points = np.column_stack([column("x"), column("y"), column("z")])
    keep = np.all(np.isfinite(points), axis=1)
    far = keep & (np.max(np.abs(np.where(keep[:, None], points, 0.0)), axis=1) > MAX_COORDINATE)
    if far.any():
        raise MessageError(topic, "out_of_range", f"cloud point {int(np.argmax(far))} lies beyond "
                                                  f"±{MAX_COORDINATE:g} m")
    weights = None
    if "weight" in layout:
        weights = column("weight")
        keep &= np.isfinite(weights) & (weights >= 0)
        weights = weights[keep]
    return points[keep], weights


# --------------------------------------------------------------------------------------------- encoders


def _header(stamp: float, frame_id: str) -> object:
    return _t("std_msgs/msg/Header")(stamp=seconds_to_stamp(stamp), frame_id=frame_id)


def _pose(position: np.ndarray, quat: np.ndarray) -> object:
    p = [float(v) for v in position]
    q = [float(v) for v in quat]
    return _t("geometry_msgs/msg/Pose")(
        position=_t("geometry_msgs/msg/Point")(x=p[0], y=p[1], z=p[2]),
        orientation=_t("geometry_msgs/msg/Quaternion")(x=q[0], y=q[1], z=q[2], w=q[3]),
    )


def encode_joint_state(stamp: float, names: list[str], positions: list[float], velocities: list[float],
                       frame_id: str = "") -> bytes:
    """sensor_msgs/msg/JointState CDR: positions [rad], velocities [rad/s], no efforts."""
    msg = _t(JOINT_STATE)(header=_header(stamp, frame_id), name=list(names),
                          position=np.asarray(positions, dtype=np.float64),
                          velocity=np.asarray(velocities, dtype=np.float64), effort=np.zeros(0))
    return serialize(msg, JOINT_STATE)


def decode_clock(payload: bytes, topic: str) -> float:
    """rosgraph_msgs/msg/Clock CDR -> the simulation time [s]; ``malformed`` when nanoseconds reach a second."""
    clock = deserialize(payload, CLOCK, topic).clock  # type: ignore[attr-defined]
    if not 0 <= clock.nanosec < 1_000_000_000:
        raise MessageError(topic, "malformed", f"clock nanosec {clock.nanosec} is not below 10^9")
    return stamp_to_seconds(clock)


def encode_clock(t: float) -> bytes:
    """rosgraph_msgs/msg/Clock CDR of the simulation time ``t`` [s] (as a simulator publishes it)."""
    return serialize(_t(CLOCK)(clock=seconds_to_stamp(t)), CLOCK)


def encode_diagnostics(stamp: float, entries: list) -> bytes:
    """diagnostic_msgs/msg/DiagnosticArray CDR of :class:`~pivotd.bus.diagnostics.DiagnosticEntry` items."""
    status_t, kv_t = _t("diagnostic_msgs/msg/DiagnosticStatus"), _t("diagnostic_msgs/msg/KeyValue")
    statuses = [status_t(level=int(e.level), name=e.name, message=e.message, hardware_id=e.hardware_id,
                         values=[kv_t(key=k, value=v) for k, v in e.values]) for e in entries]
    return serialize(_t(DIAGNOSTIC_ARRAY)(header=_header(stamp, ""), status=statuses), DIAGNOSTIC_ARRAY)


def encode_pose_stamped(stamp: float, frame_id: str, position: np.ndarray, quat: np.ndarray) -> bytes:
    """geometry_msgs/msg/PoseStamped CDR; quat (x, y, z, w)."""
    return serialize(_t(POSE_STAMPED)(header=_header(stamp, frame_id), pose=_pose(position, quat)), POSE_STAMPED)


def encode_pose_with_covariance_stamped(stamp: float, frame_id: str, position: np.ndarray, quat: np.ndarray,
                                        covariance: np.ndarray | None = None) -> bytes:
    """geometry_msgs/msg/PoseWithCovarianceStamped CDR; quat (x, y, z, w), covariance (36,) row-major (zeros)."""
    cov = np.zeros(36) if covariance is None else np.asarray(covariance, dtype=np.float64).reshape(36)
    msg = _t(POSE_WITH_COVARIANCE_STAMPED)(
        header=_header(stamp, frame_id),
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=_pose(position, quat), covariance=cov))
    return serialize(msg, POSE_WITH_COVARIANCE_STAMPED)


def encode_pose(msgtype: str, stamp: float, frame_id: str, position: np.ndarray, quat: np.ndarray,
                child_frame_id: str = "base_link") -> bytes:
    """CDR of a pose of any of :data:`POSE_TYPES` (the type a ``topics.pose_type`` names); quat (x, y, z, w)."""
    if msgtype == ODOMETRY:
        return encode_odometry(stamp, frame_id, child_frame_id, position, quat)
    if msgtype == POSE_WITH_COVARIANCE_STAMPED:
        return encode_pose_with_covariance_stamped(stamp, frame_id, position, quat)
    return encode_pose_stamped(stamp, frame_id, position, quat)


def encode_odometry(stamp: float, frame_id: str, child_frame_id: str, position: np.ndarray, quat: np.ndarray,
                    linear_velocity: np.ndarray | None = None, angular_velocity: np.ndarray | None = None) -> bytes:
    """nav_msgs/msg/Odometry CDR; velocities (3,) in the child (body) frame [m/s, rad/s], zero covariances."""
    lin = [0.0, 0.0, 0.0] if linear_velocity is None else [float(v) for v in linear_velocity]
    ang = [0.0, 0.0, 0.0] if angular_velocity is None else [float(v) for v in angular_velocity]
    vec = _t("geometry_msgs/msg/Vector3")
    msg = _t(ODOMETRY)(
        header=_header(stamp, frame_id),
        child_frame_id=child_frame_id,
        pose=_t("geometry_msgs/msg/PoseWithCovariance")(pose=_pose(position, quat), covariance=np.zeros(36)),
        twist=_t("geometry_msgs/msg/TwistWithCovariance")(
            twist=_t("geometry_msgs/msg/Twist")(linear=vec(x=lin[0], y=lin[1], z=lin[2]),
                                                angular=vec(x=ang[0], y=ang[1], z=ang[2])),
            covariance=np.zeros(36)),
    )
    return serialize(msg, ODOMETRY)


def encode_path(stamp: float, frame_id: str, positions: np.ndarray, quats: np.ndarray | None = None,
                stamps: np.ndarray | None = None) -> bytes:
    """nav_msgs/msg/Path CDR from positions (N, 3) [m], quats (N, 4) (x, y, z, w) (identity when None) and
    per-pose stamps (N,) [s] (``stamp`` when None)."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    n = positions.shape[0]
    quats = np.tile([0.0, 0.0, 0.0, 1.0], (n, 1)) if quats is None else np.asarray(quats, float).reshape(n, 4)
    ps = _t(POSE_STAMPED)
    poses = [ps(header=_header(stamp if stamps is None else float(stamps[i]), frame_id),
                pose=_pose(positions[i], quats[i])) for i in range(n)]
    return serialize(_t(PATH)(header=_header(stamp, frame_id), poses=poses), PATH)


def warm_up() -> None:
    """Build the typestore and the CDR (de)serialisers of every pivotd message type now (≈ 0.1 s once per
    process) so that the first message received is decoded as fast as the next ones."""
    decode_pose(encode_odometry(0.0, "map", "b", np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), ODOMETRY, "warm-up")
    decode_pose(encode_pose_stamped(0.0, "map", np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])), POSE_STAMPED,
                "warm-up")
    decode_pose(encode_pose_with_covariance_stamped(0.0, "map", np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0])),
                POSE_WITH_COVARIANCE_STAMPED, "warm-up")
    decode_path(encode_path(0.0, "map", np.zeros((2, 3))), "warm-up")
    decode_transforms(encode_transforms([(0.0, "map", "b", np.zeros(3), np.array([0.0, 0.0, 0.0, 1.0]))]), "warm-up",
                      0.0)
    decode_cloud(encode_cloud(0.0, "map", np.zeros((2, 3)), np.ones(2)), "warm-up")
    encode_joint_state(0.0, ["pan"], [0.0], [0.0])


def view_plan_quats(directions: np.ndarray) -> np.ndarray:
    """Camera orientations (N, 4) (x, y, z, w) whose +z axis is each view direction (N, 3)."""
    return matrix_to_quat(optical_frame_from_direction(np.asarray(directions, dtype=float).reshape(-1, 3)))


def encode_view_plan(stamp: float, frame_id: str, positions: np.ndarray, directions: np.ndarray) -> bytes:
    """nav_msgs/msg/Path of camera poses: positions (N, 3) [m], orientation +z along directions (N, 3)."""
    positions = np.asarray(positions, dtype=float).reshape(-1, 3)
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    if positions.shape != directions.shape:
        raise ValueError(f"view plan needs as many directions as positions: {positions.shape} vs {directions.shape}")
    return encode_path(stamp, frame_id, positions, view_plan_quats(directions))


def encode_cloud(stamp: float, frame_id: str, points: np.ndarray, weights: np.ndarray | None = None,
                 big_endian: bool = False, point_step: int | None = None, height: int = 1,
                 row_padding: int = 0) -> bytes:
    """sensor_msgs/msg/PointCloud2 CDR with float32 x, y, z (+ ``weight``) fields.

    ``point_step`` may exceed the packed size (padding bytes), ``height`` > 1 makes an organized
    cloud (N must divide), ``row_padding`` adds bytes at each row end (``row_step`` > width·step).
    """
    points = np.asarray(points, dtype=float).reshape(-1, 3)
    n = points.shape[0]
    names = ["x", "y", "z"] + (["weight"] if weights is not None else [])
    packed = 4 * len(names)
    step = packed if point_step is None else int(point_step)
    if step < packed:
        raise ValueError(f"point_step {step} is smaller than {packed}")
    if height < 1 or (n and n % height):
        raise ValueError(f"{n} points do not form {height} rows")
    width = n // height if n else 0
    order = ">" if big_endian else "<"
    cols = [points[:, 0], points[:, 1], points[:, 2]] + ([np.asarray(weights, float)] if weights is not None else [])
    buf = np.zeros((n, step), dtype=np.uint8)
    for i, col in enumerate(cols):
        buf[:, 4 * i:4 * i + 4] = np.asarray(col, dtype=order + "f4").reshape(n, 1).view(np.uint8)
    row_step = width * step + row_padding
    rows = np.zeros((height if n else 0, row_step), dtype=np.uint8)
    if n:
        rows[:, : width * step] = buf.reshape(height, width * step)
    pf = _t("sensor_msgs/msg/PointField")
    fields = [pf(name=name, offset=4 * i, datatype=_FLOAT32, count=1) for i, name in enumerate(names)]
    msg = _t(POINT_CLOUD2)(header=_header(stamp, frame_id), height=height if n else 1, width=width, fields=fields,
                           is_bigendian=big_endian, point_step=step, row_step=row_step, data=rows.reshape(-1),
                           is_dense=bool(np.all(np.isfinite(points))))
    return serialize(msg, POINT_CLOUD2)
