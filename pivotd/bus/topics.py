"""The bus settings: topic names, pose type, frame and limits (the config file's ``topics`` section).

:class:`BusTopics` is what :class:`~pivotd.bus.pivot_bus.PivotBus` takes and what
:func:`pivotd.config.load_config` produces from the ``topics`` section (docs/CONFIG.md). It depends on
nothing heavier than the standard library, so the config can be loaded without Zenoh or rosbags.
"""

from __future__ import annotations

from dataclasses import dataclass

from pivotd.errors import ConfigError

ODOMETRY = "nav_msgs/msg/Odometry"
POSE_STAMPED = "geometry_msgs/msg/PoseStamped"
POSE_WITH_COVARIANCE_STAMPED = "geometry_msgs/msg/PoseWithCovarianceStamped"  # e.g. AMCL's /amcl_pose
POSE_TYPES = (ODOMETRY, POSE_STAMPED, POSE_WITH_COVARIANCE_STAMPED)
TF_MESSAGE = "tf2_msgs/msg/TFMessage"
#: Where the body pose comes from (``topics.pose_source``): a pose topic, or the TF tree (``/tf``, ``/tf_static``).
POSE_SOURCE_TOPIC, POSE_SOURCE_TF = "topic", "tf"
POSE_SOURCES = (POSE_SOURCE_TOPIC, POSE_SOURCE_TF)
TOPIC_FIELDS = ("pose", "path", "landmarks", "targets", "joint_states", "view_plan", "tf", "tf_static")
#: Payload size limits of the input topics (``topics`` keys) [bytes] and their smallest allowed value.
PAYLOAD_LIMITS = ("max_pose_bytes", "max_path_bytes", "max_cloud_bytes", "max_tf_bytes")
MIN_PAYLOAD_LIMIT = 256
#: Largest ``topics.tf_max_frames``.
MAX_TF_FRAMES = 10_000
#: How the topics are carried on Zenoh (``topics.wire``): as rmw_zenoh does (domain, type and hash in the key,
#: attachments, liveliness tokens), or as zenoh-bridge-ros2dds routes a DDS robot's topics (the topic name as the
#: key, bare CDR; :mod:`pivotd.bus.ros2dds`).
WIRE_RMW_ZENOH, WIRE_ROS2DDS_BRIDGE = "rmw_zenoh", "ros2dds_bridge"
WIRES = (WIRE_RMW_ZENOH, WIRE_ROS2DDS_BRIDGE)
#: Largest ROS domain id (ROS 2's documented range 0..232; rmw_zenoh puts it first in every key expression).
MAX_DOMAIN_ID = 232
#: Environment variable of the ROS domain id, used when ``topics.domain_id`` is not set.
DOMAIN_ID_ENV = "ROS_DOMAIN_ID"
#: The ROS simulation clock topic (absolute, as every ROS node subscribes it with ``use_sim_time``).
CLOCK_TOPIC = "/clock"
#: Default names of the two joints in the published ``JointState`` (``topics.joint_names``).
DEFAULT_JOINT_NAMES = ("pan", "tilt")


def joint_names_problem(names: object) -> str | None:
    """Why ``names`` is not a pair of distinct non-empty joint names (pan first, then tilt); None when it is."""
    if not isinstance(names, tuple | list) or len(names) != 2:
        return f"must be a list of two joint names (pan, tilt), got {names!r}"
    if not all(isinstance(n, str) and n.strip() for n in names):
        return f"joint names must be non-empty strings, got {list(names)!r}"
    if names[0] == names[1]:
        return f"the two joint names must differ, both are {names[0]!r}"
    return None


def domain_id_from_env(environ: dict[str, str]) -> int:
    """The ROS domain id from ``ROS_DOMAIN_ID`` in ``environ``: 0 when unset or empty (as rcl does); raises
    ConfigError naming the variable when it is not an integer in 0..232."""
    raw = environ.get(DOMAIN_ID_ENV, "").strip()
    if not raw:
        return 0
    if not (raw.isascii() and raw.isdigit()) or int(raw) > MAX_DOMAIN_ID:
        raise ConfigError(f"{DOMAIN_ID_ENV}={environ[DOMAIN_ID_ENV]!r} in the environment (used as topics.domain_id "
                          f"is not set): must be an integer in 0..{MAX_DOMAIN_ID}")
    return int(raw)


