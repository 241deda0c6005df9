"""Reading a daemon's MCAP recording (``pivotd --record``) into arrays for figures.

Times are the recording's log times (the daemon's wall clock when it received or sent a message) in seconds
since the first recorded message, so inputs from other machines and the daemon's own outputs share one clock.

The run's config and map come from the recording itself when the files it names are not here as they were (another
machine, a config edited since): the config text and the map files it carries (pivotd/daemon/recorder.py). A name
that is no file finds the newest recording of that target (``out/demo/run.mcap`` → ``out/demo/run-…mcap``).
"""

from __future__ import annotations

import datetime
import json
import logging
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from pivotd.bus import messages as m
from pivotd.config import Config, load_config
from pivotd.daemon.recorder import (
    CONFIG_ATTACHMENT,
    JOINT_COMMAND_TOPIC,
    MAP_ATTACHMENT_PREFIX,
    MAP_METADATA_NAME,
    METADATA_NAME,
    STATE_TOPIC,
    STATUS_TOPIC,
    TF_POSE_TOPIC,
    map_checksum,
    resolve_recording,
)
from pivotd.daemon.timeline import STRING, decode_text
from pivotd.errors import InputError
from pivotd.maps.formats import load_landmarks

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class JointSeries:
    """Pan/tilt samples: times t (N,) [s], angles (N, 2) [rad], rates (N, 2) [rad/s] (NaN when not sent)."""

    t: np.ndarray
    angles: np.ndarray
    rates: np.ndarray

    def __len__(self) -> int:
        return int(self.t.shape[0])


@dataclass(frozen=True)
class StateEvent:
    """One change on the recording's state channel (pivotd/daemon/timeline.py): ``t`` [s since the recording's
    first message], ``kind`` (``state``, ``link``, ``faults``, ``threads_dead``), ``value`` and ``previous`` (None
    for the first of its kind), ``wall_time`` [s since the epoch], ``monotonic`` [s, the daemon's clock] and the
    rest of the message (``faults``: ``names``, ``mode``)."""

    t: float
    kind: str
    value: Any
    previous: Any
    wall_time: float
    monotonic: float
    extra: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class Recording:
    """What a recording holds for plotting: the run's config, body poses (times (P,) [s], positions (P, 3) [m],
    quaternions (P, 4) x y z w), measured joints (``joint_states``), commanded joints (the setpoints sent; empty
    in recordings made before they were recorded) and the landmarks (M, 3) [m] the run planned against; the state
    timeline (in time order; empty in recordings made before it was recorded), the status documents recorded at
    1 Hz as (t [s], document) and the UTC time of the first message (``start``; t = 0)."""

    path: Path
    cfg: Config
    pose_t: np.ndarray
    pose_pos: np.ndarray
    pose_quat: np.ndarray
    measured: JointSeries
    commanded: JointSeries
    landmarks: np.ndarray
    timeline: list[StateEvent] = field(default_factory=list)
    statuses: list[tuple[float, dict[str, Any]]] = field(default_factory=list)
    start: datetime.datetime | None = None

    def states(self, kind: str = "state") -> list[StateEvent]:
        """The timeline's events of one ``kind``."""
        return [e for e in self.timeline if e.kind == kind]


def _empty_joints() -> JointSeries:
    return JointSeries(np.zeros(0), np.zeros((0, 2)), np.zeros((0, 2)))


def _joints(rows: list[tuple[float, object]]) -> JointSeries:
    """JointState messages (log time, message) -> pan/tilt series (the joints named pan/tilt, else the first two)."""
    t, angles, rates = [], [], []
    for time_s, msg in sorted(rows, key=lambda r: r[0]):
        names = list(msg.name)
        idx = [names.index("pan"), names.index("tilt")] if {"pan", "tilt"} <= set(names) else [0, 1]
        pos = np.asarray(msg.position, float)
        vel = np.asarray(msg.velocity, float)
        if pos.shape[0] <= max(idx):
            continue
        t.append(time_s)
        angles.append(pos[idx])
        rates.append(vel[idx] if vel.shape[0] > max(idx) else (np.nan, np.nan))
    if not t:
        return _empty_joints()
    return JointSeries(np.asarray(t), np.asarray(angles), np.asarray(rates, float))


