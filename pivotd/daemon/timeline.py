"""The daemon's state timeline in the recording: one message per change, and the status document at 1 Hz.

On :data:`~pivotd.daemon.recorder.STATE_TOPIC` (``std_msgs/msg/String``, JSON text) one message per change of the
daemon's state (``kind: state``, the :class:`~pivotd.daemon.states.DaemonState` a control tick decided, or the
daemon at start, park and stop), of the gimbal link (``kind: link``), of the gimbal's fault bits (``kind:
faults``, set or cleared, with their names) and of the threads that died (``kind: threads_dead``). Each carries
``value``, ``previous`` (None for the first), ``wall_time`` [s since the epoch] and ``monotonic`` [s, the daemon's
clock]. On :data:`~pivotd.daemon.recorder.STATUS_TOPIC` the status document (``pivotd status --json``) at most
every :data:`STATUS_PERIOD_S`. Edges only, so a steady run adds about one status message a second; the recorder's
queue bounds the memory.
"""

from __future__ import annotations

import json
import threading
import time
from typing import Any, Protocol

from pivotd.bus import messages as m
from pivotd.bus.ros import typestore
from pivotd.daemon.recorder import STATE_TOPIC, STATUS_TOPIC
from pivotd.daemon.states import DaemonState

#: the ROS type of both channels (the JSON text in ``data``)
STRING = "std_msgs/msg/String"
#: the status document is recorded at most this often [s]
STATUS_PERIOD_S = 1.0
#: states a control tick does not decide while the park target is set: once parking, one is a tick begun before
_NOT_WHILE_PARKING = frozenset({DaemonState.WAITING, DaemonState.HOLDING, DaemonState.TRACKING})


class _Writer(Protocol):
    def write(self, topic: str, ros_type: str, cdr: bytes, stamp_ns: int | None = None,
              log_time_ns: int | None = None) -> None: ...


def encode_text(text: str) -> bytes:
    """``std_msgs/msg/String`` CDR of ``text``."""
    return m.serialize(typestore().types[STRING](data=text), STRING)


def decode_text(payload: bytes, topic: str) -> str:
    """The text of a ``std_msgs/msg/String`` CDR message (:class:`~pivotd.bus.messages.MessageError` if malformed)."""
    return str(m.deserialize(payload, STRING, topic).data)  # type: ignore[attr-defined]


class StateTimeline:
    """Edge-triggered writer of the timeline to ``recorder`` (:meth:`state` from the control and main threads,
    :meth:`status` from the main thread; a lock orders the edges)."""

    def __init__(self, recorder: _Writer, status_period_s: float = STATUS_PERIOD_S) -> None:
        self._recorder = recorder
        self._period = float(status_period_s)
        self._lock = threading.Lock()
        self._last: dict[str, Any] = {}
        self._status_at = -float("inf")
        self._parking = False

    def state(self, state: str) -> None:
        """The daemon's state is ``state`` now (recorded when it changed)."""
        if self._last.get("state") != state:  # cheap check per control tick; the edge itself under the lock
            if self._parking and state in _NOT_WHILE_PARKING:
                return
            self._edge("state", str(state))

    def parking(self) -> None:
        """The daemon parks (the park target is set): PARKING now, and no tick decided before it afterwards."""
        self._parking = True
        self._edge("state", str(DaemonState.PARKING))

    def status(self, doc: dict[str, Any]) -> None:
        """The status document just published: link, fault and dead-thread edges; the document itself at most
        every ``status_period_s``."""
        self._edge("link", str(doc.get("link")))
        gimbal = doc.get("gimbal") or {}
        self._edge("faults", int(gimbal.get("faults") or 0), names=list(gimbal.get("fault_names") or ()),
                   mode=gimbal.get("mode"))
        self._edge("threads_dead", list(doc.get("threads_dead") or ()))
        now = time.monotonic()
        if now - self._status_at >= self._period:
            self._status_at = now
            self._write(STATUS_TOPIC, json.dumps(doc, default=str))

    def _edge(self, kind: str, value: Any, **extra: Any) -> None:
        with self._lock:
            previous = self._last.get(kind)
            if kind in self._last and previous == value:
                return
            self._last[kind] = value
            wall, mono = time.time(), time.monotonic()
            text = json.dumps({"kind": kind, "value": value, "previous": previous, "wall_time": wall,
                               "monotonic": mono, **extra}, default=str)
            self._write(STATE_TOPIC, text, int(wall * 1e9))

    def _write(self, topic: str, text: str, wall_ns: int | None = None) -> None:
        self._recorder.write(topic, STRING, encode_text(text), wall_ns, wall_ns)
