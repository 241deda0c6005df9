"""What ``pivotd check`` finds beyond the config loader: what would make ``run`` fail or the gimbal idle
(errors), and values that parse but are implausible, typically radians typed into a degree key (warnings).

Static findings read only the config, the file system and the importable packages; live findings
(:func:`live_findings`) open the serial device, connect to a TCP port or ask a Zenoh router, and are skipped
by ``check --offline``. Each finding names its YAML key (and line, when the key is in the file).
"""

from __future__ import annotations

import math
import os
import socket
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from pivotd.compat import StrEnum
from pivotd.config import Config
from pivotd.config.yaml_reader import Node, read_yaml
from pivotd.errors import ConfigError
from pivotd.maps.formats import LandmarkCloud

#: Directories pivotd.service hides from the daemon (ProtectHome=yes).
PROTECTED_HOME = (Path("/home"), Path("/root"), Path("/run/user"))
#: How long a live probe (TCP connect, Zenoh router) may take [s].
PROBE_TIMEOUT_S = 1.0

# Implausibility thresholds, in the keys' units: below them a value was most likely typed in radians.
MIN_FOV_DEG = 5.0
MIN_JOINT_RANGE_DEG = 10.0
MIN_VELOCITY_DEG_S = 5.0
MIN_ACCELERATION_DEG_S2 = 10.0
MIN_JERK_DEG_S3 = 10.0
MIN_MOUNT_ANGLE_DEG = 0.5


class Severity(StrEnum):
    """An error makes ``check`` exit 2; a warning is printed (exit 1 only with ``--strict``)."""

    ERROR = "error"
    WARNING = "warning"


class PortKind(StrEnum):
    """What ``gimbal.port`` names, which decides how it is checked."""

    DEVICE = "device"  # a serial device path: must exist (static) and open (live)
    TCP = "tcp"  # socket://HOST:PORT, MAVLink tcp:HOST:PORT: a TCP connect (live)
    MOCK = "mock"  # mock://: the in-process device model, nothing to check
    OTHER = "other"  # UDP, loop://, rfc2217:// …: not probed


@dataclass(frozen=True)
class Finding:
    """One problem of a config: severity, dotted YAML key, one-line message, line in the config (None: a default)."""

    severity: Severity
    key: str
    message: str
    line: int | None = None

    def text(self, source: Path | None) -> str:
        where = f"{source}:{self.line}" if self.line is not None else str(source)
        return f"{where}: {self.key}: {self.message}"


class RawConfig:
    """The config file's YAML tree, for the line of a key and the values as written."""

    def __init__(self, root: Node) -> None:
        self.root = root

    @classmethod
    def read(cls, cfg: Config) -> RawConfig:
        return cls(read_yaml(cfg.source) if cfg.source is not None else Node({}, None))

    def node(self, key: str) -> Node | None:
        node: Node | None = self.root
        for part in key.split("."):
            if node is None or not isinstance(node.value, dict):
                return None
            node = node.value.get(part)
        return node

    def line(self, key: str) -> int | None:
        """The line of ``key``, else of its nearest parent in the file, else None."""
        parts = key.split(".")
        while parts:
            node = self.node(".".join(parts))
            if node is not None:
                return node.line
            parts.pop()
        return None

    def value(self, key: str) -> Any:
        """The value at ``key`` as plain Python (lists and dicts unwrapped), None when absent."""
        return _plain(self.node(key))


def _plain(node: Node | None) -> Any:
    if node is None:
        return None
    if isinstance(node.value, dict):
        return {k: _plain(v) for k, v in node.value.items()}
    if isinstance(node.value, list):
        return [_plain(v) for v in node.value]
    return node.value


def finding(raw: RawConfig, severity: Severity, key: str, message: str) -> Finding:
    return Finding(severity, key, message, raw.line(key))


# ------------------------------------------------------------------------------------------ static
def under_system_unit() -> bool:
    """Whether this process is a system service's (pivotd.service's ExecStartPre): systemd sets ``$INVOCATION_ID``
    for a unit's processes and the system manager (PID 1) is their parent. The parent tells it apart from a shell
    in a terminal that runs as a user service and passes its ``$INVOCATION_ID`` on."""
    return bool(os.environ.get("INVOCATION_ID")) and os.getppid() == 1


def static_findings(cfg: Config, raw: RawConfig, under_systemd: bool, offline: bool = False) -> list[Finding]:
    """Errors that need no map: the backend's package, the serial device, files hidden by the unit's sandbox
    (``offline``: a device that is absent now is a warning, see :func:`port_static`)."""
    out = [f for f in (backend_package(cfg, raw), port_static(cfg, raw, offline)) if f is not None]
    return out + protected_home(cfg, raw, under_systemd)


