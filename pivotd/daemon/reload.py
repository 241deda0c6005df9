"""SIGHUP: which settings of a reloaded config take effect now and which wait for a restart.

Live (applied at once, to the planner process and the control loop from the same :class:`Config`):
``map`` (the map file is read again), ``pivot``, ``planner``, ``gimbal.mount``, the park pose and
timeout, ``sim``. Restart-only (kept at their running values, logged as "needs restart"): the node
``name``, ``zenoh``, ``topics`` (sessions and subscriptions), ``gimbal.backend``, ``port``, ``baud``,
``mavlink`` / ``dynamixel`` (the connection), ``limits`` and ``watchdog_ms`` (sent to the device at the
handshake), ``motion`` (the device's rate limits), ``control`` (the control thread's rate and clock) and
``logging`` (the command line may override it), ``ros`` (publishers and QoS) and ``record`` (the recording
opened at the start).

What a reload costs depends on what changed. Nothing that affects the plan (no setting, or only the park pose,
``pose_gate``, ``sim``, restart-only ones): the planner process is not asked at all and the running plan stays.
``pivot`` / ``planner`` settings: the planner process builds a new planner on the map it has; ``map`` settings or
a map file that changed on disk (:mod:`pivotd.maps.fingerprint`): it reads the map again. In both cases the
control loop keeps tracking the running plan until the first plan made with the new settings replaces it: the
control loop converts the plan's world directions to joint targets with its own joint limits, mount and motion
limits at every tick, so an older plan is a valid (if no longer optimal) target, and it still holds once the plan
is older than its ``plan_timeout``. Only a new ``gimbal.mount`` drops the running plan (the control loop holds
until the first plan made with the new mount): the plan's pan branch was chosen in the old mount's frame.
"""

from __future__ import annotations

import dataclasses
import logging
from dataclasses import dataclass, fields, replace

from pivotd.config import Config
from pivotd.daemon.control import ControlLoop
from pivotd.daemon.wiring import build_control_settings, map_files_identity
from pivotd.daemon.worker import MapInfo, PlannerWorker
from pivotd.maps.fingerprint import MapIdentity

log = logging.getLogger(__name__)

#: Config sections whose changes only take effect at the next start.
RESTART_SECTIONS = ("name", "zenoh", "topics", "motion", "control", "logging", "ros", "record")
#: ``gimbal`` fields whose changes only take effect at the next start (the rest of ``gimbal`` is live).
RESTART_GIMBAL_FIELDS = ("backend", "port", "baud", "limits", "watchdog_ms", "mavlink", "dynamixel")
_NOT_SETTINGS = ("source",)
#: Live sections the plan depends on (a change rebuilds the planner in the planner process).
PLAN_SECTIONS = ("map", "pivot", "planner")
#: A change of this setting drops the running plan (see the module docstring).
PLAN_DROPPING = ("gimbal.mount",)


@dataclass(frozen=True)
class ReloadPlan:
    """config: what runs after the reload (the loaded file with restart-only settings at their running values);
    applied / needs_restart: dotted keys that changed, e.g. ``gimbal.mount``, ``zenoh.listen``."""

    config: Config
    applied: tuple[str, ...]
    needs_restart: tuple[str, ...]
    map_file_changed: bool = False  # the map settings are the same but one of the map's files changed on disk

    @property
    def reload_map(self) -> bool:
        """Whether the planner process reads the map again (map settings or map files changed)."""
        return self.map_file_changed or any(k.partition(".")[0] == "map" for k in self.applied)

    @property
    def reload_planner(self) -> bool:
        """Whether the planner process is asked at all (a new planner, and the map if :attr:`reload_map`)."""
        return self.reload_map or any(k.partition(".")[0] in PLAN_SECTIONS or k in PLAN_DROPPING
                                      for k in self.applied)

    @property
    def keeps_plan(self) -> bool:
        """Whether the control loop may keep tracking the running plan until a new one is made."""
        return not any(k in PLAN_DROPPING for k in self.applied)


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


def plan_reload(running: Config, loaded: Config, running_map: MapIdentity | None = None) -> ReloadPlan:
    """Split the differences between the running and the loaded config into live and restart-only ones.

    ``running_map``: the identity of the map files the planner process loaded (``map_files_identity`` when it
    read them); with it, an unchanged map file under unchanged map settings is not read again. None: compare settings
    only."""
    changed = changed_keys(running, loaded)
    kept = {
        "name": running.name,
        "zenoh": running.zenoh,
        "topics": running.topics,
        "motion": running.motion,
        "control": running.control,
        "logging": running.logging,
        "ros": running.ros,
        "record": running.record,
        "gimbal": replace(loaded.gimbal, **{k: getattr(running.gimbal, k) for k in RESTART_GIMBAL_FIELDS}),
    }
    return ReloadPlan(
        config=replace(loaded, **kept),
        applied=tuple(k for k in changed if not _is_restart_only(k)),
        needs_restart=tuple(k for k in changed if _is_restart_only(k)),
        map_file_changed=running_map is not None and map_files_identity(loaded) != running_map,
    )


def apply_reload(plan: ReloadPlan, worker: PlannerWorker, control: ControlLoop | None) -> MapInfo:
    """Give the planner process and the control loop the settings of ``plan.config``: the worker first, if the plan
    depends on what changed (if it refuses, RequestError, neither side changes), then the control loop (mount,
    plan timeout).

    Call from the thread that makes the worker's other requests, and drop the running plan first unless
    ``plan.keeps_plan``: the control loop then holds until the first plan made with the new settings.
    """
    info = worker.reload(plan.config, reload_map=plan.reload_map) if plan.reload_planner else worker.map_info
    if control is not None:
        control.reconfigure(build_control_settings(plan.config), plan.config.gimbal.mount)
    return info
