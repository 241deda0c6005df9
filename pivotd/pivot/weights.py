"""Spread weights: per-waypoint landmark weights that saturate dense clumps.

A visible count rewards 200 landmarks on one textured patch as much as 200 spread over the scene, yet a
camera pose is pinned down by landmarks in many directions and at several depths, and a view that holds
one clump loses everything when the clump leaves the image. Here each retained landmark of a waypoint
falls into a cell of bearing (a cube-map grid of the unit sphere, ``cell`` radians wide) × depth (shells
growing by ``depth_ratio``); a cell holding n landmarks gives each of them the weight min(1, k / n), so
a cell contributes at most ``k`` (``saturation``) to the weighted count however dense it is. The
weighted count in the cone is then close to k × the number of occupied cells — the angular and depth
extent of the visible set — while sparse landmarks keep their full weight.

Pure numpy; the cost is O(R log R) for R retained pairs (only the retained landmarks are read). The
weights depend on the set of a waypoint's retained landmarks only, not on their order.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np


@dataclass(frozen=True)
class SpreadSettings:
    """cell [rad]: bearing cell width; depth_ratio > 1: depth shells [d, d · ratio); saturation k ≥ 0: the
    most weight one cell contributes (landmarks count fully up to k per cell)."""

    cell: float
    depth_ratio: float = 2.0
    saturation: float = 1.0

    def __post_init__(self) -> None:
        if not (np.isfinite(self.cell) and 0.0 < self.cell <= np.pi):
            raise ValueError(f"spread cell must be an angle in (0, pi] rad, got {self.cell}")
        if not (np.isfinite(self.depth_ratio) and self.depth_ratio > 1.0):
            raise ValueError(f"spread depth ratio must be > 1, got {self.depth_ratio}")
        if not (np.isfinite(self.saturation) and self.saturation > 0.0):
            raise ValueError(f"spread saturation must be > 0, got {self.saturation}")


def cell_keys(offsets: np.ndarray, settings: SpreadSettings) -> np.ndarray:
    """Cell key (n,) int64 of each landmark offset (n, 3) [m] from the camera: bearing × depth shell.

    The bearing cell is the cube face of the offset's largest component and the (u, v) square of side
    ``cell`` (in the face's angle coordinates, atan of the two other components over the largest); the
    depth shell is floor(log(d) / log(depth_ratio)). Zero offsets get the key of a cell of their own kind.
    """
    off = np.asarray(offsets, dtype=float).reshape(-1, 3)
    a = np.abs(off)
    face = np.argmax(a, axis=1)
    n = off.shape[0]
    rows = np.arange(n)
    major = off[rows, face]
    safe = np.where(major == 0.0, 1.0, np.abs(major))
    u_axis = (face + 1) % 3
    v_axis = (face + 2) % 3
    # angle coordinates on the face: cells of about equal angular size across it (±45°)
    u = np.arctan(off[rows, u_axis] / safe)
    v = np.arctan(off[rows, v_axis] / safe)
    per_face = int(np.ceil((0.5 * np.pi) / settings.cell)) + 1
    iu = np.clip(np.floor((u + 0.25 * np.pi) / settings.cell).astype(np.int64), 0, per_face - 1)
    iv = np.clip(np.floor((v + 0.25 * np.pi) / settings.cell).astype(np.int64), 0, per_face - 1)
    signed_face = face * 2 + (major < 0)
    bearing = (signed_face * per_face + iu) * per_face + iv
    d = np.sqrt(np.einsum("ij,ij->i", off, off))
    shell = np.floor(np.log(np.maximum(d, 1e-12)) / np.log(settings.depth_ratio)).astype(np.int64)
    shell = np.clip(shell, -1000, 1000) + 1000  # 2001 shells cover 1e-12 m .. far beyond any map
    return bearing * 2001 + shell


def spread_weights(offsets: np.ndarray, settings: SpreadSettings) -> np.ndarray:
    """Weights (n,) in (0, 1] of landmark offsets (n, 3) [m] from one camera: min(1, k / n_cell)."""
    off = np.asarray(offsets, dtype=float).reshape(-1, 3)
    if off.shape[0] == 0:
        return np.zeros(0)
    _, inverse, counts = np.unique(cell_keys(off, settings), return_inverse=True, return_counts=True)
    return np.minimum(1.0, settings.saturation / counts[inverse.reshape(-1)])


def waypoint_spread_weights(points: np.ndarray, cameras: np.ndarray, retained: Sequence[np.ndarray],
                            settings: SpreadSettings) -> list[np.ndarray]:
    """Per waypoint, the spread weights (n_i,) of its retained landmarks ``points[retained[i]]`` seen from
    ``cameras[i]`` (points (M, 3), cameras (N, 3) [m]); reads only the retained rows of ``points``."""
    return [spread_weights(points.take(np.asarray(r, dtype=np.intp), axis=0) - cameras[i], settings)
            for i, r in enumerate(retained)]
