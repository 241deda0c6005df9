"""Jerk-limited pan/tilt setpoint generation with Ruckig (Community), inside the joint limits.

:class:`MotionGenerator` turns targets (position and velocity feed-forward, updated at any rate) into a
setpoint stream at a constant control period ``dt``. Each (re)target computes one time-optimal Ruckig
trajectory from the current position, velocity and acceleration; :meth:`MotionGenerator.step` samples it
at the next multiple of ``dt``. After a trajectory ends, Ruckig continues at the target velocity, so a
consistent moving target (position advancing at its own velocity) needs no retargeting at all.

Ruckig Community ignores position limits, so they are enforced here:

1. targets are clamped into the limits; a feed-forward velocity pointing out of a limit is dropped;
2. a candidate trajectory whose position extrema leave the limits, or whose end state could not brake
   inside them, is retried with a smaller target velocity, then without time synchronization;
3. every step checks that a jerk-limited brake from the next setpoint stays inside the limits; if it would
   not, the generator brakes from the current (still safe) setpoint instead and re-plans once stopped;
4. a final guard clamps positions (only reachable from an unsafe measured state, e.g. after :meth:`reset`
   with a velocity that cannot stop before a limit; it is counted in :attr:`MotionGenerator.guard_clamps`).

Axes are (pan, tilt); all values in rad, rad/s, rad/s², rad/s³. With ``continuous_pan`` only tilt is bounded.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

from pivotd.gimbal.kinematics import JointLimits

log = logging.getLogger(__name__)

_POS_TOL = 1e-9  # [rad] numerical slack on position limits
_OK = (Result.Working, Result.Finished)
_INTERCEPT_ITERATIONS = 12
_VELOCITY_SCALES = (1.0, 0.5, 0.25, 0.0)


@dataclass(frozen=True)
class AxisLimits:
    """Kinematic limits of one axis: rad/s, rad/s², rad/s³ (all > 0)."""

    max_velocity: float
    max_acceleration: float
    max_jerk: float

    def __post_init__(self) -> None:
        for name in ("max_velocity", "max_acceleration", "max_jerk"):
            value = getattr(self, name)
            if not (np.isfinite(value) and value > 0):
                raise ValueError(f"AxisLimits.{name} must be finite and > 0, got {value!r}")


@dataclass(frozen=True)
class MotionSample:
    """Setpoint state [pan, tilt]: position (2,) [rad], velocity (2,) [rad/s], acceleration (2,) [rad/s²]."""

    position: np.ndarray
    velocity: np.ndarray
    acceleration: np.ndarray


class MotionGenerator:
    """Ruckig setpoint generator for a pan/tilt gimbal at a constant control period ``dt`` [s].

    ``deadband`` [rad]: a new target closer than this (per axis) to where the active target has moved by
    now is ignored, as is a velocity change below ``velocity_deadband`` [rad/s] (default: ``deadband``/s),
    so that noisy targets do not cause a re-plan every cycle.
    """

    def __init__(
        self,
        dt: float,
        pan: AxisLimits,
        tilt: AxisLimits,
        limits: JointLimits,
        deadband: float = 1e-3,
        velocity_deadband: float | None = None,
    ) -> None:
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0, got {dt!r}")
        self.dt = float(dt)
        self.deadband = float(deadband)
        self.velocity_deadband = float(deadband if velocity_deadband is None else velocity_deadband)
        self.limits = limits
        self._vmax = np.array([pan.max_velocity, tilt.max_velocity])
        self._amax = np.array([pan.max_acceleration, tilt.max_acceleration])
        self._jmax = np.array([pan.max_jerk, tilt.max_jerk])
        pan_lo, pan_hi = (-np.inf, np.inf) if limits.continuous_pan else (limits.pan_min, limits.pan_max)
        self._lo = np.array([pan_lo, limits.tilt_min], dtype=float)
        self._hi = np.array([pan_hi, limits.tilt_max], dtype=float)
        self._otg = Ruckig(2, self.dt)
        self._p = np.zeros(2)
        self._v = np.zeros(2)
        self._a = np.zeros(2)
        self._traj: Trajectory | None = None
        self._t = 0.0  # time into the active trajectory [s], a multiple of dt
        self._clock = 0.0  # generator time [s]
        self._target: tuple[np.ndarray, np.ndarray] | None = None  # requested (position, velocity)
        self._target_clock = 0.0
        self._braking = False  # emergency brake before a limit; re-plan to the target once stopped
        self.replans = 0  # trajectories computed for targets (a measure of retargeting chatter)
        self.limit_brakes = 0  # times a step had to brake to stay inside the position limits
        self.guard_clamps = 0  # times the final guard had to clamp a position (unsafe measured state)
        self.reset(np.clip(np.zeros(2), self._lo, self._hi))

    # ------------------------------------------------------------------ public API
    @property
    def state(self) -> MotionSample:
        """The current setpoint (copy)."""
        return MotionSample(self._p.copy(), self._v.copy(), self._a.copy())

    @property
    def target(self) -> tuple[np.ndarray, np.ndarray] | None:
        """The active requested target (position (2,), velocity (2,)) advanced to now, or None when holding."""
        if self._target is None:
            return None
        p, v = self._target
        return np.clip(p + v * (self._clock - self._target_clock), self._lo, self._hi), v.copy()

    @property
    def settled(self) -> bool:
        """True when the active trajectory has ended (at rest, or coasting at the target velocity)."""
        return self._traj is None or self._t >= self._traj.duration - 1e-12

    def reset(self, position, velocity=(0.0, 0.0), acceleration=(0.0, 0.0)) -> None:
        """Restart from a (measured) state; a moving state is braked until the next :meth:`set_target`."""
        p = np.asarray(position, dtype=float).reshape(2)
        v = np.asarray(velocity, dtype=float).reshape(2)
        a = np.asarray(acceleration, dtype=float).reshape(2)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
            raise ValueError("reset state must be finite")
        clipped = np.clip(p, self._lo, self._hi)
        if np.any(np.abs(clipped - p) > _POS_TOL):
            log.warning("measured gimbal position %s is outside the joint limits; clamped", p)
        self._p, self._v, self._a = clipped, v.copy(), a.copy()
        self._target = None
        self._braking = False
        self._traj = None
        self._t = 0.0
        if np.any(v != 0.0) or np.any(a != 0.0):
            self._start_brake()

    def set_target(self, position, velocity=(0.0, 0.0)) -> None:
        """Track ``position`` (2,) [rad] arriving with ``velocity`` (2,) [rad/s] (feed-forward).

        The position is clamped into the limits and the velocity to the axis limits; a change inside the
        deadband of the active (moving) target is ignored.
        """
        p = np.asarray(position, dtype=float).reshape(2)
        v = np.asarray(velocity, dtype=float).reshape(2)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v))):
            raise ValueError("target must be finite")
        p = np.clip(p, self._lo, self._hi)
        v = np.clip(v, -self._vmax, self._vmax)
        current = self.target
        if current is not None:
            cp, cv = current
            if np.all(np.abs(p - cp) <= self.deadband) and np.all(np.abs(v - cv) <= self.velocity_deadband):
                return
        self._target = (p, v)
        self._target_clock = self._clock
        if not self._braking:
            self._plan_to_target()

    def hold(self) -> None:
        """Jerk-limited stop: velocity 0 as fast as possible, then hold that position."""
        self._target = None
        self._braking = False
        self._start_brake()

    def step(self) -> MotionSample:
        """Advance exactly one control period and return the new setpoint."""
        if self._traj is None:
            self._clock += self.dt
            return self.state
        t_next = self._t + self.dt
        p, v, a = self._sample(self._traj, t_next)
        if not self._brake_stays_inside(p, v, a):
            self.limit_brakes += 1
            self._start_brake(keep_target=True)
            t_next = self.dt
            p, v, a = self._sample(self._traj, t_next)
        clipped = np.clip(p, self._lo, self._hi)
        if np.any(np.abs(clipped - p) > _POS_TOL):
            self.guard_clamps += 1
            log.warning("setpoint %s clamped into the joint limits", p)
            hit = np.abs(clipped - p) > _POS_TOL
            v[hit] = 0.0
            a[hit] = 0.0
        self._p, self._v, self._a = clipped, v, a
        self._t = t_next
        self._clock += self.dt
        if self._braking and self._t >= self._traj.duration - 1e-12:
            self._braking = False
            if self._target is not None:
                self._plan_to_target()
        return self.state

    # ------------------------------------------------------------------ internals
    def _input(self, sync: Synchronization) -> InputParameter:
        inp = InputParameter(2)
        inp.current_position = self._p.tolist()
        inp.current_velocity = self._v.tolist()
        inp.current_acceleration = self._a.tolist()
        inp.max_velocity = self._vmax.tolist()
        inp.max_acceleration = self._amax.tolist()
        inp.max_jerk = self._jmax.tolist()
        inp.synchronization = sync
        return inp

    def _calculate(self, inp: InputParameter) -> Trajectory | None:
        traj = Trajectory(2)  # always fresh: a reused Trajectory may report stale extrema
        result = self._otg.calculate(inp, traj)
        return traj if result in _OK else None

    @staticmethod
    def _sample(traj: Trajectory, t: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        p, v, a = traj.at_time(t)
        return np.array(p), np.array(v), np.array(a)

    def _inside(self, traj: Trajectory) -> bool:
        for axis, bound in enumerate(traj.position_extrema):
            if bound.min < self._lo[axis] - _POS_TOL or bound.max > self._hi[axis] + _POS_TOL:
                return False
        return True

    def _brake_trajectory(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> Trajectory | None:
        inp = InputParameter(2)
        inp.current_position = p.tolist()
        inp.current_velocity = v.tolist()
        inp.current_acceleration = a.tolist()
        inp.max_velocity = self._vmax.tolist()
        inp.max_acceleration = self._amax.tolist()
        inp.max_jerk = self._jmax.tolist()
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.target_velocity = [0.0, 0.0]
        inp.target_acceleration = [0.0, 0.0]
        return self._calculate(inp)

    def _brake_stays_inside(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> bool:
        """Whether the fastest jerk-limited stop from state (p, v, a) stays inside the position limits."""
        if np.any(p < self._lo - _POS_TOL) or np.any(p > self._hi + _POS_TOL):
            return False
        if not (np.any(v != 0.0) or np.any(a != 0.0)):
            return True
        brake = self._brake_trajectory(p, v, a)
        return brake is not None and self._inside(brake)

    def _start_brake(self, keep_target: bool = False) -> None:
        traj = self._brake_trajectory(self._p, self._v, self._a)
        if traj is None:  # cannot happen for finite states with positive limits; stop dead as a last resort
            log.error("brake trajectory failed from %s %s %s; stopping", self._p, self._v, self._a)
            self._v[:] = 0.0
            self._a[:] = 0.0
            self._traj = None
            return
        self._traj = traj
        self._t = 0.0
        self._braking = keep_target and self._target is not None

    def _intercept(self, p: np.ndarray, v: np.ndarray, sync: Synchronization) -> tuple[np.ndarray, np.ndarray]:
        """Target state on the moving target's line p + v·T that the trajectory reaches at its end T.

        Solves g(T) = duration(goal(T)) − T = 0 by the secant method (fixed-point steps as a fallback);
        where the line leaves the joint range the goal is clamped and its velocity dropped.
        """
        if not np.any(v != 0.0):
            return p, v

        def goal(T: float) -> tuple[np.ndarray, np.ndarray]:
            line = p + v * T
            gp = np.clip(line, self._lo, self._hi)
            return gp, np.where(gp != line, 0.0, v)

        def g(T: float) -> float | None:
            traj = self._calculate(self._position_input(*goal(T), sync))
            return None if traj is None else traj.duration - T

        T0, g0 = 0.0, g(0.0)
        if g0 is None:
            return goal(0.0)
        T1 = T0 + g0
        for _ in range(_INTERCEPT_ITERATIONS):
            g1 = g(T1)
            if g1 is None:
                break
            if abs(g1) < 1e-9:
                break
            slope = (g1 - g0) / (T1 - T0) if T1 != T0 else 0.0
            T_next = T1 - g1 / slope if slope != 0.0 else T1 + g1
            if not np.isfinite(T_next) or T_next < 0.0:
                T_next = T1 + g1
            T0, g0, T1 = T1, g1, T_next
        return goal(T1)

    def _position_input(self, p: np.ndarray, v: np.ndarray, sync: Synchronization) -> InputParameter:
        inp = self._input(sync)
        inp.target_position = p.tolist()
        inp.target_velocity = v.tolist()
        inp.target_acceleration = [0.0, 0.0]
        return inp

    def _plan_to_target(self) -> None:
        assert self._target is not None
        req_p, req_v = self._target
        req_p = np.clip(req_p + req_v * (self._clock - self._target_clock), self._lo, self._hi)
        # A feed-forward velocity pointing out of a limit the target sits on is dropped.
        req_v = np.where(((req_p <= self._lo) & (req_v < 0)) | ((req_p >= self._hi) & (req_v > 0)), 0.0, req_v)
        self.replans += 1
        fallback: Trajectory | None = None
        for sync in (Synchronization.Time, Synchronization.No):
            for scale in _VELOCITY_SCALES:
                goal_p, goal_v = self._intercept(req_p, req_v * scale, sync)
                traj = self._calculate(self._position_input(goal_p, goal_v, sync))
                if traj is None:
                    continue
                fallback = fallback or traj
                end_ok = not np.any(goal_v != 0.0) or self._brake_stays_inside(goal_p, goal_v, np.zeros(2))
                if end_ok and self._inside(traj):
                    self._traj, self._t = traj, 0.0
                    return
                if not np.any(req_v != 0.0):
                    break  # scaling a zero velocity changes nothing
        if fallback is None:
            log.warning("no trajectory to target %s; holding", req_p)
            self._start_brake(keep_target=False)
            return
        # The current state cannot avoid the limits' neighbourhood on the way; step() brakes in time.
        self._traj, self._t = fallback, 0.0
