"""Pan/tilt reachability of a two-axis gimbal, used inside the optimisation (projected gradient ascent).

Convention (pivotd.geometry): in the gimbal base frame d = Rz(pan) Ry(tilt) x̂; positive tilt points down.
"""

from __future__ import annotations

import numpy as np

from pivotd.geometry import direction_to_pan_tilt, pan_tilt_to_direction

__all__ = ["PanTiltConstraint"]

_TOL = 1e-9


class PanTiltConstraint:
    """Joint limits per waypoint: pan ∈ [pan_min, pan_max], tilt ∈ [tilt_min, tilt_max] [rad].

    ``base_from_world`` (N, 3, 3) rotates world vectors into each waypoint's gimbal base frame.
    pan_min = −inf / pan_max = +inf (or a range ≥ 2π) means continuous pan. Tilt limits are clipped to
    [−π/2, π/2].
    """

    def __init__(
        self,
        base_from_world: np.ndarray,
        pan_min: float,
        pan_max: float,
        tilt_min: float,
        tilt_max: float,
    ) -> None:
        R = np.asarray(base_from_world, dtype=float)
        if R.ndim == 2:
            R = R[None]
        if R.ndim != 3 or R.shape[1:] != (3, 3) or not np.isfinite(R).all():
            raise ValueError(f"base_from_world must be a finite (N, 3, 3) array, got shape {R.shape}")
        if np.isnan([pan_min, pan_max, tilt_min, tilt_max]).any() or pan_min > pan_max or tilt_min > tilt_max:
            raise ValueError(f"bad pan/tilt limits: pan [{pan_min}, {pan_max}], tilt [{tilt_min}, {tilt_max}]")
        self.base_from_world = R
        self.continuous = not (np.isfinite(pan_min) and np.isfinite(pan_max)) or pan_max - pan_min >= 2 * np.pi
        self.pan_min = float(pan_min)
        self.pan_max = float(pan_max)
        self.tilt_min = float(max(tilt_min, -np.pi / 2))
        self.tilt_max = float(min(tilt_max, np.pi / 2))

    def __len__(self) -> int:
        return int(self.base_from_world.shape[0])

    def _base(self, directions: np.ndarray) -> np.ndarray:
        d = np.asarray(directions, dtype=float)
        if d.shape != (len(self), 3):
            raise ValueError(f"directions must have shape ({len(self)}, 3), got {d.shape}")
        return np.einsum("nij,nj->ni", self.base_from_world, d)

    def _pan_in_range(self, pan: np.ndarray) -> np.ndarray:
        if self.continuous:
            return np.ones(pan.shape, dtype=bool)
        wrapped = self.pan_min + np.mod(pan - self.pan_min, 2 * np.pi)
        return (wrapped <= self.pan_max + _TOL) | (np.abs(wrapped - 2 * np.pi - self.pan_min) <= _TOL)

    def reachable(self, directions: np.ndarray) -> np.ndarray:
        """(N,) bool: the world direction at each waypoint lies within the joint limits."""
        b = self._base(directions)
        pan, tilt = direction_to_pan_tilt(b)
        pole = np.hypot(b[:, 0], b[:, 1]) < 1e-9 * np.maximum(np.linalg.norm(b, axis=1), 1e-300)
        ok_tilt = (tilt >= self.tilt_min - _TOL) & (tilt <= self.tilt_max + _TOL)
        return ok_tilt & (pole | self._pan_in_range(pan))

    def project(self, directions: np.ndarray) -> np.ndarray:
        """Nearest reachable unit world direction (N, 3) for each waypoint (great-circle distance).

        Directions already within the limits are returned normalised as they are; only the others
        are moved (onto the tilt limit of their meridian, or onto a boundary meridian).
        """
        d = np.asarray(directions, dtype=float)
        if d.shape != (len(self), 3):
            raise ValueError(f"directions must have shape ({len(self)}, 3), got {d.shape}")
        b = np.matmul(self.base_from_world, d[:, :, None])[..., 0]
        n = np.sqrt(np.einsum("ij,ij->i", b, b))
        n[n < 1e-300] = 1.0
        down = -b[:, 2] / n  # sin(tilt): tilt ∈ [−π/2, π/2], so the limits compare as sines
        inside = (down >= np.sin(self.tilt_min)) & (down <= np.sin(self.tilt_max))
        if not self.continuous:
            inside &= self._pan_in_range(np.arctan2(b[:, 1], b[:, 0]))
        out = d / n[:, None]
        fix = np.flatnonzero(~inside)
        if fix.size == 0:
            return out
        bf = b[fix] / n[fix, None]
        pan, tilt = direction_to_pan_tilt(bf)
        best = pan_tilt_to_direction(pan, np.clip(tilt, self.tilt_min, self.tilt_max))
        if not self.continuous:
            off = ~self._pan_in_range(pan)
            if np.any(off):
                best[off] = self._nearest_on_edges(bf[off])
        world = np.einsum("nji,nj->ni", self.base_from_world[fix], best)  # base -> world (transpose)
        out[fix] = world / np.linalg.norm(world, axis=1, keepdims=True)
        return out

    def _nearest_on_edges(self, b: np.ndarray) -> np.ndarray:
        """Nearest point of the two boundary meridians (tilt-limited) to unit base directions b (n, 3)."""
        n = len(b)
        pans, tilts = [], []
        for p in (self.pan_min, self.pan_max):
            g = b[:, 0] * np.cos(p) + b[:, 1] * np.sin(p)
            t_star = np.arctan2(-b[:, 2], g)  # maximiser of d·dir(p, t) over the full circle
            for t in (np.clip(t_star, self.tilt_min, self.tilt_max), np.full(n, self.tilt_min),
                      np.full(n, self.tilt_max)):
                pans.append(np.full(n, p))
                tilts.append(t)
        # one conversion for all six candidates per row: (n, 6, 3)
        stack = pan_tilt_to_direction(np.stack(pans, axis=1).ravel(), np.stack(tilts, axis=1).ravel()).reshape(n, 6, 3)
        best = np.argmax(np.einsum("nkj,nj->nk", stack, b), axis=1)
        return stack[np.arange(n), best]