def backend_package(cfg: Config, raw: RawConfig) -> Finding | None:
    """The optional package the backend imports when the daemon starts it (pivotd[dynamixel], pivotd[mavlink])."""
    backend = cfg.gimbal.backend
    try:
        if backend == "dynamixel":
            from pivotd.gimbal.dynamixel_link import load_sdk

            load_sdk()
        elif backend == "mavlink":
            from pivotd.gimbal.mavlink_link import load_mavutil

            load_mavutil()
    except ConfigError as exc:
        return finding(raw, Severity.ERROR, "gimbal.backend", str(exc).removeprefix("gimbal.backend: "))
    return None


def port_kind(backend: str, port: str) -> PortKind:
    """How ``port`` of ``backend`` is reached (the config loader has refused ports a backend cannot open)."""
    if backend == "mavlink":
        if port.startswith("/"):
            return PortKind.DEVICE
        return PortKind.TCP if port.startswith("tcp:") else PortKind.OTHER
    if port.startswith("mock://"):
        return PortKind.MOCK
    if port.startswith("socket://"):
        return PortKind.TCP
    return PortKind.OTHER if "://" in port else PortKind.DEVICE


def _tcp_address(port: str) -> tuple[str, int] | None:
    rest = port.removeprefix("socket://").removeprefix("tcp:").split("?", 1)[0].rstrip("/")
    host, sep, number = rest.rpartition(":")
    return (host.strip("[]"), int(number)) if sep and host and number.isdigit() else None


def port_static(cfg: Config, raw: RawConfig, offline: bool = False) -> Finding | None:
    """A device path that does not exist, is a directory, or that this user may not read and write.

    A device that does not exist is an error, except ``offline`` (the unit's check before each start): the daemon
    waits for an adapter plugged in later, holding, so there it is a warning."""
    g = cfg.gimbal
    kind = port_kind(g.backend, g.port)
    if kind is PortKind.TCP and _tcp_address(g.port) is None:
        return finding(raw, Severity.ERROR, "gimbal.port", f"{g.port!r}: expected HOST:PORT after the scheme")
    if kind is not PortKind.DEVICE:
        return None
    path = Path(g.port)
    if not path.exists():
        dangling = " (a dangling symlink: the adapter is unplugged?)" if path.is_symlink() else ""
        if offline:
            return finding(raw, Severity.WARNING, "gimbal.port", f"{g.port}: no such device now{dangling}; the "
                           "daemon waits for it, holding")
        return finding(raw, Severity.ERROR, "gimbal.port", f"{g.port}: no such device{dangling}")
    if path.is_dir():
        return finding(raw, Severity.ERROR, "gimbal.port", f"{g.port}: is a directory, not a serial device")
    if not os.access(path, os.R_OK | os.W_OK):
        return finding(raw, Severity.ERROR, "gimbal.port", f"{g.port}: permission denied for this user (the "
                       "service user pivotd opens it through group dialout)")
    return None


def configured_files(cfg: Config) -> Iterator[tuple[str, Path]]:
    """Every file or directory the config names, by dotted key."""
    z, m = cfg.zenoh, cfg.map
    candidates = [("map.file", m.file), ("map.filters.occupancy_file", m.filters.occupancy_file),
                  ("zenoh.config_file", z.config_file), ("record.path", cfg.record.path),
                  ("sim.route", cfg.sim.route if cfg.sim is not None else None)]
    candidates += [(f"zenoh.security.{k}", getattr(z.security, k)) for k in ("ca", "cert", "key")]
    for key, path in candidates:
        if path is not None:
            yield key, Path(path)


def protected_home(cfg: Config, raw: RawConfig, under_systemd: bool) -> list[Finding]:
    """Files under /home, /root or /run/user, which pivotd.service hides (ProtectHome=yes): a warning, and an
    error when ``check`` runs as a system service (:func:`under_system_unit`), where the daemon cannot see them."""
    severity = Severity.ERROR if under_systemd else Severity.WARNING
    out = []
    for key, path in configured_files(cfg):
        absolute = Path(os.path.abspath(path))
        hidden = next((d for d in PROTECTED_HOME if absolute.is_relative_to(d)), None)
        if hidden is not None:
            out.append(finding(raw, severity, key, f"{path} is under {hidden}, which pivotd.service hides from the "
                               "daemon (ProtectHome=yes): keep it under /etc/pivotd or /var/lib/pivotd"))
    return out


