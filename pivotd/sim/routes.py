"""Constant-speed motion along a waypoint route (for the pose simulator), on :class:`pivotd.robot_path.Polyline`."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
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
