"""pivotd configuration: YAML -> typed, validated, frozen dataclasses (docs/CONFIG.md).

Angles in YAML carry a ``_deg`` suffix (``_deg_s``, ``_deg_s2``, ``_deg_s3`` for rates); the dataclasses hold
SI values (radians, seconds, metres) under the name without the suffix, with ``*_deg`` properties for
display. Relative file paths resolve against the directory of the config file. Every problem raises
:class:`~pivotd.errors.ConfigError` naming the file, line and key path, e.g.
``spot.yaml:41: gimbal.limits.tilt_max_deg: must be > tilt_min_deg (-45)``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass, field, fields, replace
from pathlib import Path

from pivotd.bus.qos import DURABILITY_NAMES, MAX_DEPTH, RELIABILITY_NAMES, QoS, TopicQoS
from pivotd.bus.security_settings import ZenohSecurity
from pivotd.bus.topics import (
    DEFAULT_JOINT_NAMES,
    MAX_DOMAIN_ID,
    MAX_TF_FRAMES,
    MIN_PAYLOAD_LIMIT,
    PAYLOAD_LIMITS,
    POSE_SOURCES,
    POSE_TYPES,
    WIRES,
    BusTopics,
    domain_id_from_env,
    joint_names_problem,
    status_key_for,
)
from pivotd.config.yaml_reader import Section, read_yaml
from pivotd.errors import ConfigError, InputError
from pivotd.firmware_proto.messages import Config as ConfigMessage
from pivotd.firmware_proto.messages import config_problems
from pivotd.gimbal import dynamixel_table
from pivotd.gimbal.kinematics import JointLimits, Mount
from pivotd.gimbal.motion import AxisLimits
from pivotd.maps.formats import weight_property_problem
from pivotd.maps.occlusion import voxel_problem
from pivotd.pivot.normalise import Normalisation
from pivotd.pivot.steps import MAX_STEP_RANGE_DEG

#: Most landmarks the live markers highlight (the planner reports at most this many in view).
MAX_MARKER_LANDMARKS = 500
LOG_LEVELS = ("DEBUG", "INFO", "WARNING", "ERROR", "CRITICAL")
ZENOH_MODES = ("peer", "client")
CONTROL_RATE_RANGE_HZ = (100.0, 200.0)
#: ``gimbal.backend`` values: pivotd's own serial protocol, MAVLink Gimbal Protocol v2, two DYNAMIXEL servos.
GIMBAL_BACKENDS = ("pivot", "mavlink", "dynamixel")
#: ``gimbal.baud`` when it is not set, per backend: the DYNAMIXEL X-series factory setting (Baud Rate = 1,
#: 57600 bps) so that new servos answer; 1 Mbps, set on the servos first, is what 100 Hz needs (docs/HARDWARE.md)
DEFAULT_BAUD = {"pivot": 115200, "mavlink": 115200, "dynamixel": dynamixel_table.FACTORY_BAUD}
#: Backends named in the docs that this version cannot drive yet (refused with a clear message).
GIMBAL_BACKENDS_UNAVAILABLE: tuple[str, ...] = ()
#: pymavlink connection strings the mavlink backend accepts (besides a serial device path).
MAVLINK_URL_PREFIXES = ("udpin:", "udpout:", "udp:", "tcp:", "tcpin:")

_NAME_RE = r"[A-Za-z0-9_][A-Za-z0-9_\-]*"
NAME_PATTERN = _NAME_RE  # of the config's ``name`` (also what ``pivotd status --name`` accepts)
_TOPIC_RE = r"/?[A-Za-z_][A-Za-z0-9_]*(/[A-Za-z_][A-Za-z0-9_]*)*"
_NAMESPACE_RE = r"/|(/[A-Za-z_][A-Za-z0-9_]*)+"
_FRAME_RE = r"[A-Za-z_][A-Za-z0-9_/]*"
_ENDPOINT_RE = re.compile(r"(?P<proto>[a-z][a-z0-9\-]*)/(?P<addr>[^#]+)(#.*)?")
_IP_PROTOCOLS = ("tcp", "udp", "tls", "quic", "ws")


@dataclass(frozen=True)
class ZenohConfig:
    """Zenoh session. Endpoints are locators such as ``tcp/127.0.0.1:7447``."""

    mode: str = "peer"
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    config_file: Path | None = None  # a Zenoh JSON5 config (TLS, auth) applied before the keys above
    multicast_scouting: bool = False
    security: ZenohSecurity = field(default_factory=ZenohSecurity)


@dataclass(frozen=True)
class MapFilters:
    """Per-waypoint landmark filters: ranges [m], view angle [rad] (None = off), occlusion voxel [m]."""

    min_range: float = 0.0
    max_range: float = 20.0
    max_view_angle: float | None = None
    occlusion_voxel: float | None = None
    occupancy_file: Path | None = None

    @property
    def max_view_angle_deg(self) -> float | None:
        return None if self.max_view_angle is None else math.degrees(self.max_view_angle)


@dataclass(frozen=True)
class MapLayers:
    """Weight multipliers of the landmark map and of the semantic targets."""

    landmarks: float = 1.0
    targets: float = 1.0


@dataclass(frozen=True)
class MapConfig:
    """Landmark map file (None only with ``allow_empty``: landmarks then arrive on the landmarks topic)."""

    file: Path | None = None
    weight_property: str | None = None
    allow_empty: bool = False
    filters: MapFilters = field(default_factory=MapFilters)
    layers: MapLayers = field(default_factory=MapLayers)
    max_landmarks_per_cell: int = 256  # the planner's queries read at most this many landmarks of one 1 m cell


@dataclass(frozen=True)
class PivotConfig:
    """Optimizer settings: full cone opening ``fov`` [rad] (α = fov/2), smoothness weight ``lam`` (λ)."""

    fov: float = math.radians(60.0)
    lam: float = 0.6
    transition_width: float = math.radians(4.0)
    iterations: int = 50
    distance_weights: bool = False  # true: eq. 15 of the paper (nearer landmarks weigh more); false: the count
    smooth_knee: float = math.radians(1.0)  # [rad] steps beyond about this cost in proportion to their size (0: the
    # paper's 1 − cos per step: a turn spread over many waypoints costs less than the same turn made at once)

    @property
    def fov_deg(self) -> float:
        return math.degrees(self.fov)

    @property
    def half_angle(self) -> float:
        """The paper's α [rad]."""
        return 0.5 * self.fov