def status_key_for(name: str) -> str:
    """Plain Zenoh key of the JSON status of node ``name``: ``pivot/<name>/status``."""
    return f"pivot/{name}/status"


def normalize_namespace(namespace: str) -> str:
    """A ROS namespace with one leading slash and no trailing slash (``/`` for the root); rejects bad names."""
    stripped = namespace.strip().strip("/")
    return "/" if not stripped else normalize_topic(stripped)


def resolve_topic(topic: str, namespace: str = "/") -> str:
    """ROS name resolution: a relative ``topic`` (no leading slash) lives under ``namespace``; an absolute one
    is used as it is. ``resolve_topic("odom", "/robot1") == "/robot1/odom"``."""
    if topic.strip().startswith("/"):
        return normalize_topic(topic)
    ns = normalize_namespace(namespace)
    return normalize_topic(topic if ns == "/" else f"{ns}/{topic.strip()}")


def bridge_topic(topic: str, namespace: str = "/") -> str:
    """The name zenoh-bridge-ros2dds configured with ``namespace`` gives the robot's topic ``topic`` on Zenoh.

    The bridge puts its namespace in front of every topic it routes, absolute names such as ``/tf`` too
    (``bridge_topic("/tf", "/robot1") == "/robot1/tf"``); a relative name is a name of the robot's root
    namespace, and a name already under ``namespace`` is taken as routed (so the function is idempotent).
    """
    ns = normalize_namespace(namespace)
    name = resolve_topic(topic, ns)
    return name if ns == "/" or name.startswith(ns + "/") else ns + name


def bridge_key(topic: str) -> str:
    """Zenoh key of a topic routed by zenoh-bridge-ros2dds: its name (:func:`bridge_topic`) without the leading
    slash, e.g. ``robot1/odom``; no domain, type or hash."""
    return normalize_topic(topic)[1:]


def normalize_topic(topic: str) -> str:
    """Fully qualified topic name with one leading slash and no trailing slash; rejects empty chunks."""
    stripped = topic.strip().strip("/")
    if not stripped or "//" in stripped or any(c in stripped for c in "*$?#@% "):
        raise ConfigError(f"invalid ROS topic name {topic!r}")
    return "/" + stripped


#: Zenoh's reassembly limit is this many times the largest payload limit: messages up to it arrive and are
#: counted as too large; beyond it Zenoh drops them before allocating them.
ZENOH_MESSAGE_LIMIT_FACTOR = 2


