"""The control tick: plan + latest pose -> pan/tilt target -> Ruckig -> one SETPOINT.

:class:`ControlLoop` holds no thread; the daemon calls :meth:`ControlLoop.tick` at the control
rate with absolute deadlines. Each tick compensates body motion with the **latest** attitude,
converts the plan's world direction to joint angles within limits, and lets the jerk-limited
motion generator produce the setpoint. A stale pose or a missing plan means a jerk-limited stop
and hold; a lost link or a faulted gimbal means no motion at all.

The setpoint stream is continuous while the device follows it. It restarts from a state the device measured
only where the device stopped following it, as measured: link down, fault, device disabled (no setpoints are sent
then), or its watchdog stopped it (a HOLDING state, or a newly latched watchdog bit). The state is one measured
after the interruption (by the device's own clock, :class:`pivotd.gimbal.device_clock.DeviceClock`: states queued
during a stall of the host are read late but were measured before it, while the device may have held since), so
motion resumes from where the gimbal really is, jerk-limited, instead of where the stream left off.

An interruption the device may or may not have held through (a stall of the loop longer than ``stall_s``, a
setpoint held up past ``stall_s`` before sending, a restart requested after clearing a latched fault bit) waits
for a state measured after it and then decides by that state: the device held, so the stream restarts from the
measured state; or it kept following the last setpoint it got, so the stream continues from that setpoint. A
restart from the measured state while the device follows would add its tracking lag, or the distance it moved
since, as a step it cannot follow within its limits (finding 7 and case 9 in docs/RELIABILITY.md).

A watchdog hold restarts the stream only if the device held while following the current stream: the hold's
state echoes the last setpoint the device received, and a hold reported with a setpoint from before the current
stream's first one (a state that was delayed on a loaded host) is the interruption the stream already restarted
from. A setpoint is never sent more than ``stall_s`` after the previous one of its stream: if the thread was held up
between computing and sending it, the device may have held meanwhile; the setpoint is dropped, the generator goes
back to the last setpoint sent, and the stream resumes after a fresh state as above.

An axis that does not follow its setpoints (blocked: :mod:`pivotd.daemon.tracking_error`) is held: it restarts
from its measured state, nothing moves towards the target until the hold has lasted the supervisor's window, and
the stream then resumes jerk-limited from there.
"""

from __future__ import annotations

import logging
import time
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from pivotd.bus.messages import PoseSample
from pivotd.daemon.planner import Plan, camera_positions
from pivotd.daemon.states import DaemonState
from pivotd.daemon.tracking_error import TrackingErrorSettings, TrackingErrorSupervisor, TrackingState
from pivotd.firmware_proto.messages import FAULT_WATCHDOG
from pivotd.geometry import quat_to_matrix, so3_exp, so3_log
from pivotd.gimbal.interface import GimbalInterface, GimbalMode, GimbalState, LinkState
from pivotd.gimbal.kinematics import JointLimits, Mount, joints_to_world_direction, world_direction_to_joints
from pivotd.gimbal.motion import MotionGenerator, MotionSample

log = logging.getLogger(__name__)

MAX_TURN_RATE = 20.0  # [rad/s] a body turn rate above this between two poses is a jump of the pose, not a turn
TURN_RATE_FLOOR = 1e-3  # [rad/s] below this the body is taken as not turning
#: [m] How far around where the camera was last located on a plan (and on from there by the distance the camera
#: has moved since) it is located on the next one: a route that comes back past the robot within the plan's horizon
#: (a loop shorter than the horizon) is not taken for where the robot is.
LOCATE_REACH = 1.0


@dataclass(frozen=True)
class ControlSettings:
    """rate_hz: control rate; pose_timeout: age [s] after which a pose is stale; lookahead: horizon [s]
    of the velocity feed-forward taken from the plan; plan_timeout: age [s] after which a plan is stale."""

    rate_hz: float = 100.0
    pose_timeout: float = 0.5
    lookahead: float = 0.2
    plan_timeout: float = 1.0
    stall_s: float = 0.25  # [s] a gap between ticks longer than this resynchronises the stream with the device
    tracking_error: TrackingErrorSettings = field(default_factory=TrackingErrorSettings)


