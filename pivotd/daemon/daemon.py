"""The pivotd daemon: wiring, threads, states, signals (docs/ARCHITECTURE.md, docs/design/daemon.md).

Threads: the main thread (signals, status, supervision: fault clearing, parking), the planner thread
(receding-horizon PIVOT at ``planner.replan_hz``, computed by the planner process of
:mod:`pivotd.daemon.worker`, which owns the map; it also applies reloads, so that it alone talks to
the worker), the control thread (absolute deadlines at ``control.rate_hz``: plan -> pan/tilt ->
Ruckig -> SETPOINT, systemd watchdog), the gimbal link's threads and Zenoh's callback threads.
Threads share only immutable objects (pose, path, plan, config) swapped by reference assignment.
"""

from __future__ import annotations

import contextlib
import logging
import os
import signal
import sys
import threading
import time
from collections import Counter, deque
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.bus.diagnostics import diagnostic_entries
from pivotd.bus.markers import PlanVisuals
from pivotd.bus.messages import DIAGNOSTIC_ARRAY, CloudMsg, PathMsg, PoseSample, encode_diagnostics
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.qos import QoS
from pivotd.bus.ratelimit import RateLimitedLog
from pivotd.bus.security import input_key_exprs
from pivotd.bus.session import build_config, open_session_waiting
from pivotd.bus.topics import resolve_topic
from pivotd.config import Config, load_config
from pivotd.daemon import logqueue
from pivotd.daemon.control import ControlLoop
from pivotd.daemon.last_error import LastErrors
from pivotd.daemon.planner import Plan, Rescue
from pivotd.daemon.pose_gate import PoseGate, PoseVerdict
from pivotd.daemon.recorder import off_status as recording_off
from pivotd.daemon.reload import apply_reload, plan_reload
from pivotd.daemon.state_log import StateLog
from pivotd.daemon.states import DaemonState
from pivotd.daemon.systemd import Notifier, watchdog_interval
from pivotd.daemon.visuals import build_plan_visuals
from pivotd.daemon.wakeup import StopFlag, Wakeup
from pivotd.daemon.wiring import (
    build_control_loop,
    build_control_settings,
    build_gimbal,
    build_replan_trigger,
    park_joints,
    release_free_memory,
    replan_anchor,
    return_large_frees_to_the_os,
)
from pivotd.daemon.worker import PlannerWorker, ReplanTimeoutError, WorkerError
from pivotd.errors import PivotdError
from pivotd.firmware_proto.messages import FAULT_WATCHDOG, MODE_NAMES, fault_names
from pivotd.gimbal.interface import GimbalInterface, GimbalMode, LinkState
from pivotd.gimbal.kinematics import joints_to_world_direction
from pivotd.gimbal.mavlink_frames import heading_from_body_quat
from pivotd.gimbal.mavlink_link import MavlinkGimbal
from pivotd.maps.formats import LandmarkCloud, make_cloud
from pivotd.version import version

log = logging.getLogger("pivotd.daemon")

SWITCH_INTERVAL_S = 0.0005
HOST_STALL_S = 0.25  # [s] a supervision pass this much later than its period: the process stalled
HOST_STALL_WINDOW_S = 2.0  # [s] a watchdog hold reported this soon after a stall of the process is the stall's
DIAGNOSTICS_PERIOD_S = 1.0  # [s] /diagnostics at about 1 Hz (from the status document, published at 1-5 Hz)
PARK_LINK_GRACE_S = 1.0  # [s] parking waits this long for a link lost meanwhile to come back, then stops


@dataclass(frozen=True)
class RunOverrides:
    """Command-line overrides of the config: gimbal port URL, Zenoh endpoints, MCAP recording."""

    port: str | None = None
    connect: tuple[str, ...] = ()
    listen: tuple[str, ...] = ()
    record: Path | None = None


def status_line(status: dict) -> str:
    """The one-line summary of a status document sent to systemd as STATUS= (``systemctl status``)."""
    planner = status.get("planner") or {}
    visible = planner.get("visible_now")
    return (f"{status['state']}; gimbal link {status['link']}; "
            f"{'no plan' if visible is None else f'{visible} landmarks in view'}; "
            f"map {status['map']['landmarks']} landmarks; {planner.get('plans', 0)} plans")


def _percentile_ms(values, q: float) -> float | None:
    return None if not values else round(float(np.percentile(np.asarray(values), q)) * 1e3, 3)


