"""One run: a policy steers the gimbal along the route; every frame is observed and localized.

Time advances in control periods of config/demo.yaml (100 Hz). At the planner rate the policy is asked
for a command (its compute is measured as CPU time, ``time.process_time``, which a shared machine's
load does not inflate); every control period the daemon's :class:`ControlLoop`
turns the latest plan (or joint target) and body pose into a jerk-limited setpoint, which a simulated
gimbal follows exactly. At the frame rate the camera pose (centre from the body pose and mount,
orientation from the setpoint, roll level) is recorded. The open-loop policies (the oracles) skip the
control loop and compute their camera path for the whole route at once: the achievable oracle runs its path
through the motion generator itself, the teleporting one points the camera at its best direction every frame.

Observation and estimation (:func:`localize`) draw from generators seeded by the run seed (dropout) and
by the run seed and frame number (detections, noise, outliers, RANSAC), independent of the policy.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, replace

import numpy as np

from pivotd.firmware_proto.messages import MODE_ENABLED
from pivotd.localization.camera import camera_rotation, dropout_mask, observe, visible
from pivotd.localization.estimator import RansacSettings, estimate_pose, pose_error
from pivotd.localization.policies import Policy
from pivotd.localization.stack import GimbalState, Plan, PoseSample, build_control_loop, joints_to_world_direction
from pivotd.localization.world import World

FRAME_HZ = 10.0  # camera frames per second that are localized


class SimulatedGimbal:
    """A gimbal that is always connected and reaches each setpoint exactly; records the commanded stream."""

    link_state = "up"

    def __init__(self, pan: float = 0.0, tilt: float = 0.0) -> None:
        self.state = GimbalState(pan, tilt, 0.0, 0.0, MODE_ENABLED, 0, 0, 0, 0.0)
        self.setpoints: list[tuple[float, float, float, float]] = []

    def send_setpoint(self, pan: float, tilt: float, pan_rate: float, tilt_rate: float) -> int:
        """Reach the setpoint at once; returns its sequence number (the link's, modulo 256: always sent)."""
        self.setpoints.append((pan, tilt, pan_rate, tilt_rate))
        self.state = replace(self.state, pan=pan, tilt=tilt, pan_rate=pan_rate, tilt_rate=tilt_rate,
                             last_setpoint_seq=(len(self.setpoints) - 1) & 0xFF)
        return (len(self.setpoints) - 1) & 0xFF

    def send_heartbeat(self) -> None:
        pass


@dataclass(frozen=True)
class Trajectory:
    """A policy's camera over a run: frame times (F,) [s], centres (F, 3) [m], optical axes (F, 3);
    the commanded stream (T, 4) (pan, tilt, pan rate, tilt rate) at the control period ``dt`` (empty for
    the teleporting oracle); compute_s: the policy's total decision time [s]; decisions: how many decisions it took
    (replans, orientation searches, per-frame looks: :meth:`Policy.decisions`)."""

    times: np.ndarray
    centres: np.ndarray
    directions: np.ndarray
    setpoints: np.ndarray
    dt: float
    compute_s: float
    decisions: int = 0


def frame_times(world: World, frame_hz: float = FRAME_HZ) -> np.ndarray:
    """Frame times (F,) [s] over the route."""
    return np.arange(0.0, world.scene.duration + 1e-9, 1.0 / frame_hz)


def run_policy(world: World, policy: Policy, frame_hz: float = FRAME_HZ) -> Trajectory:
    """Drive ``policy`` along the route of ``world`` and record its camera at every frame."""
    frames = frame_times(world, frame_hz)
    body_f, quat_f = world.body_poses(frames)
    centres = world.camera_centres(body_f, quat_f)
    cfg = world.cfg
    dt = cfg.control.dt
    if policy.open_loop:
        t0 = time.process_time()
        dirs, setpoints = policy.camera_path(centres, quat_f, frames)
        return Trajectory(frames, centres, dirs, setpoints, dt if setpoints.shape[0] else 0.0,
                          time.process_time() - t0, policy.decisions(len(frames)))
    ticks_per_replan = max(1, round(cfg.control.rate_hz / cfg.planner.replan_hz))
    n = int(np.floor(world.scene.duration / dt + 1e-9)) + 1
    times = np.arange(n) * dt
    body, quats = world.body_poses(times)
    gimbal = SimulatedGimbal()
    now = [0.0]  # the simulated time: the loop never reads the host's clock, so host stalls change nothing
    loop = build_control_loop(cfg, gimbal, clock=lambda: now[0])
    frame_tick = set(np.round(frames / dt).astype(int).tolist())
    dirs = []
    plan: Plan | None = None
    compute = 0.0
    updates = 0
    for k in range(n):
        t = float(times[k])
        now[0] = t
        pose = PoseSample(t, "map", body[k], quats[k], t)
        if k % ticks_per_replan == 0:
            t0 = time.process_time()
            command = policy.update(t, pose, loop.commanded_direction)
            compute += time.process_time() - t0
            updates += 1
            if isinstance(command, Plan):
                plan = replace(command, created=t)
                loop.override_target = None
            else:
                loop.override_target = command
        loop.tick(t, pose, plan)
        if k in frame_tick:
            pan, tilt = gimbal.setpoints[-1][:2]
            dirs.append(joints_to_world_direction(pan, tilt, quats[k], world.mount))
    setpoints = np.asarray(gimbal.setpoints, float)
    return Trajectory(frames, centres, np.asarray(dirs), setpoints, dt, compute, policy.decisions(updates))


@dataclass(frozen=True)
class FrameErrors:
    """Per frame: translation error (F,) [m] and rotation error (F,) [deg] (inf: no pose), landmarks in
    view (F,), correspondences given to the estimator (F,)."""

    translation: np.ndarray
    rotation: np.ndarray
    in_view: np.ndarray
    matches: np.ndarray


def localize(world: World, traj: Trajectory, seed: int, ransac: RansacSettings | None = None) -> FrameErrors:
    """Observe every frame of ``traj`` and estimate its pose; errors against the true camera pose."""
    present = dropout_mask(world.camera, len(world.scene.landmarks), np.random.default_rng([seed, 2024]))
    F = traj.times.shape[0]
    et, er = np.full(F, np.inf), np.full(F, np.inf)
    in_view, matches = np.zeros(F, np.int64), np.zeros(F, np.int64)
    R_all = camera_rotation(traj.directions)
    for i in range(F):
        rng = np.random.default_rng([seed, 2025, i])
        c = traj.centres[i]
        sight = world.sight(i, c)
        seen = visible(world.camera, R_all[i], c, world.scene.landmarks, sight[present[sight]])
        uv, X = observe(world.camera, R_all[i], c, world.scene.landmarks, seen, rng)
        in_view[i], matches[i] = seen.size, uv.shape[0]
        est = estimate_pose(world.camera, uv, X, seed=int(rng.integers(1 << 31)), settings=ransac)
        et[i], er[i] = pose_error(est, R_all[i], c)
    return FrameErrors(et, er, in_view, matches)
