"""Retained-set filters (paper §III: the landmark set V_i used at waypoint i).

Applied in order, each optional:

1. range: ``min_range ≤ ‖p − w‖ ≤ max_range`` (spatial index, cost set by local density);
2. view direction: when observation directions are known, drop landmarks whose direction from the
   landmark to the waypoint is more than ``max_view_angle_deg`` from their mean observation
   direction (FIF uses 60°); landmarks with an unknown (zero) direction are kept;
3. occlusion: drop landmarks whose line of sight from the waypoint crosses an occupied voxel
   (:mod:`pivotd.maps.occlusion`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pivotd.errors import InputError

if TYPE_CHECKING:
    from pivotd.maps.store import MapSnapshot


@dataclass(frozen=True)
class RetainedFilter:
    """min_range, max_range [m]; max_view_angle_deg [deg] or None (off); occlusion: use the snapshot's grid.

    occlusion_clearance [m] (None: one voxel) and occlusion_step [voxels] tune the ray test.
    """

    min_range: float = 0.0
    max_range: float = math.inf
    max_view_angle_deg: float | None = None
    occlusion: bool = False
    occlusion_clearance: float | None = None
    occlusion_step: float = 1.0

    def __post_init__(self) -> None:
        """Raises InputError (a user error: CLI exit 2) for inconsistent values."""
        if not (self.min_range >= 0 and self.max_range >= self.min_range):
            raise InputError(f"need 0 ≤ min_range ≤ max_range, got {self.min_range}, {self.max_range}")
        if self.max_view_angle_deg is not None and not 0 <= self.max_view_angle_deg <= 180:
            raise InputError(f"max_view_angle_deg must be in [0, 180], got {self.max_view_angle_deg}")
        if not 0 < self.occlusion_step <= 1:
            raise InputError(f"occlusion_step must be in (0, 1] voxels, got {self.occlusion_step}")
        if self.occlusion_clearance is not None and not self.occlusion_clearance >= 0:
            raise InputError(f"occlusion_clearance must be ≥ 0 m, got {self.occlusion_clearance}")


def view_direction_mask(
    points: np.ndarray, directions: np.ndarray, waypoint: np.ndarray, max_angle_deg: float
) -> np.ndarray:
    """(n,) bool: landmarks ``points`` (n, 3) whose unit ``directions`` (n, 3) lie within ``max_angle_deg``
    of the landmark→``waypoint`` direction (``waypoint`` (3,) or (n, 3)); zero directions (unknown) pass.

    Computed in float32 (the map's precision) on columns, without square roots.
    """
    w = np.asarray(waypoint, dtype=np.float32)
    vx, vy, vz = w[..., 0] - points[:, 0], w[..., 1] - points[:, 1], w[..., 2] - points[:, 2]
    dx, dy, dz = directions[:, 0], directions[:, 1], directions[:, 2]
    dot = vx * dx
    dot += vy * dy
    dot += vz * dz
    vv = vx * vx
    vv += vy * vy
    vv += vz * vz
    dd = dx * dx
    dd += dy * dy
    dd += dz * dz
    c = math.cos(math.radians(max_angle_deg))
    # dot ≥ c·|v|  ⇔  (c ≥ 0: dot ≥ 0 and dot² ≥ c²|v|²) or (c < 0: dot ≥ 0 or dot² ≤ c²|v|²)
    c2 = np.float32(c * c)
    ok = (dot >= 0) & (dot * dot >= c2 * vv) if c >= 0 else (dot >= 0) | (dot * dot <= c2 * vv)
    return ok | (dd < np.float32(0.25))  # zero direction: unknown, kept


def retained_for_path(snapshot: MapSnapshot, waypoints: np.ndarray, flt: RetainedFilter) -> list[np.ndarray]:
    """Per-waypoint ascending int64 index arrays into ``snapshot.points`` for waypoints (N, 3) [m]."""
    return snapshot.retained(np.asarray(waypoints, dtype=np.float64).reshape(-1, 3), flt)
