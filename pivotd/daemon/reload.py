"""SIGHUP: which settings of a reloaded config take effect now and which wait for a restart.

Live (applied at once, to the planner process and the control loop from the same :class:`Config`):
``map`` (the map file is read again), ``pivot``, ``planner``, ``gimbal.mount``, the park pose and
timeout, ``sim``. Restart-only (kept at their running values, logged as "needs restart"): the node
``name``, ``zenoh``, ``topics`` (sessions and subscriptions), ``gimbal.backend``, ``port``, ``baud``,
``mavlink`` / ``dynamixel`` (the connection), ``limits`` and ``watchdog_ms`` (sent to the device at the
handshake), ``motion`` (the device's rate limits), ``control`` (the control thread's rate and clock) and
``logging`` (the command line may override it) and ``ros`` (publishers and QoS).
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, fields, replace

from pivotd.config import Config
from pivotd.daemon.control import ControlLoop
from pivotd.daemon.wiring import build_control_settings
from pivotd.daemon.worker import MapInfo, PlannerWorker

log = logging.getLogger(__name__)

#: Config sections whose changes only take effect at the next start.
RESTART_SECTIONS = ("name", "zenoh", "topics", "motion", "control", "logging", "ros")
#: ``gimbal`` fields whose changes only take effect at the next start (the rest of ``gimbal`` is live).
RESTART_GIMBAL_FIELDS = ("backend", "port", "baud", "limits", "watchdog_ms", "mavlink", "dynamixel")
_NOT_SETTINGS = ("source",)


@dataclass(frozen=True)
class ReloadPlan:
    """config: what runs after the reload (the loaded file with restart-only settings at their running values);
    applied / needs_restart: dotted keys that changed, e.g. ``gimbal.mount``, ``zenoh.listen``."""

    config: Config
    applied: tuple[str, ...]
    needs_restart: tuple[str, ...]


def changed_keys(old: object, new: object, prefix: str = "") -> list[str]:
    """Dotted names of the fields that differ between two config dataclasses (one level into sections)."""
    out = []
    for f in fields(old):
        if f.name in _NOT_SETTINGS:
            continue
        a, b = getattr(old, f.name), getattr(new, f.name)
        if a == b:
            continue
        key = f"{prefix}{f.name}"
        if not prefix and dataclasses.is_dataclass(a) and dataclasses.is_dataclass(b):
            out.extend(changed_keys(a, b, f"{key}."))
        else:
            out.append(key)
    return out


def _is_restart_only(key: str) -> bool:
    section, _, field_name = key.partition(".")
    if section in RESTART_SECTIONS:
        return True
    return section == "gimbal" and field_name in RESTART_GIMBAL_FIELDS


def plan_reload(running: Config, loaded: Config) -> ReloadPlan:
    """Split the differences between the running and the loaded config into live and restart-only ones."""
    changed = changed_keys(running, loaded)
    kept = {
        "name": running.name,
        "zenoh": running.zenoh,
        "topics": running.topics,
        "motion": running.motion,
        "control": running.control,
        "logging": running.logging,
        "ros": running.ros,
        "gimbal": replace(loaded.gimbal, **{k: getattr(running.gimbal, k) for k in RESTART_GIMBAL_FIELDS}),
    }
    return ReloadPlan(
        config=replace(loaded, **kept),
        applied=tuple(k for k in changed if not _is_restart_only(k)),
        needs_restart=tuple(k for k in changed if _is_restart_only(k)),
    )


def apply_reload(plan: ReloadPlan, worker: PlannerWorker, control: ControlLoop | None) -> MapInfo:
    """Give the planner process and the control loop the settings of ``plan.config``: the worker first (if it
    refuses, RequestError, neither side changes), then the control loop (mount, plan timeout).

    Call from the thread that makes the worker's other requests, and drop the running plan first: the
    control loop then holds until the first plan made with the new settings.
    """
    info = worker.reload(plan.config)
    if control is not None:
        control.reconfigure(build_control_settings(plan.config), plan.config.gimbal.mount)
    return info