@dataclass(frozen=True)
class PlannerConfig:
    """Receding horizon: waypoint spacing [m], horizon [waypoints], replanning rate [Hz], optional hard
    limit on the turn between consecutive planned directions [rad] (None: no limit)."""

    waypoint_spacing: float = 0.5
    horizon: int = 20
    replan_hz: float = 5.0
    max_landmarks_per_waypoint: int = 2000
    max_step: float | None = None
    max_path_offset: float = 3.0  # [m]: progress along the path advances only with the pose this close to it
    replan_on_waypoint: bool = False  # replan when the body moved one waypoint spacing (else at every tick)
    replan_max_interval: float = 1.0  # [s] with replan_on_waypoint: replan at least this often
    normalise: Normalisation = Normalisation.TOTAL  # per-waypoint visible term over total or attainable weight
    rescue_blind: bool = True  # a second solve where the warm plan sees < rescue_fraction of one cone's best
    rescue_fraction: float = 0.25  # (0, 1]: a waypoint is blind below this share of its attainable count
    replan_budget: float = 2.0  # [s] a replan slower than this is late: counted, and the next ones plan less
    replan_deadline: float = 30.0  # [s] a replan not answered by then (the worker busy all along) restarts it


def _default_limits() -> JointLimits:
    return JointLimits(pan_min=math.radians(-170.0), pan_max=math.radians(170.0), tilt_min=math.radians(-90.0),
                       tilt_max=math.radians(90.0))


@dataclass(frozen=True)
class MavlinkConfig:
    """MAVLink identities: ours (``system_id``, ``component_id``), the gimbal manager's (``target_system``,
    ``target_component``; 0 = the first one heard) and the gimbal device it manages (0 = all / the only one)."""

    system_id: int = 1
    component_id: int = 191  # MAV_COMP_ID_ONBOARD_COMPUTER
    target_system: int = 0
    target_component: int = 0
    gimbal_device_id: int = 0


@dataclass(frozen=True)
class DynamixelConfig:
    """The two servos of a DYNAMIXEL pan–tilt unit: bus ids, whether an axis turns the other way (positive
    pan left / positive tilt down = counter-clockwise seen from the horn unless reversed), and the servo
    position [ticks, 0–4095] of joint angle 0 on each axis."""

    pan_id: int = 1
    tilt_id: int = 2
    pan_reversed: bool = False
    tilt_reversed: bool = False
    pan_zero_tick: int = dynamixel_table.CENTRE_TICKS
    tilt_zero_tick: int = dynamixel_table.CENTRE_TICKS


@dataclass(frozen=True)
class GimbalConfig:
    """Backend and its port, mount, joint limits [rad], park pose [rad], device watchdog [ms], park timeout [s]."""

    backend: str = "pivot"
    port: str = "mock://"
    baud: int = 115200
    mount: Mount = field(default_factory=Mount)
    limits: JointLimits = field(default_factory=_default_limits)
    park_pan: float = 0.0
    park_tilt: float = 0.0
    watchdog_ms: int = 250
    park_timeout_s: float = 3.0
    mavlink: MavlinkConfig = field(default_factory=MavlinkConfig)
    dynamixel: DynamixelConfig = field(default_factory=DynamixelConfig)


@dataclass(frozen=True)
class MotionConfig:
    """Per-axis kinematic limits (SI) and the retarget deadband [rad]."""

    pan: AxisLimits = field(default_factory=lambda: _axis_limits_deg(90.0, 180.0, 900.0))
    tilt: AxisLimits = field(default_factory=lambda: _axis_limits_deg(90.0, 180.0, 900.0))
    deadband: float = math.radians(0.05)


@dataclass(frozen=True)
class ControlConfig:
    """Control loop rate [Hz], stale-pose timeout [s], status and joint-state publication rates [Hz]."""

    rate_hz: float = 100.0
    pose_timeout_s: float = 0.5
    status_hz: float = 2.0
    joint_state_hz: float = 50.0
    realtime_priority: int = 0  # SCHED_FIFO priority of the control thread (0: normal scheduling)
    tracking_error: float = math.radians(10.0)  # [rad] largest |commanded - measured| of an axis ...
    tracking_error_s: float = 0.2  # [s] ... for longer than this: the axis does not follow (tracking-error hold)

    @property
    def dt(self) -> float:
        """Control period [s]."""
        return 1.0 / self.rate_hz


@dataclass(frozen=True)
class PoseGateConfig:
    """Plausibility of a pose against the last accepted one: largest speed [m/s], largest single jump [m] and
    largest turn rate [rad/s] (docs/SECURITY.md)."""

    max_speed: float = 5.0
    max_jump: float = 2.0
    max_turn_rate: float = math.radians(360.0)


@dataclass(frozen=True)
class LoggingConfig:
    level: str = "INFO"


