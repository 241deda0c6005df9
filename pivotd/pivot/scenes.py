"""Synthetic scenes for tests, benchmarks and the demo (deterministic given a seed)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class Scene:
    """points: (M, 3) landmarks [m]; weights: (M,); path: (N, 3) sensor positions [m]."""

    points: np.ndarray
    weights: np.ndarray
    path: np.ndarray


def _hallway_centerline(length: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """S-shaped centerline: +x, a left turn to +y, a right turn back to +x. Returns xy (K,2), heading (K,)."""
    s = np.arange(0.0, length + 1e-9, step)

    def sig(u: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-u))

    heading = 0.5 * np.pi * (sig((s - 0.3 * length) / 1.2) - sig((s - 0.7 * length) / 1.2))
    dx = np.cos(heading) * step
    dy = np.sin(heading) * step
    xy = np.stack([np.concatenate([[0.0], np.cumsum(dx[:-1])]), np.concatenate([[0.0], np.cumsum(dy[:-1])])], 1)
    return xy, heading


def hallway(
    length: float = 36.0,
    width: float = 3.0,
    spacing: float = 0.5,
    rich_side_points: int = 3000,
    poor_side_points: int = 150,
    sensor_height: float = 0.7,
    seed: int = 0,
) -> Scene:
    """S-shaped hallway like the paper's indoor route: landmarks concentrated on the left wall.

    The route follows the centerline at ``sensor_height`` with waypoints every ``spacing`` metres.
    Left wall (rich side) gets ``rich_side_points`` landmarks, the right wall ``poor_side_points``,
    at heights 0.2–2.6 m, on walls ``width`` apart.
    """
    rng = np.random.default_rng(seed)
    fine_xy, fine_heading = _hallway_centerline(length, 0.05)
    normal = np.stack([-np.sin(fine_heading), np.cos(fine_heading)], 1)  # points left

    def wall(count: int, side: float) -> np.ndarray:
        idx = rng.integers(0, fine_xy.shape[0], count)
        xy = fine_xy[idx] + side * 0.5 * width * normal[idx] + rng.normal(0, 0.03, (count, 2)) * normal[idx]
        z = rng.uniform(0.2, 2.6, count)
        return np.column_stack([xy, z])

    points = np.concatenate([wall(rich_side_points, +1.0), wall(poor_side_points, -1.0)])
    path_xy, _ = _hallway_centerline(length, spacing)
    path = np.column_stack([path_xy, np.full(path_xy.shape[0], sensor_height)])
    return Scene(points=points, weights=np.ones(points.shape[0]), path=path)
