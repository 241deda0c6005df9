"""Motion along a waypoint route for the pose simulator: at constant speed on :class:`pivotd.robot_path.Polyline`
(:class:`Route`), or by the route's own time stamps (:class:`TimedRoute`)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import normalize
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import PathData, Polyline, load_path


def load_route(spec: str) -> PathData:
    """``"hallway"`` (the S-shaped demo hallway) or ``"csv:FILE"`` (any path CSV); raises InputError."""
    if spec == "hallway":
        return PathData(positions=hallway().path)
    if spec.startswith("csv:") and len(spec) > 4:
        return load_path(spec[4:])
    raise InputError(f"unknown route {spec!r} (expected 'hallway' or 'csv:FILE')")


@dataclass(frozen=True)
class RoutePose:
    """position (3,) [m]; quat (4,) (x, y, z, w); velocity (3,) in the world frame [m/s]."""

    position: np.ndarray
    quat: np.ndarray
    velocity: np.ndarray


class Route(Polyline):
    """A polyline route; :meth:`at` gives the pose at arc length ``s`` [m] (clamped to the route)."""

    def at(self, s: float, speed: float = 0.0) -> RoutePose:
        """Pose at arc length ``s`` [m] while moving at ``speed`` [m/s] (zero velocity at the ends)."""
        pos, quat = self.sample(np.array([s]))
        moving = speed > 0 and 0.0 <= s < self.length and self.positions.shape[0] > 1
        velocity = self.direction(float(np.clip(s, 0.0, self.length))) * speed if moving else np.zeros(3)
        return RoutePose(pos[0], quat[0], velocity)


class TimedRoute:
    """A route played by its own time stamps (``tools/sim_pose --timed``): the pose at time ``t`` [s] from the first
    stamp, interpolated linearly between rows (quaternions renormalised), so rows that repeat a position with
    another attitude are a turn in place.

    positions (N, 3) [m]; quats (N, 4) (x, y, z, w); stamps (N,) [s], non-decreasing with a positive span.
    """

    def __init__(self, positions: np.ndarray, quats: np.ndarray, stamps: np.ndarray) -> None:
        p = np.asarray(positions, float).reshape(-1, 3)
        q = np.asarray(quats, float).reshape(-1, 4)
        t = np.asarray(stamps, float).reshape(-1)
        if not (p.shape[0] == q.shape[0] == t.shape[0] >= 2):
            raise InputError("a timed route needs at least two rows with time stamps and quaternions")
        dt = np.diff(t)
        if np.any(dt < 0):
            raise InputError(f"timed route: the time stamps decrease at row {int(np.argmax(dt < 0)) + 2}")
        if t[-1] <= t[0]:
            raise InputError("timed route: the time stamps span no time")
        q = q / np.linalg.norm(q, axis=1, keepdims=True)
        flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
        q[1:] *= flip[:, None]
        self.positions, self.quats, self.stamps = p, q, t - t[0]
        self.duration = float(self.stamps[-1])

    def at_time(self, t: float) -> RoutePose:
        """Pose at ``t`` [s] since the first row (clamped to the route; zero velocity outside it)."""
        tc = float(np.clip(t, 0.0, self.duration))
        i = int(np.clip(np.searchsorted(self.stamps, tc, side="right") - 1, 0, self.stamps.shape[0] - 2))
        span = self.stamps[i + 1] - self.stamps[i]
        u = (tc - self.stamps[i]) / span if span > 0 else 1.0
        pos = self.positions[i] + u * (self.positions[i + 1] - self.positions[i])
        quat = normalize((1 - u) * self.quats[i] + u * self.quats[i + 1])
        moving = span > 0 and 0.0 <= t < self.duration
        velocity = (self.positions[i + 1] - self.positions[i]) / span if moving else np.zeros(3)
        return RoutePose(pos, quat, velocity)