#: message types a figure uses; other channels (view plans, paths, ...) are skipped while reading
_PLOTTED_TYPES = (*m.POSE_TYPES, m.JOINT_STATE, m.POINT_CLOUD2, STRING)


@dataclass
class _Contents:
    """One pass over a recording: metadata, (topic, ROS type, log time [ns], CDR) of the plotted types (the last
    cloud per topic only), the first log time [ns], and whether the file ended early."""

    metadata: dict[str, dict[str, str]]
    attachments: dict[str, bytes]
    messages: list[tuple[str, str, int, bytes]]
    clouds: dict[str, bytes]
    first_ns: int | None
    truncated: bool


def _read_mcap(path: Path) -> _Contents:
    """Stream the MCAP file's records (chunks unpacked; no index needed). A file cut short (a daemon killed
    while recording leaves no summary and maybe half a chunk) keeps what was complete."""
    try:
        from mcap.records import Attachment, Channel, DataEnd, Footer, Message, Metadata, Schema
        from mcap.stream_reader import StreamReader
    except ImportError:
        raise InputError("reading MCAP needs the 'mcap' package: pip install 'pivotd[record]'") from None
    try:
        fh = path.open("rb")
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror})") from None
    out = _Contents({}, {}, [], {}, None, True)
    schemas: dict[int, str] = {}
    channels: dict[int, tuple[str, str]] = {}
    seen = 0
    with fh:
        try:
            for record in StreamReader(fh).records:
                seen += 1
                if isinstance(record, Message):
                    out.first_ns = record.log_time if out.first_ns is None else min(out.first_ns, record.log_time)
                    topic, msgtype = channels.get(record.channel_id, ("", ""))
                    if msgtype == m.POINT_CLOUD2:
                        out.clouds[topic] = record.data
                    elif msgtype in _PLOTTED_TYPES:
                        out.messages.append((topic, msgtype, record.log_time, record.data))
                elif isinstance(record, Channel):
                    channels[record.id] = (record.topic, schemas.get(record.schema_id, ""))
                elif isinstance(record, Schema):
                    schemas[record.id] = record.name
                elif isinstance(record, Metadata):
                    out.metadata[record.name] = dict(record.metadata)
                elif isinstance(record, Attachment):
                    out.attachments[record.name] = bytes(record.data)
                elif isinstance(record, DataEnd | Footer):
                    out.truncated = False
                    break
        except Exception as exc:  # the mcap reader raises many kinds on damaged or cut files
            if not seen:
                reason = " ".join(str(exc).split())[:200] or type(exc).__name__
                raise InputError(f"{path}: not a readable MCAP recording ({reason})") from None
    return out


def read_recording(path: str | Path, config: str | Path | None = None) -> Recording:
    """Read ``path`` (an MCAP file written by ``pivotd --record``) with the config it names in its metadata, or
    ``config`` when given. A file cut short (the daemon was killed) is read up to its last complete chunk.
    Raises :class:`InputError` naming the file on anything missing or unreadable."""
    path = resolve_recording(path)
    contents = _read_mcap(path)
    with tempfile.TemporaryDirectory(prefix="pivotd-recording-") as tmp:
        cfg = _config(path, contents, config, Path(tmp))
        return _recording(path, contents, cfg)


