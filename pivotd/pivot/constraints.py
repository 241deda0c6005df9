"""Pan/tilt reachability of a two-axis gimbal, used inside the optimisation (projected gradient ascent).

Convention (pivotd.geometry): in the gimbal base frame d = Rz(pan) Ry(tilt) x̂; positive tilt points down.
"""

from __future__ import annotations

import numpy as np

from pivotd.geometry import direction_to_pan_tilt, pan_tilt_to_direction

__all__ = ["PanTiltConstraint"]

_TOL = 1e-9
_CORNERS = [1, 2, 4, 5]  # the candidates of _nearest_on_edges at the tilt limits (pan_min: 1, 2; pan_max: 4, 5)


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
        self._sin_tilt = (np.sin(self.tilt_min), np.sin(self.tilt_max))  # the tilt limits as sines of the tilt
        if not self.continuous:  # the boundary meridians: (cos, sin) of each pan limit, and their points at the
            # tilt limits (base frame, as pan_tilt_to_direction gives them)
            edges = np.array([self.pan_min, self.pan_max])
            self._edges = (np.cos(edges), np.sin(edges))
            self._corners = pan_tilt_to_direction(np.repeat([self.pan_min, self.pan_max], 2),
                                                  np.tile([self.tilt_min, self.tilt_max], 2))  # (4, 3)

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
        inside = (down >= self._sin_tilt[0]) & (down <= self._sin_tilt[1])
        if not self.continuous:
            inside &= self._pan_in_range(np.arctan2(b[:, 1], b[:, 0]))
        out = d / n[:, None]
        fix = np.flatnonzero(~inside)
        if fix.size == 0:
            return out
        bf = b[fix] / n[fix, None]
        pan, tilt = direction_to_pan_tilt(bf)
        if self.continuous:
            best = pan_tilt_to_direction(pan, np.minimum(np.maximum(tilt, self.tilt_min), self.tilt_max))
        else:  # onto the tilt limit of the meridian where the pan is inside its range, else onto an edge
            off = ~self._pan_in_range(pan)
            if off.all():
                best = self._nearest_on_edges(bf)
            else:
                best = pan_tilt_to_direction(pan, np.minimum(np.maximum(tilt, self.tilt_min), self.tilt_max))
                if off.any():
                    best[off] = self._nearest_on_edges(bf[off])
        world = np.einsum("nji,nj->ni", self.base_from_world[fix], best)  # base -> world (transpose)
        out[fix] = world / np.sqrt(np.add.reduce(world * world, axis=1, keepdims=True))  # np.linalg.norm's sum
        return out

    def _nearest_on_edges(self, b: np.ndarray) -> np.ndarray:
        """Nearest point of the two boundary meridians (tilt-limited) to unit base directions b (n, 3)."""
        n = len(b)
        cp, sp = self._edges
        # on each meridian (columns: pan_min, pan_max) the maximiser of b·dir(p, t) over the full circle, clipped to
        # the tilt limits
        t = np.arctan2(-b[:, 2, None], b[:, 0, None] * cp + b[:, 1, None] * sp)  # (n, 2)
        np.maximum(t, self.tilt_min, out=t)
        np.minimum(t, self.tilt_max, out=t)
        ct = np.cos(t)
        # six candidates per row (n, 6, 3): those two, and each meridian's two ends at the tilt limits
        stack = np.empty((n, 6, 3))
        stack[:, _CORNERS] = self._corners
        stack[:, ::3, 0] = cp * ct
        stack[:, ::3, 1] = sp * ct
        stack[:, ::3, 2] = -np.sin(t)
        best = np.argmax(np.einsum("nkj,nj->nk", stack, b), axis=1)
        return stack[np.arange(n), best]
