"""A hard limit on the angle between consecutive viewing directions of a trajectory.

:func:`limit_steps` makes every step ≤ S by construction: a forward pass along the path moves each
axis that is further than S from its predecessor (the anchor before waypoint 0) along the great
circle towards it, to exactly S away. Axes already within S stay where they are, so a plan that meets
the limit is returned unchanged. With joint limits the moved axis is the point of that arc (at most S
from the predecessor) furthest from the predecessor that is reachable; only when no point of the arc
is reachable (the predecessor itself is not, at this waypoint) do the joint limits win over the step.
"""

from __future__ import annotations

import math

import numpy as np

from pivotd.geometry import tangent_basis
from pivotd.pivot.constraints import PanTiltConstraint

__all__ = ["MAX_STEP_RANGE_DEG", "limit_steps", "step_angles"]

#: step limits users may ask for [deg]: below 0.01° a plan can hardly turn, 180° is no limit at all
MAX_STEP_RANGE_DEG = (0.01, 180.0)


def step_angles(C: np.ndarray, anchor: np.ndarray | None = None) -> np.ndarray:
    """Angles [rad] between consecutive unit axes C (N, 3): (N − 1,), or (N,) with the anchor's step first."""
    C = np.asarray(C, dtype=float)
    seq = C if anchor is None else np.vstack([np.asarray(anchor, float)[None], C])
    a, b = seq[1:], seq[:-1]
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=1), np.einsum("ij,ij->i", a, b))


def _arc_point(p: np.ndarray, c: np.ndarray, angle: float) -> np.ndarray:
    """The unit direction ``angle`` [rad] from unit p towards unit c on their great circle."""
    u = c - (c @ p) * p
    n = math.sqrt(float(u @ u))
    if n < 1e-12:  # c = ±p: any perpendicular
        u, n = tangent_basis(p)[0], 1.0
    return math.cos(angle) * p + math.sin(angle) * (u / n)


def _reachable_on_arc(
    p: np.ndarray, c: np.ndarray, angle: float, con: PanTiltConstraint, i: int
) -> np.ndarray:
    """The point of the arc from p towards c, at most ``angle`` from p, that is reachable at waypoint i and
    furthest from p (bisection; 24 halvings ≈ 1e-7 of the angle); the projection of p if none is."""
    sub = PanTiltConstraint(con.base_from_world[i : i + 1], con.pan_min, con.pan_max, con.tilt_min, con.tilt_max)

    def ok(t: float) -> bool:
        return bool(sub.reachable(_arc_point(p, c, t)[None])[0])

    if ok(angle):
        return _arc_point(p, c, angle)
    if not ok(0.0):
        return sub.project(p[None])[0]
    lo, hi = 0.0, angle
    for _ in range(24):
        mid = 0.5 * (lo + hi)
        lo, hi = (mid, hi) if ok(mid) else (lo, mid)
    return _arc_point(p, c, lo)


def limit_steps(
    C: np.ndarray,
    max_step: float,
    *,
    anchor: np.ndarray | None = None,
    constraint: PanTiltConstraint | None = None,
) -> np.ndarray:
    """Unit axes (N, 3) with every step ≤ ``max_step`` [rad] (module docstring); C (N, 3) unit axes,
    ``anchor`` (3,) a fixed direction before waypoint 0, ``constraint`` joint limits per waypoint."""
    out = np.array(C, dtype=float)
    if not (math.isfinite(max_step) and max_step > 0):
        raise ValueError(f"max_step must be a finite angle > 0 rad, got {max_step}")
    target = max_step * (1.0 - 1e-9)  # a hair inside, so that the recomputed angle never exceeds the limit
    cos_s = math.cos(max_step)
    steps_cos = np.einsum("ij,ij->i", out[1:], out[:-1])
    first = None if anchor is None else float(out[0] @ anchor)
    if (first is None or first >= cos_s) and np.all(steps_cos >= cos_s):
        return out
    prev = None if anchor is None else np.asarray(anchor, dtype=float)
    for i in range(out.shape[0]):
        c = out[i]
        if prev is not None and float(c @ prev) < cos_s:
            c = (_arc_point(prev, c, target) if constraint is None
                 else _reachable_on_arc(prev, c, target, constraint, i))
            out[i] = c / math.sqrt(float(c @ c))
        prev = out[i]
    return out
