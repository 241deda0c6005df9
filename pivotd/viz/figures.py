"""Figures of a recorded run (``pivotd plot``). Needs matplotlib (the ``plot`` extra); renders headless (Agg).

* ``route``: the route from above with the gimbal camera's viewing directions (blue), a forward-facing
  camera's (red) and the landmarks, those that entered the gimbal camera's FoV highlighted (the paper's figures);
* ``visibility``: landmarks in the FoV over time, gimbal vs forward-facing camera and the achievable view (the
  best path the configured gimbal can execute on the route, ``pivotd bench achievable``);
* ``joints``: commanded vs measured pan and tilt with the joint limits, and below it the state timeline: the
  daemon's state over time as steps, gimbal faults set and cleared as vertical lines, UTC clock time on top;
* ``dynamics``: rate, acceleration and jerk of the commanded motion (of the measured one when the recording
  has no setpoints) against the configured limits.
"""

from __future__ import annotations

import datetime
import logging
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from pivotd.daemon.states import DaemonState
from pivotd.errors import InputError

log = logging.getLogger(__name__)

if TYPE_CHECKING:  # the figure names stay importable without the recording's dependencies
    from pivotd.bench.achievable import AchievableSeries
    from pivotd.viz.recording import JointSeries, Recording
    from pivotd.viz.views import Views

FIGURES = ("route", "visibility", "joints", "dynamics")
#: figure size [inches] of each figure drawn alone, and of ``all``
SIZES = {"route": (9.0, 7.0), "visibility": (9.0, 4.0), "joints": (9.0, 6.0), "dynamics": (9.0, 7.5),
         "all": (16.0, 11.0)}
PIVOT_COLOR, FORWARD_COLOR, ACHIEVABLE_COLOR = "tab:blue", "tab:red", "tab:gray"
AXIS_COLORS = {"pan": "tab:green", "tilt": "tab:purple"}
ENVELOPE_S = 0.1  # [s] window of the acceleration and jerk envelopes
FAULT_COLOR = "tab:red"
JOINTS_TIMELINE_RATIOS = (3.0, 1.2)  # heights of the joints panel and of the state timeline below it


def require_pyplot() -> Any:
    """matplotlib.pyplot on the Agg backend, or InputError naming the extra that provides it."""
    try:
        import matplotlib
    except ImportError:
        raise InputError("plotting needs matplotlib: pip install 'pivotd[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def build_figure(run: Recording, which: str = "all", views: Views | None = None,
                 achievable: AchievableSeries | None = None) -> Any:
    """The matplotlib Figure ``which`` (one of :data:`FIGURES` or ``all``: every one on one page). ``views`` and
    ``achievable`` (the visibility panel's achievable line) are computed from ``run`` when not given."""
    if which not in (*FIGURES, "all"):
        raise InputError(f"unknown figure {which!r}; expected one of {', '.join((*FIGURES, 'all'))}")
    plt = require_pyplot()
    if views is None and which in ("route", "visibility", "all"):
        from pivotd.viz.views import camera_views

        views = camera_views(run)
    if achievable is None and which in ("visibility", "all"):
        achievable = _achievable_series(run)
    fig = plt.figure(figsize=SIZES[which], layout="constrained")
    if which == "all":
        grid = fig.add_gridspec(3, 2, width_ratios=(1.15, 1.0))
        draw_route(fig.add_subplot(grid[0:2, 0]), run, views)
        draw_visibility(fig.add_subplot(grid[2, 0]), views, achievable)
        joints, timeline = grid[0, 1].subgridspec(2, 1, height_ratios=JOINTS_TIMELINE_RATIOS).subplots(sharex=True)
        draw_joints(joints, run)
        draw_timeline(timeline, run)
        draw_dynamics(grid[1:3, 1].subgridspec(3, 1).subplots(sharex=True), run)
        started = f", started {run.start:%Y-%m-%d %H:%M:%S} UTC" if run.start is not None else ""
        fig.suptitle(f"{run.cfg.name}: {run.path.name}{started}", fontsize=11)
    elif which == "route":
        draw_route(fig.add_subplot(), run, views)
    elif which == "visibility":
        draw_visibility(fig.add_subplot(), views, achievable)
    elif which == "joints":
        joints, timeline = fig.subplots(2, 1, sharex=True, height_ratios=JOINTS_TIMELINE_RATIOS)
        draw_joints(joints, run)
        draw_timeline(timeline, run)
    else:
        draw_dynamics(fig.subplots(3, 1, sharex=True), run)
    return fig


