"""ROS 2 QoS as pivotd uses it: the rmw enum values, the profile of one topic, and the per-topic settings.

Pure data (no Zenoh import), so the config loader can build it. :mod:`pivotd.bus.durable` turns a
``TRANSIENT_LOCAL`` profile into Zenoh's advanced publisher/subscriber as rmw_zenoh does.
"""

from __future__ import annotations

from dataclasses import dataclass, field

from pivotd.errors import ConfigError

# rmw QoS enum values (rmw/types.h).
RELIABILITY_RELIABLE, RELIABILITY_BEST_EFFORT = 1, 2
DURABILITY_TRANSIENT_LOCAL, DURABILITY_VOLATILE = 1, 2
HISTORY_KEEP_LAST, HISTORY_KEEP_ALL = 1, 2

RELIABILITY_NAMES = {"reliable": RELIABILITY_RELIABLE, "best_effort": RELIABILITY_BEST_EFFORT}
DURABILITY_NAMES = {"volatile": DURABILITY_VOLATILE, "transient_local": DURABILITY_TRANSIENT_LOCAL}
#: Largest history depth accepted in the config (a transient-local publisher keeps this many messages).
MAX_DEPTH = 1000


@dataclass(frozen=True)
class QoS:
    """ROS QoS as advertised in liveliness tokens (only what pivotd uses); fields hold rmw enum values."""

    reliability: int = RELIABILITY_RELIABLE
    durability: int = DURABILITY_VOLATILE
    history: int = HISTORY_KEEP_LAST
    depth: int = 10

    @property
    def transient_local(self) -> bool:
        """True for ``TRANSIENT_LOCAL`` durability (late joiners get the last ``depth`` messages)."""
        return self.durability == DURABILITY_TRANSIENT_LOCAL

    @property
    def reliable(self) -> bool:
        return self.reliability == RELIABILITY_RELIABLE

    @classmethod
    def named(cls, reliability: str = "reliable", durability: str = "volatile", depth: int = 10) -> QoS:
        """Profile from config names (``reliable``/``best_effort``, ``volatile``/``transient_local``), keep last."""
        if reliability not in RELIABILITY_NAMES:
            raise ConfigError(f"reliability {reliability!r} must be one of {', '.join(RELIABILITY_NAMES)}")
        if durability not in DURABILITY_NAMES:
            raise ConfigError(f"durability {durability!r} must be one of {', '.join(DURABILITY_NAMES)}")
        if isinstance(depth, bool) or not isinstance(depth, int) or not 1 <= depth <= MAX_DEPTH:
            raise ConfigError(f"depth must be an integer in 1..{MAX_DEPTH}, got {depth!r}")
        return cls(RELIABILITY_NAMES[reliability], DURABILITY_NAMES[durability], HISTORY_KEEP_LAST, depth)

    def names(self) -> tuple[str, str, int]:
        """(reliability name, durability name, depth): the inverse of :meth:`named`."""
        rel = next(k for k, v in RELIABILITY_NAMES.items() if v == self.reliability)
        dur = next(k for k, v in DURABILITY_NAMES.items() if v == self.durability)
        return rel, dur, self.depth


def _transient(depth: int) -> QoS:
    return QoS(durability=DURABILITY_TRANSIENT_LOCAL, depth=depth)


@dataclass(frozen=True)
class TopicQoS:
    """QoS of each of pivotd's topics (the config's ``ros.qos`` section).

    Inputs that a node typically publishes once or rarely (path, landmark map, targets) are
    subscribed ``TRANSIENT_LOCAL``: pivotd then gets the last message of a transient-local publisher
    that started before it, and still every message of a volatile one. The view plan is published
    ``TRANSIENT_LOCAL`` so a late transient-local subscriber gets the current plan. ``pose_tf`` and
    ``pose_tf_static`` are the subscriptions of ``/tf`` and ``/tf_static`` when the pose comes from TF (tf2's own
    listener QoS: volatile and transient local, depth 100); ``tf`` is the camera TF publisher.
    """

    pose: QoS = field(default_factory=lambda: QoS(depth=10))
    path: QoS = field(default_factory=lambda: _transient(1))
    landmarks: QoS = field(default_factory=lambda: _transient(1))
    targets: QoS = field(default_factory=lambda: _transient(1))
    joint_states: QoS = field(default_factory=lambda: QoS(depth=10))
    view_plan: QoS = field(default_factory=lambda: _transient(1))
    markers: QoS = field(default_factory=lambda: QoS(depth=1))
    tf: QoS = field(default_factory=lambda: QoS(depth=100))
    pose_tf: QoS = field(default_factory=lambda: QoS(depth=100))
    pose_tf_static: QoS = field(default_factory=lambda: _transient(100))