#: smallest ``record.max_bytes`` other than 0 [bytes]: a file holds at least one MCAP chunk or so
MIN_RECORD_BYTES = 1 << 20
#: smallest ``record.max_duration_s`` other than 0 [s]
MIN_RECORD_DURATION_S = 1.0


@dataclass(frozen=True)
class RecordConfig:
    """MCAP recording (pivotd/daemon/recorder.py): ``path`` a directory or a ``STEM.mcap`` name (None: no recording
    unless ``--record``); a new file past ``max_bytes`` [bytes] or ``max_duration_s`` [s] (0: never); map files up to
    ``map_max_bytes`` [bytes] in total are attached to each file (larger: their checksum only)."""

    path: Path | None = None
    max_bytes: int = 0
    max_duration_s: float = 0.0
    map_max_bytes: int = 64 * 1024 * 1024


@dataclass(frozen=True)
class SimConfig:
    """Simulated robot for the demo: route file (None = the built-in hallway), speed [m/s], pose rate [Hz]."""

    route: Path | None = None
    speed: float = 0.8
    pose_hz: float = 50.0
    loop: bool = True


@dataclass(frozen=True)
class RosConfig:
    """ROS 2 extras: live markers (sizes in m, at most ``marker_landmarks`` highlighted), the camera TF
    (off by default: for robots without another source of it) and the QoS of every topic."""

    markers: bool = True
    markers_topic: str = "pivot/markers"
    marker_range: float = 3.0
    marker_arrow_length: float = 1.0
    marker_landmarks: int = 200
    tf: bool = False
    tf_topic: str = "tf"
    camera_frame: str = "pivot_camera"
    qos: TopicQoS = field(default_factory=TopicQoS)
    diagnostics: bool = True
    diagnostics_topic: str = "/diagnostics"


@dataclass(frozen=True)
class Config:
    """A complete, validated pivotd configuration."""

    name: str = "pivotd"
    zenoh: ZenohConfig = field(default_factory=ZenohConfig)
    topics: BusTopics = field(default_factory=BusTopics)  # its status_key follows ``name``
    map: MapConfig = field(default_factory=MapConfig)
    pivot: PivotConfig = field(default_factory=PivotConfig)
    planner: PlannerConfig = field(default_factory=PlannerConfig)
    gimbal: GimbalConfig = field(default_factory=GimbalConfig)
    motion: MotionConfig = field(default_factory=MotionConfig)
    control: ControlConfig = field(default_factory=ControlConfig)
    logging: LoggingConfig = field(default_factory=LoggingConfig)
    pose_gate: PoseGateConfig = field(default_factory=PoseGateConfig)
    sim: SimConfig | None = None
    ros: RosConfig = field(default_factory=RosConfig)
    record: RecordConfig = field(default_factory=RecordConfig)
    source: Path | None = None  # the file this was loaded from

    def __post_init__(self) -> None:
        key = status_key_for(self.name)
        if self.topics.status_key != key:
            object.__setattr__(self, "topics", replace(self.topics, status_key=key))

    @property
    def status_key(self) -> str:
        """Plain Zenoh key of the JSON status: ``pivot/<name>/status``."""
        return self.topics.status_key

    def with_overrides(
        self,
        port: str | None = None,
        connect: list[str] | tuple[str, ...] | None = None,
        listen: list[str] | tuple[str, ...] | None = None,
    ) -> Config:
        """A copy with the command-line overrides (``--port``, ``--connect``, ``--listen``) applied and checked."""
        cfg = self
        if port is not None:
            if not port.strip():
                raise _cli_error("--port", "must not be empty")
            problem = port_problem(cfg.gimbal.backend, port)
            if problem:
                raise _cli_error("--port", problem)
            cfg = replace(cfg, gimbal=replace(cfg.gimbal, port=port))
        zenoh = cfg.zenoh
        for option, values in (("--connect", connect), ("--listen", listen)):
            if not values:
                continue
            for endpoint in values:
                problem = endpoint_problem(endpoint, listen=option == "--listen")
                if problem:
                    raise _cli_error(option, f"{endpoint!r}: {problem}")
            zenoh = replace(zenoh, **{option[2:]: tuple(values)})
        return replace(cfg, zenoh=zenoh)


def _cli_error(option: str, message: str) -> InputError:
    return InputError(f"{option}: {message}")


def _axis_limits_deg(v: float, a: float, j: float) -> AxisLimits:
    return AxisLimits(math.radians(v), math.radians(a), math.radians(j))


def endpoint_problem(endpoint: str, listen: bool = False) -> str | None:
    """Why ``endpoint`` is not a Zenoh locator like ``tcp/127.0.0.1:7447`` (None when it is fine)."""
    m = _ENDPOINT_RE.fullmatch(endpoint.strip())
    if m is None:
        return "expected <protocol>/<address>, e.g. tcp/127.0.0.1:7447"
    if m["proto"] in _IP_PROTOCOLS:
        host, sep, port = m["addr"].rpartition(":")
        if not sep or not host or not port.isdigit():
            return "expected <host>:<port> after the protocol"
        low = 0 if listen else 1
        if not low <= int(port) <= 65535:
            return f"port must be {low}..65535"
    return None


def port_problem(backend: str, port: str) -> str | None:
    """Why ``port`` cannot reach a gimbal of ``backend`` (None when it can)."""
    if backend == "mavlink":
        if port.startswith(MAVLINK_URL_PREFIXES) or port.startswith("/") or port.upper().startswith("COM"):
            return None
        return (f"{port!r} is not a MAVLink connection; expected udpin:HOST:PORT, udpout:HOST:PORT, tcp:HOST:PORT "
                "or a serial device such as /dev/ttyACM0")
    if backend == "dynamixel" and "://" in port:
        return f"{port!r}: the dynamixel backend opens a serial device path such as /dev/ttyUSB0, not a URL"
    return None