def _recording(path: Path, contents: _Contents, cfg: Config) -> Recording:
    t = cfg.topics
    pose_topic = TF_POSE_TOPIC if t.pose_from_tf else t.pose  # with TF: the poses the daemon composed and took
    poses: list[tuple[float, m.PoseSample]] = []
    measured: list[tuple[float, object]] = []
    commanded: list[tuple[float, object]] = []
    texts: list[tuple[str, float, dict]] = []  # (topic, log time [s], JSON document) of the timeline's channels
    for topic, msgtype, log_ns, data in contents.messages:
        time_s = log_ns * 1e-9
        try:
            if topic in (STATE_TOPIC, STATUS_TOPIC) and msgtype == STRING:
                doc = _json(decode_text(data, topic))
                if doc is not None:
                    texts.append((topic, time_s, doc))
                continue
            if topic == pose_topic and msgtype in m.POSE_TYPES:
                poses.append((time_s, m.decode_pose(data, msgtype, topic, None)))
            elif topic in (t.joint_states, JOINT_COMMAND_TOPIC) and msgtype == m.JOINT_STATE:
                msg = m.deserialize(data, m.JOINT_STATE, topic)
                (measured if topic == t.joint_states else commanded).append((time_s, msg))
        except m.MessageError:
            continue  # the daemon dropped it too
    truncated = contents.truncated
    cloud = contents.clouds.get(t.landmarks)
    t0 = (contents.first_ns or 0) * 1e-9
    if truncated:
        log.warning("%s: the recording ends early (no summary); using the %d complete messages", path,
                    len(poses) + len(measured) + len(commanded))
    if not poses:
        raise InputError(f"{path}: no poses on {pose_topic} (the run's pose topic) in the recording")
    if not measured:
        raise InputError(f"{path}: no joint states on {t.joint_states} in the recording")
    poses.sort(key=lambda p: p[0])
    return Recording(
        path=path, cfg=cfg,
        pose_t=np.array([p[0] for p in poses]) - t0,
        pose_pos=np.array([p[1].position for p in poses], float),
        pose_quat=np.array([p[1].quat for p in poses], float),
        measured=_shift(_joints(measured), t0),
        commanded=_shift(_joints(commanded), t0),
        landmarks=_landmarks(path, cfg, cloud),
        timeline=_timeline(texts, t0),
        statuses=sorted(((ts - t0, doc) for topic, ts, doc in texts if topic == STATUS_TOPIC), key=lambda r: r[0]),
        start=None if contents.first_ns is None else datetime.datetime.fromtimestamp(t0, datetime.timezone.utc),
    )


def _json(text: str) -> dict | None:
    """A JSON object, or None (a message the daemon did not write: skipped)."""
    try:
        doc = json.loads(text)
    except ValueError:
        return None
    return doc if isinstance(doc, dict) else None


def _timeline(texts: list[tuple[str, float, dict]], t0: float) -> list[StateEvent]:
    """The state channel's events in time order (an event lacking ``kind`` or a time is skipped)."""
    events = []
    for topic, time_s, doc in texts:
        if topic != STATE_TOPIC or not isinstance(doc.get("kind"), str):
            continue
        try:
            wall, mono = float(doc["wall_time"]), float(doc["monotonic"])
        except (KeyError, TypeError, ValueError):
            continue
        extra = {k: v for k, v in doc.items() if k not in ("kind", "value", "previous", "wall_time", "monotonic")}
        events.append(StateEvent(time_s - t0, doc["kind"], doc.get("value"), doc.get("previous"), wall, mono, extra))
    events.sort(key=lambda e: (e.t, e.monotonic))
    return events


def _shift(series: JointSeries, t0: float) -> JointSeries:
    return JointSeries(series.t - t0, series.angles, series.rates)


def _config(path: Path, contents: _Contents, override: str | Path | None, tmp: Path) -> Config:
    """The run's config: ``override``; else the config file the recording names, if it is here as recorded (same
    text, same map); else the config text and map files the recording carries, unpacked into ``tmp``."""
    if override is not None:
        return load_config(override)
    recorded = (contents.metadata.get(METADATA_NAME) or {}).get("config")
    text = contents.attachments.get(CONFIG_ATTACHMENT)
    map_meta = contents.metadata.get(MAP_METADATA_NAME)
    if recorded and Path(recorded).is_file() and (text is None or Path(recorded).read_bytes() == text):
        cfg = load_config(recorded)
        if text is None or _same_map(cfg.map.file, map_meta):
            return cfg
    if text is None:
        if not recorded:
            raise InputError(f"{path}: the recording names no config file; pass --config FILE (the run's config)")
        raise InputError(f"{path}: the run's config {recorded} is not there any more; pass --config FILE")
    return _unpacked_config(path, text, recorded, map_meta, contents.attachments, tmp)


