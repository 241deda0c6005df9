"""Jerk-limited pan/tilt setpoint generation with Ruckig (Community), inside the joint limits.

:class:`MotionGenerator` turns targets (position with velocity and acceleration feed-forward, updated at any
rate) into a setpoint stream at a constant control period ``dt``; :meth:`MotionGenerator.step` samples a
Ruckig trajectory (axes independent: pan and tilt are separate motors) at the next multiple of ``dt``,
always starting from the current position, velocity and acceleration. Two modes:

- **position** (target at rest): one time-optimal trajectory to the target, re-planned only when the
  target moves by more than the deadband (no re-planning chatter from noisy targets); exact arrival.
- **tracking** (target moving): every step, Ruckig's velocity interface heads for
  v_cmd = v_ff + a_ff·|a_ff|/2j + feedback(error) with zero acceleration at arrival, where
  feedback = min(gain·|e|, √(a_max·|e|)) (the second term is a braking curve at half the acceleration
  limit, so large errors close without overshoot) and the middle term leads by the velocity an
  acceleration adds while it is removed at full jerk. Constant-velocity targets are followed without
  steady-state error, curved ones with a small lag and smooth jerk. Between target updates the target is
  extrapolated (its acceleration for at most ``ACCELERATION_HORIZON_S``), so targets may arrive at the
  plan rate. Ruckig's velocity interface ignores max_velocity, so v_cmd is clipped and an acceleration
  that would carry the velocity past the limit is removed at full jerk.

Ruckig Community ignores position limits, so they are enforced here:

1. targets are clamped into the limits; feed-forward pointing out of a limit the target sits on is dropped;
2. every step checks that the fastest jerk-limited stop from the next setpoint stays inside the limits
   (position extrema of Ruckig's braking trajectory); if it would not, the generator brakes from the current
   setpoint (which passed the same check) instead and resumes the target once stopped;
3. a final guard clamps positions (reachable only from an unsafe measured state given to :meth:`reset`,
   one that cannot stop before a limit; counted in :attr:`MotionGenerator.guard_clamps`).

Axes are (pan, tilt); all values in rad, rad/s, rad/s², rad/s³. With ``continuous_pan`` only tilt is bounded.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from ruckig import ControlInterface, InputParameter, Result, Ruckig, Synchronization, Trajectory

from pivotd.gimbal.kinematics import JointLimits

log = logging.getLogger(__name__)

ACCELERATION_HORIZON_S = 0.3  # [s] how far a target's acceleration is extrapolated (then constant velocity)
DEFAULT_GAIN = 5.0  # [1/s] position feedback of the tracking mode (time constant 0.2 s)
_FF_POWER = 2.0  # feed-forward scale = feasibility ** _FF_POWER
_FEASIBILITY_TAU_S = 1.0  # [s] recovery time constant of the feasibility estimate (drops are immediate)
_POS_TOL = 1e-9  # [rad] numerical slack on position limits
_OK = (Result.Working, Result.Finished)

State = tuple[np.ndarray, np.ndarray, np.ndarray]  # position, velocity, acceleration, each (2,)


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

    ``deadband`` [rad]: a rest target within ``deadband`` (per axis) of the active rest target is ignored,
    so a noisy target does not re-plan every cycle. Moving targets are always taken (tracking follows them
    continuously; a deadband would only add reference error). ``gain`` [1/s]: tracking feedback, capped
    per axis at 0.8·j_max/a_max for stability. Feed-forward is scaled down while the reference (judged from
    successive targets) accelerates or jerks beyond the axis limits, so an unfollowable reference is damped
    rather than amplified. Counters for status: ``replans``, ``limit_brakes``, ``guard_clamps``.
    """

    def __init__(
        self,
        dt: float,
        pan: AxisLimits,
        tilt: AxisLimits,
        limits: JointLimits,
        deadband: float = 1e-3,
        gain: float = DEFAULT_GAIN,
    ) -> None:
        if not (np.isfinite(dt) and dt > 0):
            raise ValueError(f"dt must be > 0, got {dt!r}")
        self.dt = float(dt)
        self.deadband = float(deadband)
        if not (np.isfinite(gain) and gain > 0):
            raise ValueError(f"gain must be > 0, got {gain!r}")
        self.gain = float(gain)
        self.limits = limits
        self._vmax = np.array([pan.max_velocity, tilt.max_velocity])
        self._amax = np.array([pan.max_acceleration, tilt.max_acceleration])
        self._jmax = np.array([pan.max_jerk, tilt.max_jerk])
        # Loop stability needs the feedback slower than the jerk-limited acceleration response (≈ a/j).
        self._gain = np.minimum(self.gain, 0.8 * self._jmax / self._amax)
        self._feasibility = np.ones(2)  # smoothed share of the reference's motion the axes can follow
        self._ref_acceleration: np.ndarray | None = None
        self._ref_clock = 0.0
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
        self._target: State | None = None  # requested target state at _target_clock
        self._target_clock = 0.0
        self._braking = False  # braking before a limit; re-plan to the target once stopped
        self.replans = 0  # targets accepted (outside the deadband): a measure of retargeting chatter
        self.limit_brakes = 0  # times a step had to brake to stay inside the position limits
        self.guard_clamps = 0  # times the final guard had to clamp a position (unsafe measured state)
        self.reset(np.clip(np.zeros(2), self._lo, self._hi))

    # ------------------------------------------------------------------ public API
    @property
    def state(self) -> MotionSample:
        """The current setpoint (copy)."""
        return MotionSample(self._p.copy(), self._v.copy(), self._a.copy())

    @property
    def target(self) -> State | None:
        """The active target (position, velocity, acceleration; each (2,)) advanced to now, or None when holding."""
        if self._target is None:
            return None
        return self._extrapolate(*self._target, self._clock - self._target_clock)

    @property
    def settled(self) -> bool:
        """True when at rest on a reached position target (or holding still)."""
        at_end = self._traj is None or self._t >= self._traj.duration - 1e-12
        return at_end and not self._tracking() and bool(np.all(np.abs(self._v) < 1e-9))

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

    def set_target(self, position, velocity=(0.0, 0.0), acceleration=(0.0, 0.0)) -> None:
        """Track ``position`` (2,) [rad] moving with ``velocity`` (2,) [rad/s] and ``acceleration`` (2,) [rad/s²].

        Velocity and acceleration are feed-forward: pass the plan's derivatives for tight tracking of a
        curved plan. The position is clamped into the limits, velocity and acceleration to the axis limits.
        """
        p = np.asarray(position, dtype=float).reshape(2)
        v = np.asarray(velocity, dtype=float).reshape(2)
        a = np.asarray(acceleration, dtype=float).reshape(2)
        if not (np.all(np.isfinite(p)) and np.all(np.isfinite(v)) and np.all(np.isfinite(a))):
            raise ValueError("target must be finite")
        self._update_feasibility(a)
        new = self._extrapolate(p, np.clip(v, -self._vmax, self._vmax), np.clip(a, -self._amax, self._amax), 0.0)
        at_rest = not (np.any(new[1] != 0.0) or np.any(new[2] != 0.0))
        resting = self._target is not None and not self._tracking()
        if at_rest and resting and np.all(np.abs(new[0] - self._target[0]) <= self.deadband):
            return
        self._target = new
        self._target_clock = self._clock
        self.replans += 1
        if not self._braking and not self._tracking():
            self._plan_to_target()

    def hold(self) -> None:
        """Jerk-limited stop: velocity 0 as fast as possible, then hold that position."""
        self._target = None
        self._braking = False
        self._start_brake()

    def step(self) -> MotionSample:
        """Advance exactly one control period and return the new setpoint."""
        if self._traj is None and not self._tracking():
            self._clock += self.dt
            return self.state
        if not self._braking and self._tracking():
            traj = self._tracking_trajectory()
            if traj is not None:
                self._traj, self._t = traj, 0.0
        if self._traj is None:
            self._clock += self.dt
            return self.state
        resting = not self._braking and not self._tracking() and self._t >= self._traj.duration
        if resting and self._traj_ends_at_rest():
            self._v[:] = 0.0  # at rest on the target: nothing to sample or check
            self._a[:] = 0.0
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
        hit = np.abs(clipped - p) > _POS_TOL
        if np.any(hit):
            self.guard_clamps += 1
            log.warning("setpoint %s clamped into the joint limits", p)
            v[hit] = 0.0
            a[hit] = 0.0
        self._p, self._v, self._a = clipped, v, a
        self._t = t_next
        self._clock += self.dt
        if self._braking and self._t >= self._traj.duration - 1e-12:
            self._braking = False
            if self._target is not None and not self._tracking():
                self._plan_to_target()
        return self.state

    # ------------------------------------------------------------------ target model
    def _traj_ends_at_rest(self) -> bool:
        _, v_end, a_end = self._sample(self._traj, self._traj.duration)
        return bool(np.all(np.abs(v_end) < 1e-12) and np.all(np.abs(a_end) < 1e-12))

    def _update_feasibility(self, a: np.ndarray) -> None:
        """Track how far the reference's acceleration and jerk (from successive targets) exceed the limits."""
        elapsed = self._clock - self._ref_clock
        if self._ref_acceleration is not None and elapsed > 0.0:
            jerk = np.abs(a - self._ref_acceleration) / elapsed
            ratio = np.minimum.reduce(
                [np.ones(2), self._amax / np.maximum(np.abs(a), 1e-12), self._jmax / np.maximum(jerk, 1e-12)]
            )
            w = min(1.0, elapsed / _FEASIBILITY_TAU_S)
            self._feasibility = np.minimum(ratio, self._feasibility + w * (ratio - self._feasibility))
        if self._ref_acceleration is None or elapsed > 0.0:
            self._ref_acceleration = a.copy()
            self._ref_clock = self._clock

    def _tracking(self) -> bool:
        if self._target is None:
            return False
        _, v, a = self._target
        return bool(np.any(v != 0.0) or np.any(a != 0.0))

    def _extrapolate(self, p: np.ndarray, v: np.ndarray, a: np.ndarray, tau) -> State:
        """A target state advanced by ``tau`` [s] (scalar or per axis (2,)).

        The acceleration acts for at most ACCELERATION_HORIZON_S and until the velocity limit, then the
        velocity stays constant; the position is clamped into the limits, where motion pointing outwards
        is dropped.
        """
        tau = np.broadcast_to(np.asarray(tau, dtype=float), p.shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            t_cap = np.where(a > 0, (self._vmax - v) / a, np.where(a < 0, (-self._vmax - v) / a, np.inf))
        t_acc = np.minimum(tau, np.minimum(np.maximum(t_cap, 0.0), ACCELERATION_HORIZON_S))
        v_end = np.clip(v + a * t_acc, -self._vmax, self._vmax)
        p_end = p + v * t_acc + 0.5 * a * t_acc**2 + v_end * (tau - t_acc)
        a_end = np.where(t_acc < tau, 0.0, a)
        clipped = np.clip(p_end, self._lo, self._hi)
        outwards_lo = (clipped <= self._lo) & ((v_end < 0) | ((v_end == 0) & (a_end < 0)))
        outwards_hi = (clipped >= self._hi) & ((v_end > 0) | ((v_end == 0) & (a_end > 0)))
        stop = (clipped != p_end) | outwards_lo | outwards_hi
        return clipped, np.where(stop, 0.0, v_end), np.where(stop, 0.0, a_end)

    # ------------------------------------------------------------------ Ruckig
    def _input(self) -> InputParameter:
        inp = InputParameter(2)
        inp.current_position = self._p.tolist()
        inp.current_velocity = self._v.tolist()
        inp.current_acceleration = self._a.tolist()
        inp.max_velocity = self._vmax.tolist()
        inp.max_acceleration = self._amax.tolist()
        inp.max_jerk = self._jmax.tolist()
        inp.synchronization = Synchronization.No
        return inp

    def _calculate(self, inp: InputParameter) -> Trajectory | None:
        traj = Trajectory(2)  # always fresh: a reused Trajectory may report stale extrema
        result = self._otg.calculate(inp, traj)
        return traj if result in _OK else None

    @staticmethod
    def _sample(traj: Trajectory, t: float) -> State:
        p, v, a = traj.at_time(t)
        return np.array(p), np.array(v), np.array(a)

    def _inside(self, traj: Trajectory) -> bool:
        for axis, bound in enumerate(traj.position_extrema):
            if bound.min < self._lo[axis] - _POS_TOL or bound.max > self._hi[axis] + _POS_TOL:
                return False
        return True

    def _velocity_trajectory(
        self, p: np.ndarray, v: np.ndarray, a: np.ndarray, v_goal: np.ndarray, a_goal: np.ndarray | None = None
    ) -> Trajectory | None:
        inp = InputParameter(2)
        inp.current_position = p.tolist()
        inp.current_velocity = v.tolist()
        inp.current_acceleration = a.tolist()
        inp.max_velocity = self._vmax.tolist()
        inp.max_acceleration = self._amax.tolist()
        inp.max_jerk = self._jmax.tolist()
        inp.control_interface = ControlInterface.Velocity
        inp.synchronization = Synchronization.No
        inp.target_velocity = v_goal.tolist()
        inp.target_acceleration = [0.0, 0.0] if a_goal is None else a_goal.tolist()
        return self._calculate(inp)

    def _brake_stays_inside(self, p: np.ndarray, v: np.ndarray, a: np.ndarray) -> bool:
        """Whether the fastest jerk-limited stop from state (p, v, a) stays inside the position limits."""
        if np.any(p < self._lo - _POS_TOL) or np.any(p > self._hi + _POS_TOL):
            return False
        if not (np.any(v != 0.0) or np.any(a != 0.0)):
            return True
        brake = self._velocity_trajectory(p, v, a, np.zeros(2))
        return brake is not None and self._inside(brake)

    def _start_brake(self, keep_target: bool = False) -> None:
        traj = self._velocity_trajectory(self._p, self._v, self._a, np.zeros(2))
        if traj is None:  # not expected for finite states and positive limits; stop dead as a last resort
            log.error("brake trajectory failed from %s %s %s; stopping", self._p, self._v, self._a)
            self._v[:] = 0.0
            self._a[:] = 0.0
            self._traj = None
            return
        self._traj, self._t = traj, 0.0
        self._braking = keep_target and self._target is not None

    def _position_trajectory(self, goal: State) -> Trajectory | None:
        inp = self._input()
        inp.target_position = goal[0].tolist()
        inp.target_velocity = goal[1].tolist()
        inp.target_acceleration = goal[2].tolist()
        return self._calculate(inp)

    def _plan_to_target(self) -> None:
        """Position mode: one time-optimal trajectory to the target at rest (clamped, limit-checked)."""
        assert self._target is not None
        p, _, _ = self._extrapolate(*self._target, self._clock - self._target_clock)
        traj = self._position_trajectory((p, np.zeros(2), np.zeros(2)))
        if traj is None:
            log.warning("no trajectory to target %s; holding", p)
            self._start_brake(keep_target=False)
            return
        # From a state that cannot avoid passing near a limit, step() still brakes in time.
        self._traj, self._t = traj, 0.0

    def _tracking_trajectory(self) -> Trajectory | None:
        """Tracking mode: Ruckig's velocity interface towards v_cmd (acceleration 0 at arrival), where

        v_cmd = v_ff + a_ff·|a_ff| / 2j + feedback(position error).

        The middle term is the velocity an acceleration adds while it is removed at full jerk: with it, a
        plan accelerating at a_ff is followed without lag while every re-plan still ends at zero
        acceleration, which keeps the profiles smooth (a target acceleration makes Ruckig switch between
        profile branches from cycle to cycle).
        """
        assert self._target is not None
        p_t, v_t, a_t = self._extrapolate(*self._target, self._clock - self._target_clock)
        error = p_t - self._p
        feedback = np.sign(error) * np.minimum(self._gain * np.abs(error), np.sqrt(self._amax * np.abs(error)))
        # Feed-forward of a reference the axes cannot follow (beyond their acceleration or jerk) arrives too
        # late and pumps the loop into a limit cycle; it is scaled down with the reference's feasibility.
        ff = (v_t + a_t * np.abs(a_t) / (2.0 * self._jmax)) * self._feasibility**_FF_POWER
        v_cmd = np.clip(ff + feedback, -self._vmax, self._vmax)
        traj = self._velocity_trajectory(self._p, self._v, self._a, v_cmd)
        if traj is not None:
            _, v1, a1 = self._sample(traj, self.dt)
            if self._velocity_safe(v1, a1):
                return traj
        # Ruckig's velocity interface does not enforce max_velocity. When the next setpoint could not remove
        # its acceleration before the limit, remove it at full jerk now: the velocity then peaks at
        # v + a|a|/2j, inside the limit because the current state passed this check.
        v_peak = np.clip(self._v + self._a * np.abs(self._a) / (2.0 * self._jmax), -self._vmax, self._vmax)
        return self._velocity_trajectory(self._p, self._v, self._a, v_peak)

    def _velocity_safe(self, v: np.ndarray, a: np.ndarray) -> bool:
        """Whether |v| stays ≤ v_max when the acceleration a is removed at full jerk (peak v + a|a|/2j)."""
        peak = v + a * np.abs(a) / (2.0 * self._jmax)
        limit = self._vmax * (1.0 + 1e-9)
        return bool(np.all(np.abs(v) <= limit) and np.all(np.abs(peak) <= limit))