# ---------------------------------------------------------------------------- loading
def load_config(path: str | Path) -> Config:
    """Read and validate a config file; raises ConfigError naming file, line and key on any problem."""
    path = Path(path)
    if path.is_dir():
        raise ConfigError(f"{path}: is a directory, expected a YAML config file")
    root = Section(path, read_yaml(path))
    name = root.string("name", "pivotd", pattern=_NAME_RE, pattern_help="letters, digits, '_' and '-' only")
    control = _control(root.section("control"))
    cfg = Config(
        name=name,
        zenoh=_zenoh(root.section("zenoh")),
        topics=_topics(root.section("topics")),
        map=_map(root.section("map")),
        pivot=_pivot(root.section("pivot")),
        planner=_planner(root.section("planner"), control),
        gimbal=_gimbal(root.section("gimbal"), control),
        motion=_motion(root.section("motion")),
        control=control,
        logging=_logging(root.section("logging")),
        pose_gate=_pose_gate(root.section("pose_gate")),
        sim=_sim(root.section("sim")) if root.has("sim") else None,
        ros=_ros(root.section("ros")),
        record=_record(root.section("record")),
        source=path.resolve(),
    )
    _check_wire(root, cfg.gimbal, cfg.motion)
    root.finish()
    return cfg


# CONFIG message field -> (YAML key path, factor from the field's SI unit to the key's unit)
_WIRE_KEYS = {
    "pan_min": (("gimbal", "limits", "pan_min_deg"), math.degrees(1.0)),
    "pan_max": (("gimbal", "limits", "pan_max_deg"), math.degrees(1.0)),
    "tilt_min": (("gimbal", "limits", "tilt_min_deg"), math.degrees(1.0)),
    "tilt_max": (("gimbal", "limits", "tilt_max_deg"), math.degrees(1.0)),
    "vmax_pan": (("motion", "pan", "max_velocity_deg_s"), math.degrees(1.0)),
    "vmax_tilt": (("motion", "tilt", "max_velocity_deg_s"), math.degrees(1.0)),
    "amax_pan": (("motion", "pan", "max_acceleration_deg_s2"), math.degrees(1.0)),
    "amax_tilt": (("motion", "tilt", "max_acceleration_deg_s2"), math.degrees(1.0)),
    "watchdog_ms": (("gimbal", "watchdog_ms"), 1.0),
}


def wire_config(gimbal: GimbalConfig, motion: MotionConfig) -> ConfigMessage:
    """The CONFIG message the device receives for these settings: joint limits, and the motion limits as the
    device's rate limits (PROTOCOL.md §4)."""
    lim = gimbal.limits
    return ConfigMessage(
        pan_min=lim.pan_min, pan_max=lim.pan_max, tilt_min=lim.tilt_min, tilt_max=lim.tilt_max,
        vmax_pan=motion.pan.max_velocity, vmax_tilt=motion.tilt.max_velocity,
        amax_pan=motion.pan.max_acceleration, amax_tilt=motion.tilt.max_acceleration,
        watchdog_ms=gimbal.watchdog_ms,
    )


def _check_wire(root: Section, gimbal: GimbalConfig, motion: MotionConfig) -> None:
    """Refuse settings the gimbal protocol cannot carry or the device would refuse (so ``check`` passing
    means the device accepts the CONFIG); the error names the YAML key. Only for the ``pivot`` backend, whose
    device receives this message."""
    if gimbal.backend != "pivot":
        return
    msg = wire_config(gimbal, motion)
    for field_name, reason in config_problems(msg):
        keys, factor = _WIRE_KEYS[field_name]
        section = root
        for part in keys[:-1]:
            section = section.section(part)
        value = getattr(msg, field_name) * factor
        raise section.error(keys[-1], f"{value:g} cannot be sent to the gimbal: {reason}")


def _zenoh(s: Section) -> ZenohConfig:
    d = ZenohConfig()
    mode = s.string("mode", d.mode, choices=ZENOH_MODES)
    connect = s.string_list("connect", d.connect, check=endpoint_problem)
    listen = s.string_list("listen", d.listen, check=lambda e: endpoint_problem(e, listen=True))
    config_file = s.path_value("config_file", None)
    scouting = s.boolean("multicast_scouting", d.multicast_scouting)
    if mode == "client" and not connect and not scouting and config_file is None:
        raise s.error("connect", "client mode needs a router endpoint (or multicast_scouting: true)")
    if config_file is not None:
        _check_zenoh_file(s, mode, connect, listen, config_file, scouting)
    security = _zenoh_security(s.section("security"))
    s.finish()
    return ZenohConfig(mode, connect, listen, config_file, scouting, security)


_ZID_RE = r"[0-9a-f]{1,32}"
_PEM_FILES = ("ca", "cert", "key")