@dataclass(frozen=True)
class TickResult:
    """What one tick decided: ``mode`` (WAITING, TRACKING, HOLDING, LINK_DOWN, FAULT, TRACKING_ERROR or PARKING);
    ``setpoint`` (pan, tilt, pan_rate, tilt_rate) [rad, rad/s] when one was sent."""

    mode: DaemonState
    setpoint: tuple[float, float, float, float] | None = None
    clamped: bool = False


@dataclass
class ControlStats:
    """Rolling statistics of the loop (latency of a new pose to its first setpoint [s])."""

    ticks: int = 0
    setpoints: int = 0
    clamped: int = 0
    pose_latency: deque = field(default_factory=lambda: deque(maxlen=2000))


class ControlLoop:
    """Turns plan + pose into setpoints for ``link``. ``clock`` is the monotonic clock [s] that pose and plan
    times (``rx_time``, ``created``) come from; tests pass a fake one."""

    def __init__(self, settings: ControlSettings, motion: MotionGenerator, mount: Mount, limits: JointLimits,
                 link: GimbalInterface, clock: Callable[[], float] = time.monotonic) -> None:
        self.settings = settings
        self.motion = motion
        self.mount = mount
        self.limits = limits
        self.link = link
        self.clock = clock
        self.stats = ControlStats()
        self.commanded_direction: np.ndarray | None = None  # world direction of the last setpoint
        self.commanded_joints: tuple[float, float] | None = None  # (pan, tilt) [rad] of the last setpoint sent
        self.override_target: tuple[float, float] | None = None  # e.g. the park pose
        self._need_reset = True
        self._hard_reset = True  # the device did not follow the stream: restart even if it now follows again
        self._reset_after = -np.inf  # a restart needs a state measured at or after this time [s]
        self._seen_mode: int | None = None  # device mode in the newest state seen by a tick
        self._seen_faults = 0  # its fault bits
        self._seen_rx = -np.inf  # its receive time [s]
        self._last_tick: float | None = None
        self._segment_first: int | None = None  # seq of the first setpoint since the last restart
        self._last_send: float | None = None  # clock() when the previous setpoint of this stream was sent [s]
        self._last_sample: MotionSample | None = None  # the last setpoint sent since the last restart
        self.tracking = TrackingErrorSupervisor(settings.tracking_error)
        self._judged_rx = -np.inf  # receive time of the newest state the tracking supervisor judged [s]
        self.restarts = 0  # restarts of the stream from a measured state
        self._last_pose_rx: float | None = None
        self._prev_pose: PoseSample | None = None
        self._speed = 0.0
        self._turn = np.zeros(3)  # [rad/s] the body's estimated angular velocity, world frame
        self._located: tuple[int, float, np.ndarray] | None = None  # (path version, arc length [m], camera
        # position (3,) [m]) where the camera was last located on a plan

    def invalidate(self) -> None:
        """Restart the stream from a state measured from now on, unless the device kept following it (see the
        module docstring); the daemon calls this after it re-enabled the gimbal or cleared a fault."""
        self._request_reset(self.clock(), hard=False)

    def _request_reset(self, after: float, hard: bool) -> None:
        if not self._need_reset:
            self._reset_after = after
        else:
            self._reset_after = max(self._reset_after, after)
        self._need_reset = True
        self._hard_reset = self._hard_reset or hard

    def _reset_from(self, state: GimbalState, now: float) -> None:
        """Restart the generator at the measured state, advanced to ``now`` when the device was moving on its own."""
        pos = np.array([state.pan, state.tilt])
        rate = np.array([state.pan_rate, state.tilt_rate])
        if state.mode == GimbalMode.ENABLED:
            pos = pos + rate * float(np.clip(now - state.measured_time, 0.0, self.settings.stall_s))
        self.motion.reset(pos, rate)
        self._need_reset = self._hard_reset = False
        self._segment_first = self._last_send = self._last_sample = None
        self.tracking.restart()
        self.restarts += 1

    def _continue_stream(self) -> None:
        """The device kept following the last setpoint it got: continue the stream from that setpoint."""
        last = self._last_sample
        if last is not None and not np.array_equal(self.motion.state.position, last.position):
            self.motion.reset(last.position, last.velocity, last.acceleration)  # a computed one was not sent
        self._need_reset = False
        self._last_send = None  # the gap is over: the device still follows

    def _hold_axes_at_measured(self, state: GimbalState, axes: tuple[int, ...]) -> None:
        """Tracking-error hold: ``axes`` (standing still) restart from their measured state, the others go on from
        the last setpoint (the device follows them); the tick then brakes and holds."""
        cur = self._last_sample or self.motion.state
        pos, vel, acc = cur.position.copy(), cur.velocity.copy(), cur.acceleration.copy()
        measured = ((state.pan, state.pan_rate), (state.tilt, state.tilt_rate))
        for i in axes:
            pos[i], vel[i] = measured[i]
            acc[i] = 0.0
        self.motion.reset(pos, vel, acc)
        self._last_sample = None
        self.tracking.restart()

    def _held_on_this_stream(self, state: GimbalState) -> bool:
        """Whether a HOLDING ``state`` shows the device stopped while following the current stream: it echoes a
        setpoint of this stream (seq on the wire, modulo 256), or none of this stream was sent yet."""
        if self._segment_first is None:
            return True
        return (state.last_setpoint_seq - self._segment_first) & 0xFF < 0x80

    def _resynchronise(self, now: float, state: GimbalState, gap: float) -> bool:
        """Restart or continue the stream after an interruption (see the module docstring); False while a state
        measured after it is still missing. ``gap``: time since the previous tick [s]."""
        if gap > self.settings.stall_s:
            log.info("control loop stalled for %.3f s: resynchronising the setpoint stream with the device", gap)
            self._request_reset(now, hard=False)  # the device may have held meanwhile: its next state tells
        if state.rx_time > self._seen_rx:
            watchdog_edge = bool(state.faults & FAULT_WATCHDOG) and not self._seen_faults & FAULT_WATCHDOG
            hold_edge = state.mode == GimbalMode.HOLDING and self._seen_mode == GimbalMode.ENABLED
            # A watchdog bit that latched while the device reports it follows (ENABLED: a hold shorter than a state
            # period, resumed by the stream's next setpoint, or a bit latched without a hold) is not a stop: the
            # device executes the stream, and a restart from its measured state would step by its tracking lag.
            stopped = hold_edge or (watchdog_edge and state.mode != GimbalMode.ENABLED)
            if stopped and self._held_on_this_stream(state):
                # Its watchdog stopped it: restart once, from this state. Later states of the same hold were
                # sent before the device got the restarted stream (which resumes it) and are not followed.
                self._request_reset(state.measured_time, hard=True)
            self._seen_mode, self._seen_faults, self._seen_rx = state.mode, state.faults, state.rx_time
        if not self._need_reset:
            return True
        if state.measured_time < self._reset_after:
            return False
        if not self._hard_reset and self._last_sample is not None and state.mode == GimbalMode.ENABLED:
            self._continue_stream()  # the device followed the stream all along: keep it continuous
            return True
        self._reset_from(state, now)
        return True

    def _estimate_motion(self, pose: PoseSample) -> None:
        """Update the robot's speed [m/s] and angular velocity [rad/s] (world frame) from ``pose`` and the one
        before it (stamps' difference, else the arrival times'), each smoothed over the last poses."""
        prev = self._prev_pose
        if prev is not None and pose.rx_time > prev.rx_time:
            dt = pose.stamp - prev.stamp if pose.stamp > prev.stamp else pose.rx_time - prev.rx_time
            if dt > 1e-4:
                v = float(np.linalg.norm(pose.position - prev.position)) / dt
                self._speed += 0.3 * (min(v, 10.0) - self._speed)
                turn = so3_log(quat_to_matrix(pose.quat) @ quat_to_matrix(prev.quat).T) / dt
                if np.all(np.isfinite(turn)) and np.linalg.norm(turn) <= MAX_TURN_RATE:
                    self._turn += 0.3 * (turn - self._turn)
        self._prev_pose = pose

    def reconfigure(self, settings: ControlSettings, mount: Mount) -> None:
        """Use ``settings`` and ``mount`` from the next tick on (a reload; the planner gets the same mount).
        ``settings.rate_hz`` must stay: the motion generator runs at the rate it was built for."""
        if settings.rate_hz != self.settings.rate_hz:
            raise ValueError("the control rate cannot change while running")
        self.settings = settings
        self.tracking.settings = settings.tracking_error
        self.mount = mount

    def _locate(self, plan: Plan, cam: np.ndarray) -> float:
        """Arc length [m] of the camera at ``cam`` (3,) [m] on ``plan``: the nearest point of the plan's stretch
        within :data:`LOCATE_REACH` of where it was located last on the same path (or of the plan's start), reaching
        on by the distance the camera has moved since, unless the camera is nearer another stretch by more than
        that reach (it is elsewhere: a test's plan, a jump of the pose)."""
        last = self._located
        base = float(plan.s[0])
        moved = 0.0
        if last is not None and last[0] == plan.path_version:
            base = max(base, last[1])
            moved = float(np.linalg.norm(cam - last[2]))
        s, distance = plan.locate(cam, (base - LOCATE_REACH, base + LOCATE_REACH + moved))
        if distance > LOCATE_REACH:  # only then can another stretch be nearer by more than the reach
            s_any, distance_any = plan.locate(cam)
            if distance_any < distance - LOCATE_REACH:
                s = s_any
        self._located = (plan.path_version, s, cam)
        return s

    def _target(self, pose: PoseSample, plan: Plan, mount: Mount) -> tuple[np.ndarray, np.ndarray, bool]:
        """Joint target (2,) [rad] and feed-forward rate (2,) [rad/s] from the plan, and a clamped flag.

        The rate is the finite difference of the joint angles over half the lookahead along the plan ahead of
        the robot, at its estimated speed, with the body attitude carried on by the path's turn over that stretch
        (the plan's predicted attitudes: a corner is met as it comes), or at the robot's estimated angular velocity
        while it turns in place (a body turning under a view held in the world needs the pan to turn the other
        way). No acceleration is fed forward: the plan is piecewise linear between waypoints, so its second difference
        is a train of spikes at the waypoints and replans, beyond the axes' limits, that would only tell the
        motion generator the reference cannot be followed and scale its rate feed-forward away.
        """
        cam = camera_positions(pose.position[None, :], pose.quat[None, :], mount)[0]
        s = self._locate(plan, cam)
        prev_pan = float(self.motion.state.position[0])
        if plan.pans is not None and plan.s.shape[0] > 1:  # the branch the planner chose over its horizon
            prev_pan = float(np.interp(s, plan.s, plan.pans))
        pan, tilt, clamped = world_direction_to_joints(plan.direction_at_s(s), pose.quat, mount, self.limits,
                                                       prev_pan)
        target = np.array([pan, tilt])
        rate = np.zeros(2)
        h = 0.5 * self.settings.lookahead
        moving = plan.s.shape[0] > 1 and self._speed > 0.02
        turning = float(np.linalg.norm(self._turn)) > TURN_RATE_FLOOR
        if (moving or turning) and h > 0 and not clamped:
            s_ahead = s + (self._speed * h if moving else 0.0)
            ahead = plan.direction_at_s(s_ahead)
            # the body turned on by a rotation T sees a world direction d as the body now sees Tᵀ d; moving along
            # the path, T is the path's own turn over the lookahead (a corner is met as it comes, not after the
            # smoothed measured rate has caught up with it); turning in place, exp(ωh) at the measured rate
            turn = plan.body_turn(s, s_ahead) if moving else so3_exp(h * self._turn)
            ahead = turn.T @ ahead
            p2, t2, c2 = world_direction_to_joints(ahead, pose.quat, mount, self.limits, pan)
            if not c2:
                rate = (np.array([p2, t2]) - target) / h
        return target, rate, clamped

    def tick(self, now: float, pose: PoseSample | None, plan: Plan | None, faulted: bool = False) -> TickResult:
        """One control period at monotonic time ``now`` [s]."""
        self.stats.ticks += 1
        mount = self.mount  # one mount for the whole tick, even if a reload swaps it meanwhile
        link_state = self.link.link_state
        state = self.link.state
        gap = 0.0 if self._last_tick is None else now - self._last_tick
        self._last_tick = now
        if link_state != LinkState.UP or state is None:
            self._request_reset(now, hard=True)
            return TickResult(DaemonState.LINK_DOWN)
        if faulted or state.mode == GimbalMode.FAULT:
            # No motion while faulted; keep the watchdog fed so the fault, not a link loss, is reported.
            self._request_reset(now, hard=True)
            self.link.send_heartbeat()
            return TickResult(DaemonState.FAULT)
        if state.mode == GimbalMode.DISABLED:
            # The device ignores setpoints until the daemon enables it; the stream then starts where it stands.
            self._request_reset(now, hard=True)
            self._seen_mode, self._seen_faults, self._seen_rx = state.mode, state.faults, state.rx_time
            self.link.send_heartbeat()
            return TickResult(DaemonState.HOLDING)
        if not self._resynchronise(now, state, gap):
            # Waiting (at most a state period) for a state measured after the interruption.
            self.link.send_heartbeat()
            return TickResult(DaemonState.HOLDING)

        if state.rx_time > self._judged_rx:
            self._judged_rx = state.rx_time
            verdict = self.tracking.judge(now, state.measured_time, state.pan, state.tilt, state.pan_rate,
                                          state.tilt_rate)
            if verdict.entered_fault:
                self._hold_axes_at_measured(state, verdict.restart)

        clamped = False
        if self.tracking.state is TrackingState.FAULT:
            self.motion.hold()  # no motion towards the target while an axis does not follow
            mode = DaemonState.TRACKING_ERROR
        elif self.override_target is not None:
            self.motion.set_target(np.asarray(self.override_target, float), np.zeros(2))
            mode = DaemonState.PARKING
        elif pose is None:
            self.motion.hold()
            mode = DaemonState.WAITING
        elif (now - pose.rx_time > self.settings.pose_timeout or plan is None
              or now - plan.created > self.settings.plan_timeout):
            self.motion.hold()
            mode = DaemonState.HOLDING
        else:
            self._estimate_motion(pose)
            target, rate, clamped = self._target(pose, plan, mount)
            self.motion.set_target(target, rate)
            mode = DaemonState.TRACKING

        sample = self.motion.step()
        pan, tilt = float(sample.position[0]), float(sample.position[1])
        vp, vt = float(sample.velocity[0]), float(sample.velocity[1])
        sent_at = self.clock()
        if self._last_send is not None and sent_at - self._last_send > self.settings.stall_s:
            # Held up between computing and sending: the device may have held meanwhile, and this setpoint would
            # resume it with the old stream. Drop it; a state measured from now on tells whether the stream goes on
            # from the last setpoint sent (the device followed it) or restarts from the measured state.
            log.info("control tick held up for %.3f s before sending: resynchronising the setpoint stream",
                     sent_at - self._last_send)
            self._request_reset(sent_at, hard=False)
            self.link.send_heartbeat()
            return TickResult(DaemonState.HOLDING)
        seq = self.link.send_setpoint(pan, tilt, vp, vt)
        if seq is None:
            # Not sent (the device went silent, or the link's queue is full). Wait for a state the device measures
            # after it answers again: if it held meanwhile the stream restarts from there, else it continues from
            # the last setpoint the device got (this computed one is dropped), as after a stall of the loop.
            self._request_reset(sent_at, hard=False)
            return TickResult(DaemonState.HOLDING)
        self._last_send = sent_at
        self._last_sample = sample
        self.commanded_joints = (pan, tilt)
        self.tracking.commanded(sent_at, pan, tilt, vp, vt)
        if self._segment_first is None:
            self._segment_first = seq
        self.stats.setpoints += 1
        self.stats.clamped += int(clamped)
        if pose is not None:
            if mode == DaemonState.TRACKING and pose.rx_time != self._last_pose_rx:
                self.stats.pose_latency.append(self.clock() - pose.rx_time)
                self._last_pose_rx = pose.rx_time
            self.commanded_direction = joints_to_world_direction(pan, tilt, pose.quat, mount)
        if self.tracking.state is not TrackingState.OK and mode == DaemonState.TRACKING:
            mode = DaemonState.TRACKING_ERROR  # recovering: reported until the axes follow again
        return TickResult(mode, (pan, tilt, vp, vt), clamped)
