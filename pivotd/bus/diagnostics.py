"""The daemon's health as ROS diagnostics: the status document -> ``diagnostic_msgs/msg/DiagnosticStatus`` entries.

Pure (no I/O): :func:`diagnostic_entries` reads the JSON status document the daemon publishes
(``pivot/<name>/status``) and returns one entry per component, named ``<name>: <component>`` as
``diagnostic_updater`` names them (so ``diagnostic_aggregator`` and ``rqt_robot_monitor`` group them under the
node). :func:`pivotd.bus.messages.encode_diagnostics` makes the ``DiagnosticArray``. Levels and keys: docs/ROS2.md §3.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass

#: Components, in the order of the array: the daemon's state, the gimbal link, the pose, the gimbal's faults, the
#: planner.
COMPONENTS = ("state", "gimbal link", "pose", "gimbal faults", "planner")
#: States in which the daemon controls nothing, and those in which it holds for want of input.
_ERROR_STATES = {"fault", "failed", "link-down", "tracking-error"}
_WARN_STATES = {"starting", "waiting", "holding", "parking", "stopped"}


class DiagnosticLevel(enum.IntEnum):
    """``diagnostic_msgs/msg/DiagnosticStatus`` levels (the message's byte constants)."""

    OK = 0
    WARN = 1
    ERROR = 2
    STALE = 3


@dataclass(frozen=True)
class DiagnosticEntry:
    """One ``DiagnosticStatus``: level, name, message, hardware id and (key, value) strings."""

    level: DiagnosticLevel
    name: str
    message: str
    hardware_id: str
    values: tuple[tuple[str, str], ...]


def _text(value: object) -> str:
    return "" if value is None else str(value)


def diagnostic_entries(status: dict, pose_timeout_s: float, replan_budget_s: float,
                       hardware_id: str = "") -> list[DiagnosticEntry]:
    """The entries of :data:`COMPONENTS` for status document ``status``. ``pose_timeout_s`` [s]: a pose older is
    WARN; ``replan_budget_s`` [s]: a p99 solve time above it is WARN; ``hardware_id``: the gimbal's port."""
    name = _text(status.get("name")) or "pivotd"
    out = []

    def add(component: str, level: DiagnosticLevel, message: str, hw: str = "", **values: object) -> None:
        out.append(DiagnosticEntry(level, f"{name}: {component}", message, hw,
                                   tuple((k, _text(v)) for k, v in values.items())))

    state = _text(status.get("state"))
    error = status.get("last_error")
    last_error = error.get("message") if isinstance(error, dict) else error
    level = (DiagnosticLevel.ERROR if state in _ERROR_STATES else DiagnosticLevel.WARN if state in _WARN_STATES
             else DiagnosticLevel.OK)
    add("state", level, state, state=state, last_error=last_error, reloads=status.get("reloads"),
        needs_restart=",".join(status.get("needs_restart") or ()))

    link, link_error = _text(status.get("link")), _text(status.get("link_error"))
    level = (DiagnosticLevel.OK if link == "up" else DiagnosticLevel.STALE if link == "stopped"
             else DiagnosticLevel.ERROR)
    message = f"{link}: {link_error}" if link_error and level is not DiagnosticLevel.OK else link
    add("gimbal link", level, message, hardware_id, link=link, link_error=link_error)

    age = status.get("pose_age_s")
    if age is None:
        level, message = DiagnosticLevel.STALE, "no pose received"
    elif age > pose_timeout_s:
        level, message = DiagnosticLevel.WARN, f"pose stale ({age:.2f} s > {pose_timeout_s:g} s): holding"
    else:
        level, message = DiagnosticLevel.OK, f"pose age {age:.3f} s"
    add("pose", level, message, pose_age_s=age, pose_timeout_s=pose_timeout_s)

    gimbal = status.get("gimbal")
    if gimbal is None:
        add("gimbal faults", DiagnosticLevel.STALE, "no gimbal state", hardware_id, faults="", fault_names="")
    else:
        names = ",".join(gimbal.get("fault_names") or ())
        faults = int(gimbal.get("faults") or 0)
        add("gimbal faults", DiagnosticLevel.ERROR if faults else DiagnosticLevel.OK,
            f"faults: {names or hex(faults)}" if faults else "no faults", hardware_id, faults=f"0x{faults:04x}",
            fault_names=names, mode=gimbal.get("mode"), fault_episodes=status.get("fault_episodes"))

    planner = status.get("planner") or {}
    p50, p99, plans = planner.get("solve_ms_p50"), planner.get("solve_ms_p99"), planner.get("plans", 0)
    budget_ms = replan_budget_s * 1e3
    if not plans:
        level, message = DiagnosticLevel.STALE, "no plan yet"
    elif p99 is not None and p99 > budget_ms:
        level, message = DiagnosticLevel.WARN, f"solve time p99 {p99:g} ms above the {budget_ms:g} ms budget"
    else:
        level, message = DiagnosticLevel.OK, f"solve time p50 {_text(p50)} ms, p99 {_text(p99)} ms"
    add("planner", level, message, plans=plans, solve_ms_p50=p50, solve_ms_p99=p99, budget_ms=budget_ms,
        visible_now=planner.get("visible_now"), timeouts=planner.get("timeouts"),
        worker_restarts=planner.get("worker_restarts"))
    return out