def _zenoh_security(s: Section) -> ZenohSecurity:
    d = ZenohSecurity()
    files = {k: s.path_value(k, None) for k in _PEM_FILES}
    given = [k for k, v in files.items() if v is not None]
    if given and len(given) < len(_PEM_FILES):
        missing = next(k for k in _PEM_FILES if files[k] is None)
        raise s.error(missing, f"required with {', '.join(given)} (mutual TLS needs ca, cert and key)")
    for k, path in files.items():
        if path is not None and (problem := _pem_problem(path)):
            raise s.error(k, f"{path}: {problem}")
    out = ZenohSecurity(
        **files,
        verify_name_on_connect=s.boolean("verify_name_on_connect", d.verify_name_on_connect),
        allow_cert_common_names=s.string_list("allow_cert_common_names", d.allow_cert_common_names,
                                              check=lambda v: None if v.strip() else "must not be empty"),
        allow_interfaces=s.string_list("allow_interfaces", d.allow_interfaces,
                                       check=lambda v: None if v.strip() else "must not be empty"),
        allow_zids=s.string_list("allow_zids", d.allow_zids, check=lambda v: None if re.fullmatch(_ZID_RE, v) else
                                 "a Zenoh id: 1 to 32 lowercase hex digits"),
    )
    if out.allow_cert_common_names and not out.tls:
        raise s.error("allow_cert_common_names", "needs mutual TLS (set ca, cert and key)")
    s.finish()
    return out


def _pem_problem(path: Path) -> str | None:
    """Why ``path`` is not a readable PEM file (None when it is)."""
    if not path.is_file():
        return "not a file"
    try:
        with path.open("rb") as fh:
            head = fh.read(64 * 1024)
    except OSError as exc:
        return f"cannot be read ({exc.strerror or exc})"
    return None if b"-----BEGIN " in head else "not a PEM file (no -----BEGIN line)"


def _check_zenoh_file(s: Section, mode: str, connect: tuple[str, ...], listen: tuple[str, ...], config_file: Path,
                      scouting: bool) -> None:
    """Parse ``zenoh.config_file`` with Zenoh's own loader, overlaid with the other keys as the daemon does."""
    from pivotd.bus.session import build_config

    try:
        build_config(mode, connect, listen, config_file, scouting)
    except ConfigError as exc:
        raise s.error("config_file", str(exc)) from None


def _topics(s: Section) -> BusTopics:
    d = BusTopics()
    relative = {f.name: f.default for f in fields(BusTopics)}  # the defaults as written: relative names
    help_topic = "a ROS 2 topic name such as /pivot/landmarks"

    def topic(key: str) -> str:
        return s.string(key, relative[key], pattern=_TOPIC_RE, pattern_help=help_topic)

    map_frame = s.string("map_frame", d.map_frame, pattern=_FRAME_RE, pattern_help="a TF frame name")
    base_frame = s.string("base_frame", d.base_frame, pattern=_FRAME_RE, pattern_help="a TF frame name")
    if base_frame.strip("/") == map_frame.strip("/"):
        raise s.error("base_frame", f"must differ from map_frame ({map_frame!r})")
    out = BusTopics(
        namespace=s.string("namespace", d.namespace, pattern=_NAMESPACE_RE,
                           pattern_help="a ROS namespace such as /robot1"),
        domain_id=_domain_id(s),
        humble=s.boolean("humble", d.humble),
        wire=s.string("wire", d.wire, choices=WIRES),
        pose=topic("pose"),
        pose_type=s.string("pose_type", d.pose_type, choices=POSE_TYPES),
        path=topic("path"),
        landmarks=topic("landmarks"),
        targets=topic("targets"),
        joint_states=topic("joint_states"),
        view_plan=topic("view_plan"),
        frame_id=s.string("frame_id", d.frame_id, pattern=_FRAME_RE, pattern_help="a TF frame name"),
        pose_source=s.string("pose_source", d.pose_source, choices=POSE_SOURCES),
        map_frame=map_frame,
        base_frame=base_frame,
        tf=topic("tf"),
        tf_static=topic("tf_static"),
        tf_max_frames=s.number("tf_max_frames", d.tf_max_frames, min=1, max=MAX_TF_FRAMES, integer=True),
        max_cloud_points=s.number("max_cloud_points", d.max_cloud_points, min=1, integer=True),
        joint_names=_joint_names(s),
        publish_map=s.boolean("publish_map", d.publish_map),
        use_sim_time=s.boolean("use_sim_time", d.use_sim_time),
        **{k: s.number(k, getattr(d, k), min=MIN_PAYLOAD_LIMIT, integer=True) for k in PAYLOAD_LIMITS},
    )
    s.finish()
    return out


def _domain_id(s: Section) -> int:
    """``topics.domain_id``; unset: ``ROS_DOMAIN_ID`` from the environment, else 0 (as ROS nodes do)."""
    if s.has("domain_id"):
        return s.number("domain_id", 0, min=0, max=MAX_DOMAIN_ID, integer=True)
    s.number("domain_id", None)  # a null value counts as unset
    try:
        return domain_id_from_env(os.environ)
    except ConfigError as exc:
        raise ConfigError(f"{s.file}: {exc}") from None


def _joint_names(s: Section) -> tuple[str, str]:
    names = s.string_list("joint_names", DEFAULT_JOINT_NAMES,
                          check=lambda n: None if n.strip() else "must be a non-empty joint name")
    problem = joint_names_problem(names)
    if problem:
        raise s.error("joint_names", problem)
    return names