def save_figure(fig: Any, out: str | Path, dpi: int = 110) -> Path:
    """Write ``fig`` as PNG to ``out`` and release it."""
    plt = require_pyplot()
    out = Path(out)
    try:
        fig.savefig(out, dpi=dpi)
    except OSError as exc:
        raise InputError(f"{out}: cannot write ({exc.strerror})") from None
    finally:
        plt.close(fig)
    return out


def _arrow_frames(cams: np.ndarray, count: int = 28) -> np.ndarray:
    """Indices of about ``count`` frames evenly spaced by distance travelled (none where the robot stood)."""
    if cams.shape[0] == 0:
        return np.zeros(0, int)
    s = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(cams[:, :2], axis=0), axis=1))])
    if s[-1] <= 0:
        return np.array([0])
    marks = np.linspace(0.0, s[-1], count)
    return np.unique(np.searchsorted(s, marks).clip(0, cams.shape[0] - 1))


def draw_route(ax: Any, run: Recording, views: Views) -> None:
    """Top view: landmarks near the route (grey), those the gimbal camera saw (orange), route, view arrows."""
    cfg = run.cfg
    pts = run.landmarks
    route = run.pose_pos
    reach = cfg.map.filters.max_range
    lo, hi = route[:, :2].min(axis=0) - reach, route[:, :2].max(axis=0) + reach
    near = np.all((pts[:, :2] >= lo) & (pts[:, :2] <= hi), axis=1)
    unseen = near & ~views.seen
    ax.scatter(pts[unseen, 0], pts[unseen, 1], s=2, c="0.75", linewidths=0, label=f"landmarks ({int(near.sum())})")
    ax.scatter(pts[views.seen, 0], pts[views.seen, 1], s=3, c="tab:orange", linewidths=0,
               label=f"seen by the gimbal camera ({int(views.seen.sum())})")
    ax.plot(route[:, 0], route[:, 1], "-", c="k", lw=1.2, label="route")
    ax.plot(route[0, 0], route[0, 1], "o", c="k", ms=5)
    idx = _arrow_frames(views.cameras)
    length = 0.045 * float(np.max(hi - lo))  # arrows scale with the drawn area
    for key, color, label in (("forward", FORWARD_COLOR, "forward-facing camera"), ("pivot", PIVOT_COLOR,
                                                                                   "gimbal camera (PIVOT)")):
        d = getattr(views, key)[idx, :2]
        norm = np.linalg.norm(d, axis=1, keepdims=True)
        d = np.where(norm > 1e-9, d / np.maximum(norm, 1e-9), 0.0) * length
        c = views.cameras[idx]
        ax.quiver(c[:, 0], c[:, 1], d[:, 0], d[:, 1], color=color, angles="xy", scale_units="xy", scale=1,
                  width=0.004 if key == "pivot" else 0.003, alpha=1.0 if key == "pivot" else 0.6, label=label)
    ax.set_xlim(lo[0], hi[0])
    ax.set_ylim(lo[1], hi[1])
    ax.set_aspect("equal", adjustable="box")
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title(f"route from above: viewing directions and landmarks (FoV {cfg.pivot.fov_deg:.0f}°, "
                 f"range {cfg.map.filters.min_range:g}–{reach:g} m)")
    ax.legend(loc="best", fontsize=7, markerscale=3)


def _achievable_series(run: Recording) -> AchievableSeries | None:
    """The achievable view per frame of ``run``, or None (with a warning) when the run is too short for it."""
    from pivotd.bench.achievable import achievable

    try:
        return achievable(run).series
    except InputError as exc:
        log.warning("no achievable view in the figure: %s", exc)
        return None


def draw_visibility(ax: Any, views: Views, achievable: AchievableSeries | None = None) -> None:
    """Landmarks in the FoV per frame, gimbal vs forward-facing camera, and the achievable view when given."""
    ax.plot(views.t, views.n_pivot, c=PIVOT_COLOR, lw=1.2,
            label=f"gimbal camera (PIVOT), mean {views.n_pivot.mean() if views.t.size else 0:.1f}")
    ax.plot(views.t, views.n_forward, c=FORWARD_COLOR, lw=1.0,
            label=f"forward-facing camera, mean {views.n_forward.mean() if views.t.size else 0:.1f}")
    if achievable is not None:
        ax.plot(achievable.t, achievable.n_achievable, c=ACHIEVABLE_COLOR, lw=1.0, ls="--",
                label=f"achievable (best executable path), mean {achievable.n_achievable.mean():.1f}")
    ax.set_xlabel("time [s]")
    ax.set_ylabel("landmarks in the FoV")
    ax.set_ylim(bottom=0)
    ax.set_title("visible landmarks over time")
    ax.legend(loc="best", fontsize=8)