class Daemon:
    """One pivotd process. ``run()`` blocks until SIGTERM/SIGINT (or :meth:`request_stop`)."""

    def __init__(self, config_path: str | Path, overrides: RunOverrides | None = None) -> None:
        self.config_path = Path(config_path)
        self.overrides = overrides or RunOverrides()
        self.cfg: Config = self._load_config()
        self.notifier = Notifier()
        self.state = DaemonState.STARTING
        self._stop = StopFlag()  # shutdown requested: leave the main loop, park (set by the SIGTERM handler)
        self._stop_signal: int | None = None  # the signal that asked for it (logged by the main thread)
        self._halt = threading.Event()  # threads exit (after parking)
        # Cuts the planner thread's wait short (reload, stop); set by signal handlers, so no lock (see wakeup.py).
        self._planner_wake = Wakeup()
        self._lock = threading.Lock()
        # Latest inputs: immutable objects swapped by reference.
        self.pose: PoseSample | None = None  # the last pose the pose gate accepted
        self._pose_gate = PoseGate()
        self._path: tuple[np.ndarray, np.ndarray | None, int] | None = None
        self._path_version = 0
        self._pending_clouds: dict[str, CloudMsg] = {}
        self._bus_layers: dict[str, LandmarkCloud] = {}  # layers received over Zenoh, kept across reloads
        self.plan: Plan | None = None
        # The map and the optimizer live in the planner process (see pivotd/daemon/worker.py).
        self.worker = PlannerWorker(self.cfg, logging.getLogger().getEffectiveLevel())
        self._sent_path_version = -1
        self._worker_errors = 0
        self.link: GimbalInterface | None = None
        self.bus: PivotBus | None = None
        self.visuals: PlanVisuals | None = None  # live markers and camera TF (cfg.ros)
        self.session = None
        self.control: ControlLoop | None = None
        self._jitter: deque = deque(maxlen=5000)
        self._solve: deque = deque(maxlen=500)
        self._plans = 0
        self._rescues: Counter[Rescue] = Counter()  # replans by what the rescue of a blind warm start did
        self._seeds: Counter[str] = Counter()  # plans by the seed they came from (warm, anchor, chain, joint_grid, ...)
        self._replan_trigger = build_replan_trigger(self.cfg)
        self._inputs_generation = 0  # counts map layer replacements and worker restarts (inputs of a plan)
        self._reloads = 0
        self._reload_errors = 0
        # SIGHUPs received (written by the signal handler only; the kernel merges those still pending) and, of them,
        # the ones the reloads run so far answer (planner thread only): a reload is pending while they differ.
        self._reload_requests = 0
        self._reload_served = 0
        self._reload_runs = 0  # reloads started (planner thread)
        self._needs_restart: tuple[str, ...] = ()  # changed settings that wait for a restart
        self._errors = LastErrors()  # the status's last_error (assign a "source: text" string to _last_error)
        self._dead_threads: set[str] = set()  # threads that must not die and did (logged once each)
        self._clear_attempts = 0
        self._fault_episodes = 0  # faults seen since start (each run of FAULT states counts once)
        self._last_host_stall = -np.inf  # [s monotonic] when this process last stalled (SIGSTOP, no CPU)
        self._host_stalls_seen = 0
        self._last_supervision: float | None = None
        self._last_clear = 0.0
        self._last_link_error: str | None = None
        self._rl = RateLimitedLog(log)
        self._states = StateLog(self.cfg.topics.pose, self.cfg.topics.path, log)  # state changes, logged once each
        self._threads: list[threading.Thread] = []
        self._recorder = None
        self._timeline = None  # the recording's state timeline (pivotd/daemon/timeline.py), with a recording
        self._map_published = 0  # the worker's map loads (PlannerWorker.map_previews) already published
        self._diagnostics_pub = None  # /diagnostics (cfg.ros.diagnostics)
        self._diagnostics_at = -np.inf  # [s monotonic] when diagnostics were last published

    @property
    def _last_error(self) -> str:
        """The current error's message; assigning ``"source: text"`` records it with its time."""
        return self._errors.message

    @_last_error.setter
    def _last_error(self, message: str) -> None:
        self._errors.set(message)

    # ------------------------------------------------------------------ configuration
    def _load_config(self) -> Config:
        ov = self.overrides
        return load_config(self.config_path).with_overrides(
            port=ov.port, connect=list(ov.connect) or None, listen=list(ov.listen) or None)

    # ------------------------------------------------------------------ bus callbacks (bus decoding threads)
    def _on_pose(self, pose: PoseSample) -> None:
        verdict = self._pose_gate.check(pose, self.cfg.pose_gate, self.cfg.control.pose_timeout_s)
        if verdict is PoseVerdict.ACCEPTED:
            self.pose = pose
            link = self.link
            if isinstance(link, MavlinkGimbal):  # for a gimbal reporting yaw in the earth frame without delta_yaw
                link.set_vehicle_heading(heading_from_body_quat(pose.quat), at=pose.rx_time)
            if self._recorder is not None and self.cfg.topics.pose_from_tf:  # the bus recorded only the TF messages
                self._record_tf_pose(pose)
            self._states.pose(pose)
            return
        last = self.pose
        where = "" if last is None else f" (last accepted at {np.round(last.position, 2).tolist()})"
        t = self.cfg.topics
        source = f"TF {t.map_frame} -> {t.base_frame}" if t.pose_from_tf else t.pose
        self._rl.warning(f"pose:{verdict.value}", f"{source}: pose at "
                         f"{np.round(pose.position, 2).tolist()} refused: exceeds the pose_gate {verdict.value} "
                         f"limit{where}")

    def _record_tf_pose(self, pose: PoseSample) -> None:
        """Record a pose composed from TF on the recording's TF pose channel (queued, never raises)."""
        from pivotd.bus.messages import POSE_STAMPED, encode_pose_stamped
        from pivotd.daemon.recorder import TF_POSE_TOPIC

        self._recorder.write(TF_POSE_TOPIC, POSE_STAMPED,
                             encode_pose_stamped(pose.stamp, pose.frame_id, pose.position, pose.quat),
                             int(pose.stamp * 1e9))

    def _on_path(self, path: PathMsg) -> None:
        with self._lock:
            self._path_version += 1
            self._path = (path.positions, path.quats, self._path_version)
        self._states.path(int(path.positions.shape[0]))

    def _on_cloud(self, layer: str, cloud: CloudMsg) -> None:
        with self._lock:
            self._pending_clouds[layer] = cloud

    # ------------------------------------------------------------------ planner thread
    def _apply_pending_clouds(self) -> None:
        with self._lock:
            pending, self._pending_clouds = self._pending_clouds, {}
        for layer, cloud in pending.items():
            topic = getattr(self.cfg.topics, layer, layer)
            try:
                lc = make_cloud(topic, cloud.points, cloud.weights)
            except PivotdError as exc:
                self._rl.warning(f"cloud:{layer}", f"dropped cloud: {exc}")
                continue
            mult = float(getattr(self.cfg.map.layers, layer, 1.0))
            info = self.worker.set_layer(layer, lc, mult)
            self._inputs_generation += 1
            self._bus_layers[layer] = lc
            log.info("map layer %r replaced from %s: %d points (map version %d)", layer, topic, len(lc), info.version)

    def _planner_loop(self) -> None:
        """Replans on absolute deadlines ``next_t`` one replan period apart. An early wake (SIGHUP, stop) applies the
        pending reload and goes back to waiting for the same deadline, so no number of wakes moves the schedule;
        a replan that overran its period skips the deadlines it missed instead of replanning in a burst.

        Reloads coalesce: SIGHUPs that arrive while one is pending (or during a reload) are answered by the next
        one, so a storm of them is at most one reload under way and one pending (counted in the status)."""
        next_t = time.monotonic()
        while not self._stop.is_set():
            self._planner_wake.clear()  # a SIGHUP from now on wakes the wait below again
            try:
                requests = self._reload_requests
                if requests > self._reload_served:  # SIGHUPs not answered yet: one reload answers them all
                    self._reload_served = requests
                    self._reload_runs += 1
                    self._do_reload()
                now = time.monotonic()
                if now < next_t:
                    self._planner_wake.wait(next_t - now)
                    continue  # woken early: apply the reload, keep the deadline
                period = 1.0 / self.cfg.planner.replan_hz
                next_t += period
                if next_t <= now:  # this replan started more than a period late: skip the missed deadlines
                    next_t = now + period
                self._apply_pending_clouds()
                self._replan_once()
            except WorkerError as exc:
                self._worker_errors += 1
                self._last_error = f"planner: {exc}"
                if isinstance(exc, ReplanTimeoutError):  # a replan given up counts in solve_ms_* with its time
                    self._solve.append(exc.elapsed_s)
                if not self._stop.is_set():
                    log.error("planner worker: %s; restarting it", exc)
                    self._restart_worker()
            except PivotdError as exc:  # a refused request (e.g. a bad cloud): log it, keep planning
                self._rl.warning("planner", f"planner: {exc}")
                self._last_error = f"planner: {exc}"
            except Exception as exc:  # keep planning; never take the daemon down
                self._rl.exception("planner", f"planner: replan failed: {exc!r}")
                self._last_error = f"planner: {exc}"
            else:
                self._errors.resolve("planner")

    def _replan_once(self) -> None:
        pose = self.pose
        if pose is None or time.monotonic() - pose.rx_time > self.cfg.control.pose_timeout_s:
            return
        path = self._path
        version = 0 if path is None else path[2]
        if version != self._sent_path_version:
            self.worker.set_path(*(path or (None, None, 0)))
            self._sent_path_version = version
        now = time.monotonic()
        inputs = (version, self._inputs_generation)
        if self.plan is None:
            self._replan_trigger.reset()
        if self._replan_trigger.due(now, pose.position, inputs) is None:
            return  # the current plan stands (pivotd.daemon.replan_trigger)
        # the joints being commanded, at the attitude planned for (the park pose before the first setpoint)
        anchor = replan_anchor(self.cfg, None if self.control is None else self.control.commanded_joints, pose.quat)
        plan = self.worker.replan(pose.position, pose.quat, anchor, now=pose.rx_time)
        self._replan_trigger.planned(now, pose.position, inputs)
        self.plan = plan
        self._plans += 1
        self._rescues[plan.rescue] += 1
        self._seeds[plan.seed] += 1
        self._solve.append(plan.solve_s)
        if self.bus is not None:
            self.bus.publish_view_plan(pose.stamp, plan.positions, plan.directions)
            if self.visuals is not None:
                self.visuals.publish(pose.stamp, plan.positions, plan.directions, plan.body_quats[0], plan.in_view,
                                     self._measured_direction(pose))

    def _measured_direction(self, pose: PoseSample) -> np.ndarray | None:
        """World viewing direction (3,) from the measured joints and ``pose`` (None while the link is down)."""
        link = self.link
        st = link.state if link is not None and link.link_state == LinkState.UP else None
        if st is None:
            return None
        return joints_to_world_direction(st.pan, st.tilt, pose.quat, self.cfg.gimbal.mount)

    def _restart_worker(self) -> None:
        """Start a fresh planner process and give it back the bus layers and the path."""
        try:
            self.worker.restart(self.cfg)
        except PivotdError as exc:
            log.error("planner worker restart failed: %s", exc)
            self._stop.wait(1.0)
            return
        self._inputs_generation += 1
        for layer, lc in self._bus_layers.items():
            self.worker.set_layer(layer, lc, float(getattr(self.cfg.map.layers, layer, 1.0)))
        self._sent_path_version = -1

    # ------------------------------------------------------------------ control thread
    def _control_loop(self) -> None:
        assert self.control is not None and self.link is not None
        prio = self.cfg.control.realtime_priority
        if prio > 0:
            try:  # this thread only (pid 0 = the calling thread on Linux)
                os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param(prio))
                log.info("control thread runs SCHED_FIFO priority %d", prio)
            except (OSError, AttributeError) as exc:
                log.warning("control.realtime_priority %d not applied (%s); running with normal scheduling "
                            "(grant CAP_SYS_NICE or LimitRTPRIO in the service)", prio, exc)
        period = 1.0 / self.cfg.control.rate_hz
        js_every = max(1, round(self.cfg.control.rate_hz / self.cfg.control.joint_state_hz))
        wd = watchdog_interval()
        wd_period = wd / 2.0 if wd else None
        last_wd = 0.0
        k = 0
        t0 = time.monotonic()
        while not self._halt.is_set():
            deadline = t0 + k * period
            now = time.monotonic()
            if deadline > now:
                time.sleep(deadline - now)
                now = time.monotonic()
            elif now - deadline > period:
                # Overrun by more than a period: resynchronise instead of bursting.
                skipped = int((now - deadline) / period)
                k += skipped
                deadline = t0 + k * period
            self._jitter.append(now - deadline)
            k += 1
            # Nothing in a tick may end this thread: an exception anywhere is logged (rate-limited) and the next
            # tick comes at its deadline (the tick after a failed one restarts from what the link reports).
            try:
                pose = self.pose
                tick = self.control.tick(now, pose, self.plan)
                self.state = tick.mode
                self._states.tick(now, tick.mode, pose, self.cfg.control.pose_timeout_s)
                if self._timeline is not None:
                    self._timeline.state(tick.mode)
                if tick.setpoint is not None and self._recorder is not None:
                    self._record_setpoint(tick.setpoint)
            except Exception as exc:
                self._rl.exception("control", f"control: tick failed: {exc!r}")
                self._last_error = f"control: {exc!r}"
                continue
            self._errors.resolve("control")
            try:
                # The loop ticked without an exception: it is alive (link-down included, it reconnects by
                # itself), so systemd's watchdog is fed; a stuck or crashing loop stops feeding it.
                if wd_period and now - last_wd >= wd_period:
                    self.notifier.watchdog()
                    last_wd = now
                if k % js_every == 0 and self.bus is not None:
                    st = self.link.state
                    stamp = self.bus.now()  # None: simulation time and no /clock yet
                    if st is not None and self.link.link_state == LinkState.UP and stamp is not None:
                        self.bus.publish_joint_state(stamp, st.pan, st.tilt, st.pan_rate, st.tilt_rate)
            except Exception as exc:
                self._rl.warning("control:outputs", f"control: watchdog or joint_states failed: {exc!r}")

    # ------------------------------------------------------------------ supervision (main thread)
    def _note_host_stall(self, now: float) -> None:
        """Remember when this process last stalled: a gap between supervision passes beyond their period, or a
        stall the gimbal link saw (its ``host_stalls``)."""
        stalls = (self.link.counters().get("host_stalls", 0) if self.link is not None else 0)
        last = self._last_supervision
        if stalls != self._host_stalls_seen or (
                last is not None and now - last > 1.0 / self.cfg.control.status_hz + HOST_STALL_S):
            self._last_host_stall = now
        self._host_stalls_seen = stalls
        self._last_supervision = now

    def _supervise_gimbal(self) -> None:
        link = self.link
        self._note_host_stall(time.monotonic())
        if link is not None and link.last_error != self._last_link_error:
            self._last_link_error = link.last_error
            if link.last_error and link.link_state != LinkState.UP:
                log.warning("gimbal link: %s (retrying with backoff)", link.last_error)
        if link is None or link.link_state != LinkState.UP or link.state is None:
            return
        st = link.state
        now = time.monotonic()
        if st.mode == GimbalMode.FAULT or st.faults:
            if now - self._last_clear >= 1.0:
                self._last_clear = now
                # The device's watchdog held it because this process stalled: that is the host's stall (counted
                # in link_counters.host_stalls), not a fault of the gimbal. The bit is cleared all the same.
                host_stall = (st.faults == FAULT_WATCHDOG and st.mode != GimbalMode.FAULT
                              and now - self._last_host_stall <= HOST_STALL_WINDOW_S)
                if self._clear_attempts == 0 and not host_stall:
                    self._fault_episodes += 1
                self._clear_attempts += 1
                log.warning("gimbal fault bits 0x%04x (%s), mode %s: sending CLEAR_FAULT (attempt %d)",
                            st.faults, ", ".join(fault_names(st.faults)) or "none", MODE_NAMES.get(st.mode, st.mode),
                            self._clear_attempts)
                if link.clear_fault() and self.control is not None:
                    self.control.invalidate()
        else:
            self._clear_attempts = 0
        if st.mode == GimbalMode.DISABLED and not self._stop.is_set():
            log.info("gimbal is disabled: sending ENABLE")
            if link.set_enabled(True) and self.control is not None:
                self.control.invalidate()

    def _record_setpoint(self, setpoint: tuple[float, float, float, float]) -> None:
        """Record the setpoint just sent (pan, tilt [rad], rates [rad/s]) on the recording's command channel
        (queued: :meth:`Recorder.write` neither blocks nor raises; a failed recording says so in the status)."""
        from pivotd.bus.messages import JOINT_STATE, encode_joint_state
        from pivotd.daemon.recorder import JOINT_COMMAND_TOPIC

        pan, tilt, pan_rate, tilt_rate = setpoint
        stamp = time.time()
        names = list(self.cfg.topics.joint_names)
        self._recorder.write(JOINT_COMMAND_TOPIC, JOINT_STATE,
                             encode_joint_state(stamp, names, [pan, tilt], [pan_rate, tilt_rate]),
                             int(stamp * 1e9))

    def status(self) -> dict:
        """The JSON status document published on ``pivot/<name>/status``."""
        pose = self.pose
        link = self.link
        st = link.state if link is not None else None
        plan = self.plan
        state = self.state
        if st is not None and st.mode == GimbalMode.FAULT:
            state = DaemonState.FAULT
        ctl = self.control.stats if self.control is not None else None
        dead = self._check_threads()
        if dead:  # a thread that must not die did: the gimbal is not controlled, whatever the last tick said
            state = DaemonState.FAILED
        return {
            "name": self.cfg.name,
            "version": version(),
            "state": state,
            "time": time.time(),
            "pose_age_s": None if pose is None else round(time.monotonic() - pose.rx_time, 3),
            "link": link.link_state if link is not None else LinkState.STOPPED,
            "link_error": link.last_error if link is not None else None,
            "gimbal": None if st is None else {
                "mode": MODE_NAMES.get(st.mode, str(st.mode)),
                "faults": st.faults,
                "fault_names": fault_names(st.faults),
                "pan_deg": round(float(np.degrees(st.pan)), 3),
                "tilt_deg": round(float(np.degrees(st.tilt)), 3),
                "age_s": round(time.monotonic() - st.rx_time, 3),
            },
            "pose_gate": self._pose_gate.counters(),
            "clear_fault_attempts": self._clear_attempts,
            "fault_episodes": self._fault_episodes,
            "planner": {
                "plans": self._plans,
                "rescues_tried": self._rescues[Rescue.LOST] + self._rescues[Rescue.KEPT],
                "rescues_kept": self._rescues[Rescue.KEPT],
                "seeds": dict(sorted(self._seeds.items())),
                "solve_ms_p50": _percentile_ms(list(self._solve), 50),
                "solve_ms_p99": _percentile_ms(list(self._solve), 99),
                "horizon": 0 if plan is None else int(plan.directions.shape[0]),
                "landmarks": 0 if plan is None else plan.landmarks,
                "visible_now": None if plan is None else int(plan.visible[0]),
                "progress_m": None if plan is None or plan.s.shape[0] < 2 else round(float(plan.s[0]), 3),
                "worker_pid": self.worker.pid,
                "worker_restarts": self.worker.restarts,
                "worker_errors": self._worker_errors,
                "late": self.worker.late,
                "timeouts": self.worker.timeouts,
                "degrade": 0 if plan is None else plan.degrade,
                "path_mode": None if plan is None else plan.path_mode.value,  # on_path, off_path, no_path
                "path_offset_m": None if plan is None or plan.path_offset is None else round(plan.path_offset, 2),
                "off_path_replans": self.worker.off_path_replans,
                "path_points": 0 if self._path is None else int(self._path[0].shape[0]),  # of the last path received
            },
            "control": {
                "rate_hz": self.cfg.control.rate_hz,
                "jitter_ms_p99": _percentile_ms(list(self._jitter), 99),
                "setpoints": 0 if ctl is None else ctl.setpoints,
                "clamped": 0 if ctl is None else ctl.clamped,
                "pose_latency_ms_p99": None if ctl is None else _percentile_ms(list(ctl.pose_latency), 99),
            },
            "tracking_error": None if self.control is None else self.control.tracking.status(),
            "map": {"landmarks": self.worker.map_info.landmarks, "version": self.worker.map_info.version,
                    "layers": self.worker.map_info.layers},
            "link_counters": link.counters() if link is not None else {},
            "reloads": self._reloads,
            "reload_errors": self._reload_errors,
            "reload_requests": self._reload_requests,
            "reloads_coalesced": self._reload_served - self._reload_runs,
            "needs_restart": list(self._needs_restart),
            "last_error": self._errors.status(),
            "recording": self._recorder.status() if self._recorder is not None else recording_off(),
            "logging": logqueue.installed().status() if logqueue.installed() is not None else None,
            "threads_dead": sorted(dead),
        }

    def _check_threads(self) -> set[str]:
        """Names of the daemon's threads (control, planner) that ended while the daemon runs; each is logged once."""
        for t in self._threads:
            # the planner thread ends when a stop is requested, the control thread after parking
            ends = self._halt if t.name == "pivotd-control" else self._stop
            if not t.is_alive() and not ends.is_set() and t.name not in self._dead_threads:
                self._dead_threads.add(t.name)
                self._last_error = f"daemon: thread {t.name} died"
                log.error("thread %s died: %s", t.name, "the gimbal gets no setpoints (its watchdog holds it)"
                          if t.name == "pivotd-control" else "no more replans (the control loop holds)")
        return set(self._dead_threads)

    def _do_reload(self) -> None:
        """Apply a changed config (planner thread): live settings to the planner process and the control loop
        together; restart-only settings keep their running values and are logged (see pivotd.daemon.reload)."""
        self.notifier.reloading()
        running_plan = self.plan
        try:
            plan = plan_reload(self.cfg, self._load_config(), self.worker.map_identity)
            if not plan.keeps_plan:
                self.plan = None  # the control loop holds until the first plan made with the new settings
            info = apply_reload(plan, self.worker, self.control)
        except PivotdError as exc:
            self._reload_errors += 1
            self._last_error = f"reload: {exc}"
            if isinstance(exc, WorkerError):  # no answer in time: the worker's state is unknown
                log.error("reload failed, keeping the running config: %s; restarting the planner worker", exc)
                self._restart_worker()
            else:  # refused: neither the worker nor the control loop changed
                log.error("reload failed, keeping the running config and map: %s", exc)
            self.plan = running_plan
        except Exception as exc:  # a bug: put both sides back on the running config
            self._reload_errors += 1
            self._last_error = f"reload: {exc!r}"
            log.exception("reload failed, keeping the running config; restarting the planner worker")
            self._restart_worker()
            if self.control is not None:
                self.control.reconfigure(build_control_settings(self.cfg), self.cfg.gimbal.mount)
        else:
            self.cfg = plan.config
            if plan.reload_planner:  # a new planner in the worker: replan now (the running plan is tracked until then)
                self._replan_trigger = build_replan_trigger(self.cfg)
                self._inputs_generation += 1
            self._needs_restart = plan.needs_restart
            self._reloads += 1
            self._errors.resolve("reload")
            what = ("map read again" if plan.reload_map else "map kept" if plan.reload_planner
                    else "planner and map kept")
            log.info("reloaded %s: %d landmarks; applied: %s%s; %s", self.config_path, info.landmarks,
                     ", ".join(plan.applied) or "no setting changed",
                     " (a map file changed on disk)" if plan.map_file_changed else "", what)
            if plan.needs_restart:
                log.warning("changed settings that need a restart (running values kept): %s",
                            ", ".join(plan.needs_restart))
        self.notifier.ready()

    def _park(self) -> None:
        """Move to the park pose within the park timeout, then disable."""
        link, control = self.link, self.control
        if link is None or control is None:
            return
        if "pivotd-control" in self._check_threads():
            log.error("cannot park: the control thread is gone; disabling the gimbal where it stands")
            return
        if link.link_state != LinkState.UP:  # nothing to park: the device's watchdog holds it where it is
            log.warning("gimbal link %s: not parking (stopping now; the gimbal's own watchdog holds it)",
                        link.link_state)
            return
        self.state = DaemonState.PARKING
        target = park_joints(self.cfg)
        control.override_target = target
        if self._timeline is not None:
            self._timeline.parking()  # the control ticks may not get to say so: a park at the park pose is done
        deadline = time.monotonic() + self.cfg.gimbal.park_timeout_s
        down_since: float | None = None
        tol = np.radians(0.5)
        while time.monotonic() < deadline:
            st = link.state
            if link.link_state != LinkState.UP:  # a link hiccup: the supervisor reconnects; keep parking a while
                now = time.monotonic()
                down_since = now if down_since is None else down_since
                if now - down_since > PARK_LINK_GRACE_S:
                    log.warning("gimbal link lost while parking (down for %.1f s): stopping without the park pose",
                                now - down_since)
                    break
                time.sleep(0.02)
                continue
            down_since = None
            if st is not None and abs(st.pan - target[0]) < tol and abs(st.tilt - target[1]) < tol \
                    and abs(st.pan_rate) < 0.01 and abs(st.tilt_rate) < 0.01:
                break
            time.sleep(0.02)
        else:
            log.warning("park pose not reached within %.1f s", self.cfg.gimbal.park_timeout_s)
        control.override_target = None

    # ------------------------------------------------------------------ lifecycle
    def request_stop(self) -> None:
        self._stop.set()
        self._planner_wake.set()

    def _install_signals(self) -> None:
        def on_term(signum, _frame):  # no lock and no logging here: the main thread logs it (wakeup.py)
            self._stop_signal = signum
            self.request_stop()

        wake_fd = self._planner_wake.write_fd

        def on_hup(_signum, _frame):  # no lock and no Python call: the next SIGHUP may interrupt it (wakeup.py)
            self._reload_requests += 1
            try:  # noqa: SIM105 - contextlib.suppress is a Python call
                os.write(wake_fd, b"\0")
            except OSError:  # the pipe is full: the planner thread is woken already
                pass

        signal.signal(signal.SIGTERM, on_term)
        signal.signal(signal.SIGINT, on_term)
        signal.signal(signal.SIGHUP, on_hup)

    def _start(self) -> bool:
        """Start the gimbal link, the control and planner threads, then the bus. The gimbal is held from the start
        (no pose: the control loop holds where it is; supervision enables it and clears faults) while the session
        opens; in client mode that waits for the router for as long as it takes, staying responsive to SIGTERM
        and SIGHUP. READY=1 is sent once the gimbal is held, before the bus is up. False: stopped while waiting."""
        cfg = self.cfg
        return_large_frees_to_the_os()
        z = cfg.zenoh
        zenoh_settings = dict(mode=z.mode, connect=z.connect, listen=z.listen, config_file=z.config_file,
                              multicast_scouting=z.multicast_scouting, security=z.security,
                              input_keys=input_key_exprs(cfg.topics), max_message_bytes=cfg.topics.max_message_bytes)
        build_config(**zenoh_settings)  # bad Zenoh settings exit (2) before the gimbal is touched
        record = self.overrides.record if self.overrides.record is not None else cfg.record.path
        if record is not None:
            from pivotd.daemon.recorder import open_recording, record_run

            r = cfg.record
            self._recorder = open_recording(record, r.max_bytes, r.max_duration_s,
                                            what="--record" if self.overrides.record is not None else "record.path")
            record_run(self._recorder, cfg.name, cfg.source, version(), cfg.map.file, r.map_max_bytes)
            from pivotd.daemon.timeline import StateTimeline

            self._timeline = StateTimeline(self._recorder)
            self._timeline.state(self.state)
        self.link = build_gimbal(cfg)
        self.link.start()
        self.control = build_control_loop(cfg, self.link)
        self.state = DaemonState.WAITING
        if self._timeline is not None:
            self._timeline.state(DaemonState.WAITING)
        for name, target in (("planner", self._planner_loop), ("control", self._control_loop)):
            t = threading.Thread(target=target, name=f"pivotd-{name}", daemon=True)
            t.start()
            self._threads.append(t)
        where = ", ".join([*z.listen, *z.connect]) or z.mode
        bus_wait = f"waiting for the Zenoh router at {where}" if z.mode == "client" else f"opening Zenoh ({where})"
        self.notifier.ready(f"{DaemonState.WAITING}; {bus_wait}; gimbal held")
        self.session = open_session_waiting(self._wait_supervising, **zenoh_settings)
        if self.session is None:
            return False
        self.bus = PivotBus(self.session, cfg.topics, node_name=cfg.name, on_pose=self._on_pose,
                            on_path=self._on_path, on_cloud=self._on_cloud,
                            on_raw=self._recorder.write if self._recorder is not None else None, qos=cfg.ros.qos,
                            tf_timeout=cfg.control.pose_timeout_s)
        self.visuals = build_plan_visuals(self.bus, cfg)
        if cfg.ros.diagnostics:
            self._diagnostics_pub = self.bus.add_publisher(
                resolve_topic(cfg.ros.diagnostics_topic, cfg.topics.namespace), DIAGNOSTIC_ARRAY, QoS(depth=10))
        log.info("pivotd %s %r ready: %d landmarks, gimbal %s, zenoh %s", version(), cfg.name,
                 self.worker.map_info.landmarks, cfg.gimbal.port, where)
        return True

    def _publish_map(self) -> None:
        """Latch the map file's landmarks (strided, :data:`~pivotd.daemon.worker.MAX_PREVIEW_POINTS`) on the landmarks
        topic once per load of the map by the worker (start, reload, restart) with ``topics.publish_map``. An empty
        map is published only to replace one published before."""
        worker, bus = self.worker, self.bus
        if bus is None or not bus.topics.publish_map or worker.map_previews == self._map_published:
            return
        self._map_published = worker.map_previews
        points, weights = worker.map_preview
        if len(points) or bus.map_publisher is not None:
            bus.publish_map(bus.now() or 0.0, points, weights)
            log.info("map: %d landmarks published on %s", len(points), bus.topics.landmarks)

    def _publish_diagnostics(self, status: dict) -> None:
        """``status`` as a DiagnosticArray on ``ros.diagnostics_topic``, at most every :data:`DIAGNOSTICS_PERIOD_S`."""
        now = time.monotonic()
        if self._diagnostics_pub is None or now - self._diagnostics_at < DIAGNOSTICS_PERIOD_S:
            return
        self._diagnostics_at = now
        entries = diagnostic_entries(status, self.cfg.control.pose_timeout_s, self.cfg.planner.replan_budget,
                                     self.cfg.gimbal.port)
        self.bus.put(self._diagnostics_pub, encode_diagnostics(self.bus.now() or 0.0, entries))

    def _wait_supervising(self, seconds: float) -> bool:
        """Wait ``seconds`` while supervising the gimbal (before the bus is up); True as soon as stop is requested."""
        end = time.monotonic() + seconds
        period = 1.0 / self.cfg.control.status_hz
        while not self._stop.is_set():
            try:
                self._supervise_gimbal()
            except Exception as exc:
                self._rl.exception("supervise", f"supervision failed: {exc!r}")
            remaining = end - time.monotonic()
            if remaining <= 0:
                return False
            self._stop.wait(min(remaining, period))
        return True

    def run(self) -> int:
        """Run until stopped; returns the exit code (0 after a clean park and disable)."""
        # The control thread must get the GIL back promptly after its sleep: the default 5 ms switch
        # interval would add up to 5 ms of jitter whenever the planner thread is running Python code.
        sys.setswitchinterval(SWITCH_INTERVAL_S)
        self._install_signals()
        try:
            started = self._start()
            status_period = 1.0 / self.cfg.control.status_hz
            last_line = ""
            while started and not self._stop.is_set():
                self._stop.wait(status_period)
                try:
                    # Publish first: a fault that supervision clears right away is still reported once.
                    status = self.status()
                    if self.bus is not None:
                        self.bus.publish_status(status)
                        self._publish_map()
                        self._publish_diagnostics(status)
                    if self._timeline is not None:
                        self._timeline.status(status)
                    line = status_line(status)
                    if line != last_line:
                        self.notifier.status(line)
                        last_line = line
                    self._supervise_gimbal()
                    if self.bus is not None and self.bus.large_payload_seen():
                        release_free_memory()  # Zenoh reassembled it in many small heap blocks, now free
                except Exception as exc:
                    self._rl.exception("supervise", f"supervision failed: {exc!r}")
            if self._stop_signal is not None:
                log.info("signal %s: parking and stopping", signal.Signals(self._stop_signal).name)
            self.notifier.stopping()
            self._park()
        finally:
            self._stop.set()
            self._halt.set()
            for t in self._threads:
                t.join(timeout=2.0)
            if self.link is not None:
                self.link.stop(disable=True)
            if self.bus is not None:
                self.state = DaemonState.STOPPED
                with contextlib.suppress(Exception):
                    self.bus.publish_status(self.status())
                self.bus.close()
            if self.session is not None:
                self.session.close()
            if self._recorder is not None:
                if self._timeline is not None:
                    self._timeline.state(DaemonState.STOPPED)
                self._recorder.close()
            self.worker.close()
        log.info("pivotd stopped")
        return 1 if self._dead_threads else 0