def _map(s: Section) -> MapConfig:
    d = MapConfig()
    allow_empty = s.boolean("allow_empty", d.allow_empty)
    file = s.path_value("file", None)
    if file is None and not allow_empty:
        raise s.error("file", "required key is missing (or set map.allow_empty: true)")
    if file is not None and file.is_dir() and not (file / "points3D.bin").exists() and not (
        file / "points3D.txt"
    ).exists():
        raise s.error("file", f"{file} is a directory without a COLMAP points3D file")
    weight_property = s.string("weight_property", None)
    if weight_property is not None and file is not None and (
            problem := weight_property_problem(file, weight_property)) is not None:
        raise s.error("weight_property", f"{file}: {problem}")
    f = s.section("filters")
    fd = MapFilters()
    min_range = f.number("min_range", fd.min_range, min=0.0)
    max_range = f.number("max_range", fd.max_range, min=0.0, min_open=True)
    if max_range <= min_range:
        raise f.error("max_range", f"must be > min_range ({min_range:g})")
    view_deg = f.number("max_view_angle_deg", None, min=0.0, max=180.0, min_open=True)
    voxel = f.number("occlusion_voxel", None, min=0.0, min_open=True)
    if voxel is not None and (problem := voxel_problem(voxel, max_range)):
        raise f.error("occlusion_voxel", problem)
    filters = MapFilters(
        min_range=min_range,
        max_range=max_range,
        max_view_angle=None if view_deg is None else math.radians(view_deg),
        occlusion_voxel=voxel,
        occupancy_file=f.path_value("occupancy_file", None),
    )
    f.finish()
    layers_s = s.section("layers")
    layers = MapLayers(
        landmarks=layers_s.number("landmarks", MapLayers.landmarks, min=0.0),
        targets=layers_s.number("targets", MapLayers.targets, min=0.0),
    )
    layers_s.finish()
    cell_cap = s.number("max_landmarks_per_cell", MapConfig.max_landmarks_per_cell, min=1, integer=True)
    s.finish()
    return MapConfig(file, weight_property, allow_empty, filters, layers, cell_cap)


def _pivot(s: Section) -> PivotConfig:
    d = PivotConfig()
    fov_deg = s.number("fov_deg", d.fov_deg, min=0.0, max=180.0, min_open=True, max_open=True)
    width_deg = s.number("transition_width_deg", math.degrees(d.transition_width), min=0.0, max=45.0, min_open=True)
    out = PivotConfig(
        fov=math.radians(fov_deg),
        lam=s.number("lambda", d.lam, min=0.0),
        transition_width=math.radians(width_deg),
        iterations=s.number("iterations", d.iterations, min=1, max=10_000, integer=True),
        distance_weights=s.boolean("distance_weights", d.distance_weights),
        smooth_knee=math.radians(s.number("smooth_knee_deg", math.degrees(d.smooth_knee), min=0.0, max=180.0)),
    )
    s.finish()
    return out


def _radians_or_none(deg: float | None) -> float | None:
    return None if deg is None else math.radians(deg)


def _planner(s: Section, control: ControlConfig) -> PlannerConfig:
    d = PlannerConfig()
    out = PlannerConfig(
        waypoint_spacing=s.number("waypoint_spacing", d.waypoint_spacing, min=0.0, min_open=True),
        horizon=s.number("horizon", d.horizon, min=1, max=10_000, integer=True),
        replan_hz=s.number("replan_hz", d.replan_hz, min=0.0, max=control.rate_hz, min_open=True),
        max_landmarks_per_waypoint=s.number(
            "max_landmarks_per_waypoint", d.max_landmarks_per_waypoint, min=1, integer=True
        ),
        max_step=_radians_or_none(s.number("max_step_deg", None, min=MAX_STEP_RANGE_DEG[0], max=MAX_STEP_RANGE_DEG[1])),
        max_path_offset=s.number("max_path_offset", d.max_path_offset, min=0.0, min_open=True),
        replan_on_waypoint=s.boolean("replan_on_waypoint", d.replan_on_waypoint),
        replan_max_interval=s.number("replan_max_interval_s", d.replan_max_interval, min=0.0, min_open=True, max=10.0),
        normalise=Normalisation(s.string("normalise", d.normalise.value, choices=tuple(Normalisation))),
        rescue_blind=s.boolean("rescue_blind", d.rescue_blind),
        rescue_fraction=s.number("rescue_fraction", d.rescue_fraction, min=0.0, min_open=True, max=1.0),
        replan_budget=s.number("replan_budget_s", d.replan_budget, min=0.0, min_open=True, max=3600.0),
        replan_deadline=s.number("replan_deadline_s", d.replan_deadline, min=0.0, min_open=True, max=3600.0),
    )
    if out.replan_deadline < out.replan_budget:
        raise s.error("replan_deadline_s", f"must be ≥ replan_budget_s ({out.replan_budget:g})")
    s.finish()
    return out