# ------------------------------------------------------------------------------------------ warnings
def plausibility_findings(cfg: Config, raw: RawConfig) -> list[Finding]:
    """Warnings on values that parse but are implausible (most likely radians in a degree key)."""
    out: list[Finding] = []

    def warn(key: str, message: str) -> None:
        out.append(finding(raw, Severity.WARNING, key, message))

    fov, width = math.degrees(cfg.pivot.fov), math.degrees(cfg.pivot.transition_width)
    if fov < MIN_FOV_DEG:
        warn("pivot.fov_deg", f"{fov:g}° is a very narrow cone (< {MIN_FOV_DEG:g}°): radians in a degree key?")
    elif fov <= width:
        warn("pivot.fov_deg", f"{fov:g}° is not wider than pivot.transition_width_deg ({width:g}°): the cone is "
             "all soft edge")
    lim = cfg.gimbal.limits
    axes = [("tilt", lim.tilt_min, lim.tilt_max)]
    if not lim.continuous_pan:
        axes.insert(0, ("pan", lim.pan_min, lim.pan_max))
    for axis, lo, hi in axes:
        span = math.degrees(hi - lo)
        if span < MIN_JOINT_RANGE_DEG:
            warn(f"gimbal.limits.{axis}_max_deg", f"the {axis} range [{math.degrees(lo):g}, {math.degrees(hi):g}]° "
                 f"spans only {span:g}° (< {MIN_JOINT_RANGE_DEG:g}°): radians in a degree key?")
    for axis, limits in (("pan", cfg.motion.pan), ("tilt", cfg.motion.tilt)):
        for name, value, floor, unit in (("max_velocity_deg_s", limits.max_velocity, MIN_VELOCITY_DEG_S, "°/s"),
                                         ("max_acceleration_deg_s2", limits.max_acceleration,
                                          MIN_ACCELERATION_DEG_S2, "°/s²"),
                                         ("max_jerk_deg_s3", limits.max_jerk, MIN_JERK_DEG_S3, "°/s³")):
            if math.degrees(value) < floor:
                warn(f"motion.{axis}.{name}", f"{math.degrees(value):g}{unit} is implausibly slow (< {floor:g}"
                     f"{unit}): radians in a degree key?")
    rpy = raw.value("gimbal.mount.rpy_deg")
    numbers = isinstance(rpy, list) and all(isinstance(a, int | float) for a in rpy)
    if numbers and any(a != 0 for a in rpy) and all(abs(a) < MIN_MOUNT_ANGLE_DEG for a in rpy):
        warn("gimbal.mount.rpy_deg", f"{rpy}: every angle is below {MIN_MOUNT_ANGLE_DEG:g}° but not all are 0: "
             "radians in a degree key?")
    return out


def map_has_directions(cloud: LandmarkCloud | None) -> bool:
    """Whether the loaded map carries mean observation directions (landmarks from the topic never do)."""
    return cloud is not None and cloud.directions is not None


def filter_findings(cfg: Config, raw: RawConfig, cloud: LandmarkCloud | None) -> list[Finding]:
    """A view-angle filter on a map without observation directions drops nothing (pivotd.maps.store)."""
    if cfg.map.filters.max_view_angle is None or map_has_directions(cloud):
        return []
    source = (f"{cfg.map.file} has none" if cfg.map.file is not None
              else f"there is no map.file and landmarks on {cfg.topics.landmarks} carry none")
    return [finding(raw, Severity.WARNING, "map.filters.max_view_angle_deg",
                    f"drops nothing: it needs the map's observation directions and {source} (a COLMAP model with "
                    "images.bin or images.txt beside points3D has them)")]


# ------------------------------------------------------------------------------------------ live
def live_findings(cfg: Config, raw: RawConfig) -> list[Finding]:
    """Probes skipped by ``--offline``: open the serial device, connect to a TCP port, reach the Zenoh router."""
    return [f for f in (port_live(cfg, raw), router_live(cfg, raw)) if f is not None]


def port_live(cfg: Config, raw: RawConfig) -> Finding | None:
    """Open (and close at once) the serial device, or connect to the TCP port, as the backend will."""
    g = cfg.gimbal
    kind = port_kind(g.backend, g.port)
    if kind is PortKind.DEVICE:
        try:
            os.close(os.open(g.port, os.O_RDWR | os.O_NOCTTY | os.O_NONBLOCK))
        except OSError as exc:
            return finding(raw, Severity.ERROR, "gimbal.port",
                           f"{g.port}: cannot be opened: {exc.strerror or exc} (--offline skips this)")
    elif kind is PortKind.TCP:
        address = _tcp_address(g.port)
        assert address is not None  # port_static refused it
        try:
            socket.create_connection(address, timeout=PROBE_TIMEOUT_S).close()
        except OSError as exc:
            return finding(raw, Severity.ERROR, "gimbal.port", f"{g.port}: no connection to {address[0]}:"
                           f"{address[1]}: {exc.strerror or exc} (--offline skips this)")
    return None


def router_live(cfg: Config, raw: RawConfig) -> Finding | None:
    """Client mode: whether a router answers on ``zenoh.connect`` within :data:`PROBE_TIMEOUT_S`."""
    z = cfg.zenoh
    if z.mode != "client" or not z.connect:
        return None
    from pivotd.bus.security import input_key_exprs
    from pivotd.bus.session import RouterUnreachableError, open_session

    try:
        session = open_session(z.mode, z.connect, (), z.config_file, z.multicast_scouting, z.security,
                               input_key_exprs(cfg.topics), connect_timeout_s=PROBE_TIMEOUT_S, warn=False)
    except RouterUnreachableError:
        return finding(raw, Severity.ERROR, "zenoh.connect",
                       f"no Zenoh router answers at {', '.join(z.connect)} within {PROBE_TIMEOUT_S:g} s (run would "
                       "wait for one, holding the gimbal; --offline skips this)")
    session.close()
    return None
