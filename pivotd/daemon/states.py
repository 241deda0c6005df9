"""The daemon's state, as reported in the status document (``state``) and decided by each control tick."""

from __future__ import annotations

from pivotd.compat import StrEnum


class DaemonState(StrEnum):
    """What the daemon is doing. A control tick decides one of WAITING … PARKING; the daemon adds the rest."""

    STARTING = "starting"  # loading the config and the map, opening the bus and the gimbal
    WAITING = "waiting"  # no pose received yet: holding still
    TRACKING = "tracking"  # following the plan
    HOLDING = "holding"  # pose or plan stale: jerk-limited stop and hold
    LINK_DOWN = "link-down"  # gimbal link not up: nothing is sent
    FAULT = "fault"  # gimbal faulted: heartbeats only, no motion
    TRACKING_ERROR = "tracking-error"  # an axis does not follow its setpoints: held, then probed (status block)
    PARKING = "parking"  # moving to the park pose before shutdown
    STOPPED = "stopped"  # shut down
    FAILED = "failed"  # a thread that must not die has died (status ``threads_dead``): nothing is controlled