def _gimbal(s: Section, control: ControlConfig) -> GimbalConfig:
    d = GimbalConfig()
    backend = s.string("backend", d.backend)
    if backend in GIMBAL_BACKENDS_UNAVAILABLE:
        raise s.error("backend", f"{backend!r} is not available in this version; use "
                                 f"{' or '.join(GIMBAL_BACKENDS)}")
    if backend not in GIMBAL_BACKENDS:
        raise s.error("backend", f"must be one of {', '.join(GIMBAL_BACKENDS)}; got {backend!r}")
    port = s.string("port", d.port)
    if not port.strip():
        raise s.error("port", "must not be empty (a device such as /dev/ttyUSB0 or a pyserial URL)")
    problem = port_problem(backend, port)
    if problem:
        raise s.error("port", problem)
    baud = s.number("baud", DEFAULT_BAUD.get(backend, d.baud), min=1, integer=True)

    m = s.section("mount")
    xyz = m.vector("xyz", None)
    rpy_deg = m.vector("rpy_deg", None)
    m.finish()
    mount = d.mount
    if xyz is not None or rpy_deg is not None:
        mount = Mount.from_xyz_rpy(xyz or tuple(d.mount.translation),
                                   [math.radians(a) for a in (rpy_deg or (0.0, 0.0, 0.0))])  # rpy: none rotates

    lim = s.section("limits")
    dl = d.limits
    continuous = lim.boolean("continuous_pan", dl.continuous_pan)
    pan_min = lim.number("pan_min_deg", math.degrees(dl.pan_min), min=-720.0, max=720.0)
    pan_max = lim.number("pan_max_deg", math.degrees(dl.pan_max), min=-720.0, max=720.0)
    tilt_min = lim.number("tilt_min_deg", math.degrees(dl.tilt_min), min=-180.0, max=180.0)
    tilt_max = lim.number("tilt_max_deg", math.degrees(dl.tilt_max), min=-180.0, max=180.0)
    if pan_max <= pan_min:
        raise lim.error("pan_max_deg", f"must be > pan_min_deg ({pan_min:g})")
    if tilt_max <= tilt_min:
        raise lim.error("tilt_max_deg", f"must be > tilt_min_deg ({tilt_min:g})")
    lim.finish()
    limits = JointLimits(
        pan_min=math.radians(pan_min),
        pan_max=math.radians(pan_max),
        tilt_min=math.radians(tilt_min),
        tilt_max=math.radians(tilt_max),
        continuous_pan=continuous,
    )

    park = s.section("park")
    park_pan = park.number("pan_deg", math.degrees(d.park_pan))
    park_tilt = park.number("tilt_deg", math.degrees(d.park_tilt))
    if not continuous and not pan_min <= park_pan <= pan_max:
        raise park.error("pan_deg", f"must lie within the pan limits [{pan_min:g}, {pan_max:g}]")
    if not tilt_min <= park_tilt <= tilt_max:
        raise park.error("tilt_deg", f"must lie within the tilt limits [{tilt_min:g}, {tilt_max:g}]")
    park.finish()

    period_ms = 1000.0 / control.rate_hz
    watchdog_ms = s.number("watchdog_ms", d.watchdog_ms, min=1, max=65535, integer=True)
    if watchdog_ms < 3 * period_ms:
        raise s.error("watchdog_ms", f"must be ≥ 3 control periods ({3 * period_ms:g} ms at {control.rate_hz:g} Hz)")
    out = GimbalConfig(
        backend=backend,
        port=port,
        baud=baud,
        mount=mount,
        limits=limits,
        park_pan=math.radians(park_pan),
        park_tilt=math.radians(park_tilt),
        watchdog_ms=watchdog_ms,
        park_timeout_s=s.number("park_timeout_s", d.park_timeout_s, min=0.0, min_open=True),
        mavlink=_mavlink(s.section("mavlink")),
        dynamixel=_dynamixel(s.section("dynamixel"), lim if backend == "dynamixel" else None, limits),
    )
    s.finish()
    return out


def _dynamixel(s: Section, lim: Section | None, limits: JointLimits) -> DynamixelConfig:
    """The ``gimbal.dynamixel`` section; with ``lim`` (the backend is dynamixel) the joint limits must also fit the
    servos' 0–4095 ticks around each zero tick (blamed on the zero tick when it is set, else on the limit)."""
    d = DynamixelConfig()
    pan_id = s.number("pan_id", d.pan_id, min=0, max=252, integer=True)
    tilt_id = s.number("tilt_id", d.tilt_id, min=0, max=252, integer=True)
    if tilt_id == pan_id:
        raise s.error("tilt_id", f"must differ from pan_id ({pan_id})")
    out = DynamixelConfig(pan_id, tilt_id, s.boolean("pan_reversed", d.pan_reversed),
                          s.boolean("tilt_reversed", d.tilt_reversed),
                          s.number("pan_zero_tick", d.pan_zero_tick, min=0, max=dynamixel_table.MAX_TICK, integer=True),
                          s.number("tilt_zero_tick", d.tilt_zero_tick, min=0, max=dynamixel_table.MAX_TICK,
                                   integer=True))
    if lim is not None:
        if limits.continuous_pan:
            raise lim.error("continuous_pan", "the dynamixel backend drives the servos in Position Control Mode "
                                              "(within ±180°): no continuous pan")
        for axis, lo, hi, rev, zero in (("pan", limits.pan_min, limits.pan_max, out.pan_reversed, out.pan_zero_tick),
                                        ("tilt", limits.tilt_min, limits.tilt_max, out.tilt_reversed,
                                         out.tilt_zero_tick)):
            problem = dynamixel_table.position_limits_problem(axis, lo, hi, rev, zero)
            if problem is None:
                continue
            if s.has(f"{axis}_zero_tick"):
                raise s.error(f"{axis}_zero_tick", problem)
            end = "min" if dynamixel_table.position_limits_problem(axis, lo, lo, rev, zero) else "max"
            raise lim.error(f"{axis}_{end}_deg", problem)
    s.finish()
    return out


def _mavlink(s: Section) -> MavlinkConfig:
    d = MavlinkConfig()

    def ident(key: str, low: int) -> int:
        return s.number(key, getattr(d, key), min=low, max=255, integer=True)

    out = MavlinkConfig(
        system_id=ident("system_id", 1),
        component_id=ident("component_id", 1),
        target_system=ident("target_system", 0),
        target_component=ident("target_component", 0),
        gimbal_device_id=ident("gimbal_device_id", 0),
    )
    s.finish()
    return out


def _axis(s: Section, default: AxisLimits) -> AxisLimits:
    def deg(key: str, value: float) -> float:
        return math.radians(s.number(key, math.degrees(value), min=0.0, min_open=True))

    out = AxisLimits(
        max_velocity=deg("max_velocity_deg_s", default.max_velocity),
        max_acceleration=deg("max_acceleration_deg_s2", default.max_acceleration),
        max_jerk=deg("max_jerk_deg_s3", default.max_jerk),
    )
    s.finish()
    return out