@dataclass(frozen=True)
class BusTopics:
    """Topic names, types and validation settings of the bus.

    The fields from ``domain_id`` to ``max_cloud_bytes`` are the keys of the config's ``topics`` section
    (same names and defaults). ``status_key`` follows the config's ``name`` (:func:`status_key_for`).
    ``namespace`` is the ROS namespace of pivotd's node (the config's ``topics.namespace``): relative topic
    names, such as the defaults, resolve under it on construction (:func:`resolve_topic`), so the fields
    hold fully qualified names. The last two are settings for code that builds its own bus (tests, tools)
    and keep their defaults in the daemon: ``accept_empty_frame``: messages with an empty ``frame_id`` are
    taken as being in ``frame_id``; ``humble``: publish with rmw_zenoh's Humble key form (no type hash)
    instead of RIHS01 hashes. ``frame_id`` None accepts any frame.
    ``max_*_bytes``: payload size limits [bytes] of the pose, path, cloud and TF topics, checked before decoding.
    ``wire``: :data:`WIRE_RMW_ZENOH` or :data:`WIRE_ROS2DDS_BRIDGE`; with the bridge, ``namespace`` is the bridge's
    ``namespace`` and goes in front of every topic, absolute names too (:func:`bridge_topic`).
    ``joint_names``: the names of the pan and tilt joints in the published ``JointState`` (the URDF's, for
    ``robot_state_publisher``). ``publish_map``: the daemon latches the map file's landmarks on ``landmarks``.
    ``use_sim_time``: the stamps pivotd makes follow ``/clock`` (:data:`CLOCK_TOPIC`) instead of the wall clock.
    ``pose_source``: ``"topic"`` (the pose topic) or ``"tf"``: the pose of ``base_frame`` in ``map_frame``
    composed from ``tf`` and ``tf_static`` (:mod:`pivotd.bus.tf_tree`, at most ``tf_max_frames`` frames).
    """

    domain_id: int = 0
    pose: str = "odom"
    pose_type: str = ODOMETRY
    path: str = "plan"
    landmarks: str = "pivot/landmarks"
    targets: str = "pivot/targets"
    joint_states: str = "pivot/joint_states"
    view_plan: str = "pivot/view_plan"
    frame_id: str | None = "map"
    max_cloud_points: int = 1_000_000
    max_pose_bytes: int = 16 * 1024
    max_path_bytes: int = 4 * 1024 * 1024
    max_cloud_bytes: int = 32 * 1024 * 1024
    pose_source: str = POSE_SOURCE_TOPIC
    map_frame: str = "map"
    base_frame: str = "base_link"
    tf: str = "tf"
    tf_static: str = "tf_static"
    max_tf_bytes: int = 256 * 1024
    tf_max_frames: int = 256
    status_key: str = status_key_for("pivotd")
    accept_empty_frame: bool = True
    namespace: str = "/"
    humble: bool = False
    wire: str = WIRE_RMW_ZENOH
    joint_names: tuple[str, str] = DEFAULT_JOINT_NAMES
    publish_map: bool = True
    use_sim_time: bool = False

    def __post_init__(self) -> None:
        if self.wire not in WIRES:
            raise ConfigError(f"wire {self.wire!r} must be one of {', '.join(WIRES)}")
        problem = joint_names_problem(self.joint_names)
        if problem:
            raise ConfigError(f"joint_names: {problem}")
        object.__setattr__(self, "joint_names", tuple(self.joint_names))
        if self.pose_type not in POSE_TYPES:
            raise ConfigError(f"pose_type {self.pose_type!r} must be one of {', '.join(POSE_TYPES)}")
        if self.pose_source not in POSE_SOURCES:
            raise ConfigError(f"pose_source {self.pose_source!r} must be one of {', '.join(POSE_SOURCES)}")
        for name in ("map_frame", "base_frame"):
            frame = getattr(self, name)
            if not isinstance(frame, str) or not frame.strip().lstrip("/"):
                raise ConfigError(f"{name} must be a TF frame name, got {frame!r}")
        if self.map_frame.strip().lstrip("/") == self.base_frame.strip().lstrip("/"):
            raise ConfigError(f"map_frame and base_frame must differ, both are {self.map_frame!r}")
        if isinstance(self.tf_max_frames, bool) or not 1 <= self.tf_max_frames <= MAX_TF_FRAMES:
            raise ConfigError(f"tf_max_frames must be in 1..{MAX_TF_FRAMES}, got {self.tf_max_frames!r}")
        if self.max_cloud_points < 1:
            raise ConfigError(f"max_cloud_points must be >= 1, got {self.max_cloud_points}")
        for name in PAYLOAD_LIMITS:
            if getattr(self, name) < MIN_PAYLOAD_LIMIT:
                raise ConfigError(f"{name} must be >= {MIN_PAYLOAD_LIMIT}, got {getattr(self, name)}")
        if not isinstance(self.domain_id, int) or not 0 <= self.domain_id <= MAX_DOMAIN_ID:
            raise ConfigError(f"domain_id must be an integer in 0..{MAX_DOMAIN_ID}, got {self.domain_id!r}")
        object.__setattr__(self, "namespace", normalize_namespace(self.namespace))
        resolve = bridge_topic if self.bridged else resolve_topic
        for name in TOPIC_FIELDS:
            object.__setattr__(self, name, resolve(getattr(self, name), self.namespace))
        key = self.status_key
        if not key or key.startswith("/") or key.endswith("/") or any(c in key for c in "*$?# "):
            raise ConfigError(f"status_key {key!r} is not a plain Zenoh key such as pivot/pivotd/status")

    @property
    def bridged(self) -> bool:
        """Whether the topics are carried as zenoh-bridge-ros2dds routes them (``wire: ros2dds_bridge``)."""
        return self.wire == WIRE_ROS2DDS_BRIDGE

    @property
    def pose_from_tf(self) -> bool:
        """Whether the pose is composed from the TF tree rather than read from the pose topic."""
        return self.pose_source == POSE_SOURCE_TF

    @property
    def max_message_bytes(self) -> int:
        """Largest message [bytes] the session needs to reassemble (Zenoh drops larger ones unseen)."""
        return ZENOH_MESSAGE_LIMIT_FACTOR * max(getattr(self, name) for name in PAYLOAD_LIMITS)
