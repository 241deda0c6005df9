"""The TF tree as pivotd uses it: transforms per frame pair, bounded, and the pose of one frame in another.

Pure (no I/O, no threads, no clock): feed :class:`TransformRecord` values (what a
``geometry_msgs/TransformStamped`` says, plus when and from whom it was received) to :meth:`TfTree.add`, then ask
:meth:`TfTree.lookup` for the pose of ``base_frame`` in ``map_frame`` through whatever frames lie between them
(``map -> odom -> base_link``, or longer chains, up to their common ancestor). The bus
(:mod:`pivotd.bus.pivot_bus`) does the receiving and the locking.

Rules (docs/ROS2.md, "Pose from TF"):

* Each child frame has one parent at a time. A transform naming another parent for a known child is a
  **reparenting** when it comes from the same publisher, or when the old link has gone quiet (a dynamic link not
  received for ``parent_timeout`` s): the old link is replaced (counted ``reparented``). From a different
  publisher while the old link is still live (or static) it is a child with **two parents**: dropped
  (``two_parents``). Within one message, a child named twice with different parents is dropped likewise.
* A transform that would close a **loop** (its parent is the child itself or one of the child's descendants) is
  dropped (``loop``); so are non-finite values (``nonfinite``), a rotation whose squared norm is off 1 by more
  than 0.01 (``non_unit_quaternion``, tf2's own tolerance), a translation beyond ±10⁷ m (``out_of_range``) and an
  empty frame name (``empty_frame``). Leading ``/`` of frame names are ignored, as tf2 does.
* Memory: at most ``max_frames`` links (a new one beyond that first evicts the dynamic link received longest ago
  if it has been quiet for ``forget_after`` s, else is dropped: ``too_many_frames``) and at most ``depth``
  transforms per link (the newest stamps are kept); a static link keeps its latest transform only.
* Composition takes the **newest transform of each link** (no interpolation to a common time: that would delay
  the pose by the slowest link's period). The pose's ``stamp`` is the **oldest** stamp among the dynamic links
  used (static links never age); it is **stale** when a dynamic link used was last received more than
  ``timeout`` s before ``now``.
"""

from __future__ import annotations

import bisect
import enum
from collections import deque
from collections.abc import Iterable
from dataclasses import dataclass, field

import numpy as np

from pivotd.geometry import MAX_COORDINATE, matrix_to_quat, quat_to_matrix

#: Largest accepted | |q|² − 1 | of a transform's rotation (tf2 rejects beyond this, "denormalized quaternion").
QUATERNION_TOLERANCE = 0.01
#: A stamp this much [s] older than a link's newest one means the publisher's clock jumped back (a restarted
#: simulation or bag): the link's buffer is cleared and starts again from it.
JUMP_BACK_S = 1.0


class TfDrop(enum.Enum):
    """Why a transform (or a composition) was dropped; the values are the counter names."""

    NONFINITE = "nonfinite"
    NON_UNIT_QUATERNION = "non_unit_quaternion"
    OUT_OF_RANGE = "out_of_range"
    EMPTY_FRAME = "empty_frame"
    LOOP = "loop"
    TWO_PARENTS = "two_parents"
    TOO_MANY_FRAMES = "too_many_frames"
    MISSING_LINK = "missing_link"  # lookup: no chain of links joins the two frames
    STALE = "stale"  # lookup: a dynamic link of the chain was not received for longer than the timeout


#: The reasons :meth:`TfTree.add` drops a transform for (the others are the lookup's).
TRANSFORM_DROPS = tuple(r for r in TfDrop if r not in (TfDrop.MISSING_LINK, TfDrop.STALE))


@dataclass(frozen=True)
class TransformRecord:
    """One received transform: the pose of ``child`` in ``parent``. stamp: header time [s]; translation (3,) [m];
    rotation (4,) (x, y, z, w); rx_time: reception time [s] (any monotonic clock, the one ``lookup`` gets as
    ``now``); static: from ``/tf_static``; source: the publisher's id (e.g. its GID in hex, "" when unknown)."""

    parent: str
    child: str
    stamp: float
    translation: np.ndarray
    rotation: np.ndarray
    rx_time: float
    static: bool = False
    source: str = ""