def draw_joints(ax: Any, run: Recording) -> None:
    """Pan and tilt [deg] over time: measured (solid), commanded (dashed) and the joint limits of the run's config
    (``gimbal.limits``, dotted: min then max per axis, after the data lines)."""
    for i, axis in enumerate(("pan", "tilt")):
        color = AXIS_COLORS[axis]
        ax.plot(run.measured.t, np.degrees(run.measured.angles[:, i]), "-", c=color, lw=3.0, alpha=0.35,
                label=f"{axis} measured")
        if len(run.commanded):
            ax.plot(run.commanded.t, np.degrees(run.commanded.angles[:, i]), "--", c=color, lw=1.0,
                    label=f"{axis} commanded")
    for axis, (lo, hi) in joint_limits_deg(run).items():
        ax.axhline(lo, c=AXIS_COLORS[axis], ls=":", lw=1.0, label=f"{axis} limits {lo:g}°…{hi:g}°")
        ax.axhline(hi, c=AXIS_COLORS[axis], ls=":", lw=1.0, label="_nolegend_")
    ax.set_ylabel("joint angle [deg]")
    source = "" if len(run.commanded) else " (no setpoints in this recording)"
    ax.set_title(f"commanded vs measured pan/tilt{source}")
    ax.legend(loc="best", fontsize=8, ncol=2)


def joint_limits_deg(run: Recording) -> dict[str, tuple[float, float]]:
    """The run's joint limits (``gimbal.limits``) per axis: (min, max) [deg]."""
    lim = run.cfg.gimbal.limits
    return {"pan": (round(float(np.degrees(lim.pan_min)), 6), round(float(np.degrees(lim.pan_max)), 6)),
            "tilt": (round(float(np.degrees(lim.tilt_min)), 6), round(float(np.degrees(lim.tilt_max)), 6))}


def state_steps(run: Recording) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """The daemon's state as steps: change times (K,) [s] (the last one repeated at the end of the recording),
    levels (K,) (indices into the names) and the names: the states the run went through, in
    :class:`DaemonState` order (unknown ones after). Empty arrays when the recording has no state timeline."""
    events = run.states("state")
    if not events:
        return np.zeros(0), np.zeros(0, int), []
    seen = {str(e.value) for e in events}
    names = [str(s) for s in DaemonState if str(s) in seen] + sorted(seen - {str(s) for s in DaemonState})
    t = [e.t for e in events]
    levels = [names.index(str(e.value)) for e in events]
    end = max(t[-1], float(run.measured.t[-1]) if len(run.measured) else t[-1])
    return np.array([*t, end]), np.array([*levels, levels[-1]]), names


def fault_marks(run: Recording) -> list[tuple[float, bool, str]]:
    """The gimbal's fault bits changing: (time [s], set (True) or cleared (False), label) per change."""
    marks = []
    for e in run.states("faults"):
        bits, before = int(e.value or 0), int(e.previous or 0)
        if bits == before or (e.previous is None and not bits):
            continue
        names = ", ".join(e.extra.get("names") or ()) or "none"
        marks.append((e.t, bool(bits), f"fault 0x{bits:04x} ({names})" if bits else "faults cleared"))
    return marks


def draw_timeline(ax: Any, run: Recording) -> None:
    """The daemon's state over time (steps, one level per state), fault bits set (solid red) and cleared (dotted),
    threads that died (black); UTC clock time on the top axis; the recording's start time in the title."""
    t, levels, names = state_steps(run)
    if names:
        ax.step(t, levels, where="post", c="k", lw=1.2, label="daemon state")
        ax.set_yticks(range(len(names)), names, fontsize=7)
        ax.set_ylim(-0.5, len(names) - 0.5)
    else:
        ax.text(0.5, 0.5, "no state timeline in this recording", transform=ax.transAxes, ha="center", va="center")
        ax.set_yticks([])
    for k, (time_s, is_set, label) in enumerate(fault_marks(run)):
        ax.axvline(time_s, c=FAULT_COLOR, ls="-" if is_set else ":", lw=1.0, label=label if k < 6 else "_nolegend_")
    for e in run.states("threads_dead"):
        if e.value:
            ax.axvline(e.t, c="k", ls="--", lw=1.0, label=f"thread died: {', '.join(map(str, e.value))}")
    if len(ax.get_lines()) > 1:
        ax.legend(loc="upper left", fontsize=7)
    ax.set_xlabel("time [s]")
    started = f"recording started {run.start:%Y-%m-%d %H:%M:%S} UTC" if run.start is not None else "no messages"
    ax.set_title(f"daemon state and faults ({started})", fontsize=9)
    if run.start is not None:
        add_utc_axis(ax, run.start)


