"""The body pose from TF: ``/tf`` and ``/tf_static`` messages in, map-frame :class:`PoseSample` values out.

:class:`TfPose` keeps the :class:`~pivotd.bus.tf_tree.TfTree` (behind a lock), feeds it each decoded message and,
when the message changed a link between ``topics.map_frame`` and ``topics.base_frame`` (or no chain joins them
yet), composes the pose of the base frame in the map frame. Drops are counted per reason (the tree's counters,
and through ``count`` in the bus counters of the topic they came on) and each distinct problem is logged once,
with the frame names. The decoded pose gets the reception time of the message that completed it, its stamp the
oldest stamp of the chain's dynamic links (docs/ROS2.md, "Pose from TF").
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable

from pivotd.bus import messages as m
from pivotd.bus.ratelimit import RateLimitedLog
from pivotd.bus.tf_tree import TRANSFORM_DROPS, ComposedPose, Rejection, TfDrop, TfTree

log = logging.getLogger(__name__)

#: Distinct problems logged once each; past this many, further ones are rate-limited per reason instead.
MAX_LOGGED_PROBLEMS = 1000


class TfPose:
    """Composes poses of ``base_frame`` in ``map_frame``; ``timeout`` [s]: a dynamic link received longer ago than
    this makes the pose stale (no pose is produced). ``count(topic, counter)`` adds one to a bus counter."""

    def __init__(self, map_frame: str, base_frame: str, timeout: float, max_frames: int,
                 count: Callable[[str, str], None], on_pose: Callable[[m.PoseSample], None] | None) -> None:
        self.map_frame, self.base_frame = map_frame, base_frame
        self.timeout = float(timeout)
        self.tree = TfTree(max_frames=max_frames)
        self._count, self._on_pose = count, on_pose
        self._lock = threading.Lock()
        self._logged: set[tuple[str, ...]] = set()
        self._ratelog = RateLimitedLog(log)
        self._composed = 0
        self._last: ComposedPose | None = None

    def take(self, topic: str, payload: bytes, rx: float, static: bool, source: str) -> None:
        """Decode one TFMessage (raises :class:`~pivotd.bus.messages.MessageError` when it is not one), add its
        transforms and hand the composed pose, if the message made one, to ``on_pose``."""
        records = m.decode_transforms(payload, topic, rx, static, source)
        with self._lock:
            rejected = self.tree.add_all(records)
            relevant = self.tree.chain(self.map_frame, self.base_frame) is None or any(
                self._on_branch(r.child) for r in records)
            result = self.tree.lookup(self.map_frame, self.base_frame, rx, self.timeout) if relevant else None
            if isinstance(result, ComposedPose):
                self._composed += 1
                self._last = result
        for rejection in rejected:
            if rejection.reason in TRANSFORM_DROPS:
                self._count(topic, f"dropped_{rejection.reason.value}")
            self._report(rejection)
        if isinstance(result, Rejection):
            self._report(result)
        elif result is not None and self._on_pose is not None:
            self._on_pose(m.PoseSample(stamp=result.stamp, frame_id=self.map_frame, position=result.position,
                                       quat=result.quat, rx_time=rx))

    def _on_branch(self, child: str) -> bool:
        """Whether the link of ``child`` lies on the way up from the base or the map frame (caller holds the lock)."""
        name = child.strip().lstrip("/")
        return name in self.tree.ancestors(self.base_frame) or name in self.tree.ancestors(self.map_frame)

    def _report(self, rejection: Rejection) -> None:
        with self._lock:
            first = rejection.key not in self._logged and len(self._logged) < MAX_LOGGED_PROBLEMS
            if first:
                self._logged.add(rejection.key)
        if first:
            log.warning("TF: %s (dropped; logged once)", rejection.message)
        elif rejection.key not in self._logged:
            self._ratelog.warning(f"tf:{rejection.reason.value}", f"TF: {rejection.message} (dropped)")

    def status(self) -> dict[str, object]:
        """The status block ``tf``: frames, the chain last composed, poses composed, its age, and the counters."""
        with self._lock:
            counts = dict(self.tree.counts)
            last = self._last
            frames = self.tree.frames()
            composed = self._composed
        dropped = {r.value: counts.pop(r.value) for r in TfDrop}
        return {"map_frame": self.map_frame, "base_frame": self.base_frame, "frames": frames,
                "chain": None if last is None else list(last.frames), "composed": composed,
                "transforms": counts, "dropped": dropped}