@dataclass(frozen=True)
class Rejection:
    """A dropped transform or lookup: the reason and a one-line message naming the frames; ``key`` identifies the
    problem (reason and frames) so that a caller can log each one once."""

    reason: TfDrop
    message: str
    key: tuple[str, ...]


@dataclass(frozen=True)
class ComposedPose:
    """Pose of the source frame in the target frame: position (3,) [m], quat (4,) unit (x, y, z, w).
    frames: the chain target → … → source; stamp [s]: the oldest stamp among the dynamic links (the newest static
    stamp when every link is static); oldest_rx [s]: reception time of the least recently received dynamic link
    (``inf`` when all are static)."""

    frames: tuple[str, ...]
    position: np.ndarray
    quat: np.ndarray
    stamp: float
    oldest_rx: float


@dataclass
class _Link:
    parent: str
    static: bool
    source: str
    last_rx: float
    buffer: deque = field(default_factory=deque)  # TransformRecord, ascending stamps
    stamps: list = field(default_factory=list)  # their stamps, for bisect


def frame_name(name: str) -> str:
    """A frame name as tf2 compares them: surrounding blanks and leading ``/`` removed."""
    return name.strip().lstrip("/")


class TfTree:
    """Links child → parent with their recent transforms; see the module docstring for the rules.

    ``max_frames``: links kept at most; ``depth``: transforms kept per dynamic link; ``parent_timeout`` [s]: a
    dynamic link not received for this long may be taken over by another parent; ``forget_after`` [s]: a dynamic
    link this quiet may be evicted to make room for a new frame. Not thread-safe (the caller locks).
    """

    def __init__(self, max_frames: int = 256, depth: int = 16, parent_timeout: float = 1.0,
                 forget_after: float = 10.0) -> None:
        if max_frames < 1 or depth < 1:
            raise ValueError(f"max_frames and depth must be >= 1, got {max_frames}, {depth}")
        self.max_frames, self.depth = int(max_frames), int(depth)
        self.parent_timeout, self.forget_after = float(parent_timeout), float(forget_after)
        self._links: dict[str, _Link] = {}
        self.counts: dict[str, int] = {r.value: 0 for r in TfDrop} | {"accepted": 0, "reparented": 0,
                                                                      "evicted": 0, "jump_back": 0}

    # ------------------------------------------------------------------ feeding
    def add_all(self, records: Iterable[TransformRecord]) -> list[Rejection]:
        """Add the transforms of one message; a child named with two different parents in it drops both."""
        records = list(records)
        parents: dict[str, set[str]] = {}
        for r in records:
            parents.setdefault(frame_name(r.child), set()).add(frame_name(r.parent))
        out = []
        for r in records:
            child = frame_name(r.child)
            if len(parents[child]) > 1:
                names = " and ".join(repr(p) for p in sorted(parents[child]))
                out.append(self._reject(TfDrop.TWO_PARENTS, f"frame {child!r} has two parents in one message: "
                                                            f"{names}", (child, *sorted(parents[child]))))
                continue
            rejection = self.add(r)
            if rejection is not None:
                out.append(rejection)
        return out

    def add(self, rec: TransformRecord) -> Rejection | None:
        """Add one transform; None when kept, else why it was dropped (counted)."""
        parent, child = frame_name(rec.parent), frame_name(rec.child)
        pair = (parent, child)
        what = f"transform {parent!r} -> {child!r}"
        if not parent or not child:
            return self._reject(TfDrop.EMPTY_FRAME, f"{what} has an empty frame name", pair)
        t = np.asarray(rec.translation, dtype=float).reshape(3)
        q = np.asarray(rec.rotation, dtype=float).reshape(4)
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(q)) and np.isfinite(rec.stamp)):
            return self._reject(TfDrop.NONFINITE, f"{what} has a NaN or infinite value", pair)
        if np.max(np.abs(t)) > MAX_COORDINATE:
            return self._reject(TfDrop.OUT_OF_RANGE, f"{what}: translation beyond ±{MAX_COORDINATE:g} m", pair)
        norm2 = float(q @ q)
        if abs(norm2 - 1.0) > QUATERNION_TOLERANCE:
            return self._reject(TfDrop.NON_UNIT_QUATERNION, f"{what}: rotation quaternion of norm "
                                                            f"{np.sqrt(norm2):.4g}, not a unit quaternion", pair)
        if parent == child or self._is_ancestor(child, parent):
            return self._reject(TfDrop.LOOP, f"{what} would close a loop ({child!r} is {parent!r} or one of its "
                                             f"ancestors)", pair)
        link = self._links.get(child)
        if link is not None and link.parent != parent:
            live = link.static or rec.rx_time - link.last_rx <= self.parent_timeout
            if live and link.source != rec.source:
                return self._reject(TfDrop.TWO_PARENTS, f"frame {child!r} has two parents: {link.parent!r} and "
                                                        f"{parent!r} from another publisher", (child, link.parent,
                                                                                               parent))
            self.counts["reparented"] += 1
            link = None  # the new parent replaces the old link
        if link is None:
            if child not in self._links and len(self._links) >= self.max_frames and not self._evict(rec.rx_time):
                return self._reject(TfDrop.TOO_MANY_FRAMES, f"{what}: the tree already holds {self.max_frames} "
                                                            f"frames", pair)
            link = _Link(parent, rec.static, rec.source, rec.rx_time)
            self._links[child] = link
        rec = TransformRecord(parent, child, float(rec.stamp), t, q / np.sqrt(norm2), rec.rx_time, rec.static,
                              rec.source)
        if rec.static or link.static:  # static, or a frame moving between /tf and /tf_static: its latest only
            link.buffer.clear()
            link.stamps.clear()
        elif link.stamps and rec.stamp < link.stamps[-1] - JUMP_BACK_S:
            self.counts["jump_back"] += 1
            link.buffer.clear()
            link.stamps.clear()
        link.static, link.source = rec.static, rec.source
        link.last_rx = max(link.last_rx, rec.rx_time)
        self._insert(link, rec)
        self.counts["accepted"] += 1
        return None

    def _insert(self, link: _Link, rec: TransformRecord) -> None:
        i = bisect.bisect_left(link.stamps, rec.stamp)
        if i < len(link.stamps) and link.stamps[i] == rec.stamp:  # the same time again: the newer message wins
            link.buffer[i] = rec
            return
        if len(link.stamps) >= self.depth:
            if i == 0:
                return  # older than everything kept in a full buffer
            link.buffer.popleft()
            link.stamps.pop(0)
            i -= 1
        link.buffer.insert(i, rec)
        link.stamps.insert(i, rec.stamp)

    def _evict(self, now: float) -> bool:
        quiet = [(link.last_rx, child) for child, link in self._links.items()
                 if not link.static and now - link.last_rx >= self.forget_after]
        if not quiet:
            return False
        del self._links[min(quiet)[1]]
        self.counts["evicted"] += 1
        return True

    def _is_ancestor(self, frame: str, of: str) -> bool:
        """Whether ``frame`` is ``of`` itself or one of its ancestors."""
        node, steps = of, 0
        while steps <= len(self._links):
            if node == frame:
                return True
            link = self._links.get(node)
            if link is None:
                return False
            node, steps = link.parent, steps + 1
        return False  # not reached: the tree has no loops

    def _reject(self, reason: TfDrop, message: str, frames: tuple[str, ...]) -> Rejection:
        self.counts[reason.value] += 1
        return Rejection(reason, message, (reason.value, *frames))

    # ------------------------------------------------------------------ querying
    def ancestors(self, frame: str) -> list[str]:
        """``frame`` and its parents up to the root of its tree."""
        chain = [frame_name(frame)]
        while (link := self._links.get(chain[-1])) is not None and len(chain) <= len(self._links):
            chain.append(link.parent)
        return chain

    def chain(self, target: str, source: str) -> tuple[str, ...] | None:
        """Frames from ``target`` to ``source`` through their common ancestor, or None when no link joins them."""
        joined = self._join(frame_name(target), frame_name(source))
        return None if joined is None else joined[1]

    def _join(self, target: str, source: str) -> tuple[str, tuple[str, ...]] | None:
        """(common ancestor, chain target → … → source) or None."""
        up_s, up_t = self.ancestors(source), self.ancestors(target)
        on_t = {f: i for i, f in enumerate(up_t)}
        for i, f in enumerate(up_s):
            if f in on_t:
                return f, tuple(up_t[:on_t[f]]) + tuple(reversed(up_s[:i + 1]))
        return None

    def lookup(self, target: str, source: str, now: float, timeout: float) -> ComposedPose | Rejection:
        """Pose of ``source`` in ``target`` from the newest transform of each link between them, or why not
        (``missing_link``; ``stale``: a dynamic link last received more than ``timeout`` s before ``now``); counted."""
        target, source = frame_name(target), frame_name(source)
        joined = self._join(target, source)
        if joined is None:
            up_s, up_t = self.ancestors(source), self.ancestors(target)
            return self._reject(TfDrop.MISSING_LINK, f"no transform chain {target} -> {source}: {source!r} reaches up "
                                                     f"to {up_s[-1]!r}, {target!r} to {up_t[-1]!r}",
                                (target, source, up_s[-1], up_t[-1]))
        common, chain = joined
        R_t, p_t, stamps, statics, rxs = self._up(target, common)
        R_s, p_s, s_stamps, s_statics, s_rxs = self._up(source, common)
        stamps += s_stamps
        statics += s_statics
        rxs += s_rxs
        for child, age in rxs:
            if now - age > timeout:
                parent = self._links[child].parent
                return self._reject(TfDrop.STALE, f"transform {parent} -> {child} is stale: last received "
                                                  f"{now - age:.2f} s ago", (parent, child))
        R = R_t.T @ R_s  # the source's orientation in the target frame
        p = R_t.T @ (p_s - p_t)
        stamp = min(stamps) if stamps else (max(statics) if statics else 0.0)
        oldest_rx = min((a for _, a in rxs), default=float("inf"))
        return ComposedPose(chain, p, matrix_to_quat(R), float(stamp), float(oldest_rx))

    def _up(self, frame: str, ancestor: str) -> tuple[np.ndarray, np.ndarray, list, list, list]:
        """(R (3, 3), p (3,)) of ``frame`` in ``ancestor`` and the dynamic stamps, static stamps and (child, last
        reception) of the dynamic links passed."""
        R, p = np.eye(3), np.zeros(3)
        stamps, statics, rxs = [], [], []
        node = frame
        while node != ancestor:
            link = self._links[node]
            rec = link.buffer[-1]
            Rl = quat_to_matrix(rec.rotation)
            R, p = Rl @ R, Rl @ p + rec.translation  # frame in the link's parent
            if link.static:
                statics.append(rec.stamp)
            else:
                stamps.append(rec.stamp)
                rxs.append((node, link.last_rx))
            node = link.parent
        return R, p, stamps, statics, rxs

    # ------------------------------------------------------------------ status
    def frames(self) -> int:
        """Number of links (child frames) held."""
        return len(self._links)

    def parent_of(self, frame: str) -> str | None:
        link = self._links.get(frame_name(frame))
        return None if link is None else link.parent

    def buffered(self, frame: str) -> int:
        """Transforms held for the link of ``frame`` (0 when it has none)."""
        link = self._links.get(frame_name(frame))
        return 0 if link is None else len(link.buffer)