def _motion(s: Section) -> MotionConfig:
    d = MotionConfig()
    out = MotionConfig(
        pan=_axis(s.section("pan"), d.pan),
        tilt=_axis(s.section("tilt"), d.tilt),
        deadband=math.radians(s.number("deadband_deg", math.degrees(d.deadband), min=0.0, max=10.0)),
    )
    s.finish()
    return out


def _control(s: Section) -> ControlConfig:
    d = ControlConfig()
    lo, hi = CONTROL_RATE_RANGE_HZ
    rate = s.number("rate_hz", d.rate_hz, min=lo, max=hi)
    out = ControlConfig(
        rate_hz=rate,
        pose_timeout_s=s.number("pose_timeout_s", d.pose_timeout_s, min=0.0, min_open=True),
        status_hz=s.number("status_hz", d.status_hz, min=1.0, max=5.0),
        joint_state_hz=s.number("joint_state_hz", d.joint_state_hz, min=0.0, max=rate, min_open=True),
        realtime_priority=s.number("realtime_priority", d.realtime_priority, min=0, max=99, integer=True),
        tracking_error=math.radians(s.number("tracking_error_deg", math.degrees(d.tracking_error), min=0.0,
                                             max=180.0, min_open=True)),
        tracking_error_s=s.number("tracking_error_s", d.tracking_error_s, min=2.0 / rate, max=10.0),
    )
    s.finish()
    return out


def _pose_gate(s: Section) -> PoseGateConfig:
    d = PoseGateConfig()
    out = PoseGateConfig(
        max_speed=s.number("max_speed", d.max_speed, min=0.0, min_open=True),
        max_jump=s.number("max_jump", d.max_jump, min=0.0, min_open=True),
        max_turn_rate=math.radians(s.number("max_turn_rate_deg_s", math.degrees(d.max_turn_rate), min=0.0,
                                            min_open=True)),
    )
    s.finish()
    return out


def _logging(s: Section) -> LoggingConfig:
    level = s.string("level", LoggingConfig().level)
    if level.upper() not in LOG_LEVELS:
        raise s.error("level", f"must be one of {', '.join(LOG_LEVELS)}; got {level!r}")
    s.finish()
    return LoggingConfig(level.upper())


def _record(s: Section) -> RecordConfig:
    d = RecordConfig()
    max_bytes = s.number("max_bytes", d.max_bytes, min=0, integer=True)
    if 0 < max_bytes < MIN_RECORD_BYTES:
        raise s.error("max_bytes", f"must be 0 (no limit) or ≥ {MIN_RECORD_BYTES} (1 MiB), got {max_bytes}")
    max_duration = s.number("max_duration_s", d.max_duration_s, min=0.0)
    if 0 < max_duration < MIN_RECORD_DURATION_S:
        raise s.error("max_duration_s", f"must be 0 (no limit) or ≥ {MIN_RECORD_DURATION_S:g} s, got {max_duration:g}")
    out = RecordConfig(
        path=s.path_value("path", None, must_exist=False),
        max_bytes=max_bytes,
        max_duration_s=max_duration,
        map_max_bytes=s.number("map_max_bytes", d.map_max_bytes, min=0, integer=True),
    )
    s.finish()
    return out


def _sim(s: Section) -> SimConfig:
    d = SimConfig()
    out = SimConfig(
        route=s.path_value("route", None),
        speed=s.number("speed", d.speed, min=0.0, max=10.0, min_open=True),
        pose_hz=s.number("pose_hz", d.pose_hz, min=1.0, max=1000.0),
        loop=s.boolean("loop", d.loop),
    )
    s.finish()
    return out


def _ros(s: Section) -> RosConfig:
    d = RosConfig()
    help_topic = "a ROS 2 topic name such as /pivot/markers"
    q = s.section("qos")
    per_topic = {}
    for name in TopicQoS.__dataclass_fields__:
        t = q.section(name)
        reliability, durability, depth = getattr(d.qos, name).names()
        per_topic[name] = QoS.named(
            t.string("reliability", reliability, choices=tuple(RELIABILITY_NAMES)),
            t.string("durability", durability, choices=tuple(DURABILITY_NAMES)),
            t.number("depth", depth, min=1, max=MAX_DEPTH, integer=True))
        t.finish()
    q.finish()
    out = RosConfig(
        markers=s.boolean("markers", d.markers),
        markers_topic=s.string("markers_topic", d.markers_topic, pattern=_TOPIC_RE, pattern_help=help_topic),
        marker_range=s.number("marker_range", d.marker_range, min=0.0, max=1000.0, min_open=True),
        marker_arrow_length=s.number("marker_arrow_length", d.marker_arrow_length, min=0.0, max=1000.0,
                                     min_open=True),
        marker_landmarks=s.number("marker_landmarks", d.marker_landmarks, min=0, max=MAX_MARKER_LANDMARKS,
                                  integer=True),
        tf=s.boolean("tf", d.tf),
        tf_topic=s.string("tf_topic", d.tf_topic, pattern=_TOPIC_RE, pattern_help=help_topic),
        camera_frame=s.string("camera_frame", d.camera_frame, pattern=_FRAME_RE, pattern_help="a TF frame name"),
        qos=TopicQoS(**per_topic),
        diagnostics=s.boolean("diagnostics", d.diagnostics),
        diagnostics_topic=s.string("diagnostics_topic", d.diagnostics_topic, pattern=_TOPIC_RE,
                                   pattern_help=help_topic),
    )
    s.finish()
    return out