def add_utc_axis(ax: Any, start: datetime.datetime) -> Any:
    """A secondary time axis on top of ``ax`` labelled with the UTC clock time (``start`` + the axis' seconds)."""
    from matplotlib.ticker import FuncFormatter

    top = ax.secondary_xaxis("top")
    top.xaxis.set_major_formatter(FuncFormatter(
        lambda s, _: (start + datetime.timedelta(seconds=float(s))).strftime("%H:%M:%S")))
    top.set_xlabel("UTC", fontsize=7)
    top.tick_params(labelsize=7)
    return top


def motion_derivatives(series: JointSeries, dt: float | None) -> tuple[np.ndarray, ...]:
    """Rate (N, 2) [rad/s], acceleration (N-1, 2) [rad/s²], jerk (N-2, 2) [rad/s³] and their times.

    Rates are the series' own when it carries them, else differences of the angles. ``dt`` [s] is the fixed
    period between samples (setpoints: one control period each), or None to use the sample times."""
    t = series.t
    steps = np.full(max(t.size - 1, 0), dt) if dt is not None else np.maximum(np.diff(t), 1e-6)
    if np.all(np.isfinite(series.rates)) and series.rates.size:
        rate, t_rate = series.rates, t
    else:
        rate = np.diff(series.angles, axis=0) / steps[:, None]
        t_rate, steps = t[1:], steps[1:]
    acc = np.diff(rate, axis=0) / steps[: rate.shape[0] - 1, None]
    jerk = np.diff(acc, axis=0) / steps[: max(acc.shape[0] - 1, 0), None]
    return t_rate, rate, t_rate[1:], acc, t_rate[2:], jerk


def max_envelope(t: np.ndarray, y: np.ndarray, window: float) -> tuple[np.ndarray, np.ndarray]:
    """Maximum of ``y`` (N,) per window of ``window`` [s] of the sorted times ``t`` (N,): window starts, maxima."""
    if t.size == 0:
        return t, y
    bins = np.floor((t - t[0]) / window).astype(np.int64)
    starts = np.flatnonzero(np.diff(bins, prepend=-1))
    return t[0] + bins[starts] * window, np.maximum.reduceat(y, starts)


def draw_dynamics(axes: Any, run: Recording) -> None:
    """Three stacked axes: |rate|, |acceleration|, |jerk| per joint [deg/s^k] with the limits as dashed lines."""
    commanded = len(run.commanded) > 2
    series = run.commanded if commanded else run.measured
    limits = {"pan": run.cfg.motion.pan, "tilt": run.cfg.motion.tilt}
    t_v, v, t_a, a, t_j, j = motion_derivatives(series, run.cfg.control.dt if commanded else None)
    rows = (("rate", "deg/s", t_v, v, "max_velocity", None),
            ("acceleration", "deg/s²", t_a, a, "max_acceleration", ENVELOPE_S),
            ("jerk", "deg/s³", t_j, j, "max_jerk", ENVELOPE_S))
    for ax, (what, unit, t, values, limit_name, window) in zip(axes, rows, strict=True):
        peaks = []
        top = 0.0
        for i, axis in enumerate(("pan", "tilt")):
            color = AXIS_COLORS[axis]
            limit = np.degrees(getattr(limits[axis], limit_name))
            series_deg = np.degrees(np.abs(values[:, i])) if values.size else np.zeros(0)
            if window is None:
                ax.plot(t, series_deg, c=color, lw=0.9, label=f"|{axis}|")
            else:  # bang-bang profiles alternate every period: show the envelope
                t_env, env = max_envelope(t, series_deg, window)
                ax.step(t_env, env, where="post", c=color, lw=0.9, label=f"|{axis}|, max per {window:g} s")
            ax.axhline(limit, c=color, ls="--", lw=1.0, label=f"{axis} limit {limit:g}")
            top = max(top, limit, float(series_deg.max()) if series_deg.size else 0.0)
            if series_deg.size:
                peaks.append(f"{axis} {series_deg.max() / limit:.0%}")
        ax.set_ylabel(f"{what} [{unit}]")
        ax.set_ylim(0, 1.45 * top)  # room for the legend above the lines
        ax.set_title(f"{what}: peak {', '.join(peaks) or '-'} of the limit", fontsize=9)
        ax.legend(loc="upper right", fontsize=7, ncol=2)
    axes[-1].set_xlabel("time [s]")
    source = "setpoints sent" if commanded else "measured joint states"
    axes[0].set_title(f"{source}: {axes[0].get_title()}", fontsize=9)