def _same_map(map_file: Path | None, meta: dict[str, str] | None) -> bool:
    """Whether ``map_file`` is the map the run recorded (no checksum recorded: assumed)."""
    if map_file is None or not meta or not meta.get("sha256"):
        return True
    try:
        return map_checksum(map_file)[0] == meta["sha256"]
    except OSError:
        return False


def _unpacked_config(path: Path, text: bytes, recorded: str | None, map_meta: dict[str, str] | None,
                     attachments: dict[str, bytes], tmp: Path) -> Config:
    """The recorded config text as a config in ``tmp``: the map from the recording's attachments (else the map file
    it names, if that is the run's), its files elsewhere dropped when not here (Zenoh, the demo's route, an
    occupancy file: a figure needs none of them)."""
    try:
        doc = yaml.safe_load(text.decode("utf-8"))
    except (UnicodeDecodeError, yaml.YAMLError) as exc:
        raise InputError(f"{path}: the recorded config does not parse ({type(exc).__name__})") from None
    if not isinstance(doc, dict):
        raise InputError(f"{path}: the recorded config is not a mapping")
    doc.pop("zenoh", None)
    doc.pop("sim", None)
    doc.pop("record", None)
    base = Path(recorded).parent if recorded else tmp
    map_doc = doc.get("map") if isinstance(doc.get("map"), dict) else {}
    filters = map_doc.get("filters") if isinstance(map_doc.get("filters"), dict) else {}
    occupancy = filters.get("occupancy_file")
    if occupancy is not None and not (base / str(occupancy)).expanduser().exists():
        filters.pop("occupancy_file")
        log.warning("%s: the run's occupancy file %s is not here; the figures do without it", path, occupancy)
    elif occupancy is not None:
        filters["occupancy_file"] = str((base / str(occupancy)).expanduser())
    if map_meta and map_meta.get("file"):
        map_doc["file"] = str(_run_map(path, map_meta, attachments, tmp))
        doc["map"] = map_doc
    config = tmp / "config.yaml"
    config.write_text(yaml.safe_dump(doc))
    log.info("%s: using the config%s recorded with the run", path, " and map" if map_meta else "")
    return load_config(config)


def _run_map(path: Path, meta: dict[str, str], attachments: dict[str, bytes], tmp: Path) -> Path:
    """The run's map file: unpacked from the recording into ``tmp``, or the file it names when that is the same."""
    original = Path(meta["file"])
    if meta.get("attached") == "true":
        names = json.loads(meta.get("files") or "[]")
        missing = [n for n in names if n not in attachments]
        if not missing:
            for name in names:
                out = tmp / name
                out.parent.mkdir(parents=True, exist_ok=True)
                out.write_bytes(attachments[name])
            inner = names[0][len(MAP_ATTACHMENT_PREFIX):] if names else original.name
            return tmp / MAP_ATTACHMENT_PREFIX / inner.split("/")[0]
    if original.exists():
        if not _same_map(original, meta):
            log.warning("%s: the map %s differs from the run's (sha256 %s); using it all the same", path, original,
                        meta.get("sha256", "")[:12])
        return original
    raise InputError(f"{path}: the run's map {original} is not in the recording (over record.map_max_bytes) and "
                     "not here; pass --config FILE")


def _landmarks(path: Path, cfg: Config, cloud_payload: bytes | None) -> np.ndarray:
    """The map file's landmarks plus the last landmark cloud received over the bus (a map-less run's map)."""
    parts = []
    if cfg.map.file is not None:
        parts.append(load_landmarks(cfg.map.file, weight_property=cfg.map.weight_property).points)
    if cloud_payload is not None:
        parts.append(m.decode_cloud(cloud_payload, cfg.topics.landmarks, None, cfg.topics.max_cloud_points).points)
    if not parts:
        raise InputError(f"{path}: no landmarks: the config has no map file and none were received on "
                         f"{cfg.topics.landmarks}")
    return np.concatenate([np.asarray(p, float).reshape(-1, 3) for p in parts])
