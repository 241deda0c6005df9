"""Constant-speed motion along a waypoint route (for the pose simulator).

Positions are interpolated linearly in arc length; attitude comes from the route's quaternions
(normalized linear interpolation) when it has them, otherwise yaw follows the path tangent
(vertex tangents from neighbouring segments, interpolated in arc length, so it turns smoothly).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import matrix_to_quat, yaw_to_matrix
from pivotd.paths import PathData, load_path
from pivotd.pivot.scenes import hallway


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


class Route:
    """A polyline route; :meth:`at` gives the pose at arc length ``s`` [m] (clamped to the route)."""

    def __init__(self, positions: np.ndarray, quats: np.ndarray | None = None) -> None:
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        if positions.shape[0] == 0:
            raise InputError("route has no waypoints")
        # Drop repeated waypoints: they have no tangent and add nothing to the geometry.
        keep = np.ones(positions.shape[0], dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(positions, axis=0), axis=1) > 1e-9
        self.positions = positions[keep]
        self.quats = None
        if quats is not None:
            q = np.asarray(quats, dtype=float).reshape(-1, 4)[keep]
            # Keep consecutive quaternions in the same hemisphere for interpolation.
            for i in range(1, q.shape[0]):
                if np.dot(q[i], q[i - 1]) < 0:
                    q[i] = -q[i]
            self.quats = q
        seg = np.linalg.norm(np.diff(self.positions, axis=0), axis=1)
        self.arc = np.concatenate([[0.0], np.cumsum(seg)])
        self.length = float(self.arc[-1])
        self.yaw = self._vertex_yaw()

    def _vertex_yaw(self) -> np.ndarray:
        p = self.positions
        if p.shape[0] < 2:
            return np.zeros(p.shape[0])
        tangent = np.empty_like(p)
        tangent[0] = p[1] - p[0]
        tangent[-1] = p[-1] - p[-2]
        tangent[1:-1] = p[2:] - p[:-2]
        return np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))

    def at(self, s: float, speed: float = 0.0) -> RoutePose:
        """Pose at arc length ``s`` [m] while moving at ``speed`` [m/s] (zero velocity at the ends)."""
        if self.positions.shape[0] == 1:
            q = self.quats[0] if self.quats is not None else np.array([0.0, 0.0, 0.0, 1.0])
            return RoutePose(self.positions[0].copy(), q, np.zeros(3))
        s_c = float(np.clip(s, 0.0, self.length))
        i = int(np.clip(np.searchsorted(self.arc, s_c, side="right") - 1, 0, len(self.arc) - 2))
        span = self.arc[i + 1] - self.arc[i]
        u = (s_c - self.arc[i]) / span
        position = (1 - u) * self.positions[i] + u * self.positions[i + 1]
        if self.quats is not None:
            q = (1 - u) * self.quats[i] + u * self.quats[i + 1]
            quat = q / np.linalg.norm(q)
        else:
            quat = matrix_to_quat(yaw_to_matrix((1 - u) * self.yaw[i] + u * self.yaw[i + 1]))
        direction = (self.positions[i + 1] - self.positions[i]) / span
        moving = speed > 0 and 0.0 <= s < self.length
        return RoutePose(position, quat, direction * speed if moving else np.zeros(3))
