"""Gimbal kinematics: world viewing direction <-> pan/tilt joint angles.

Chain: world --(body attitude, quaternion x,y,z,w)--> body --(mount)--> gimbal base --(pan, tilt)--> optical axis.
The pan/tilt convention is the one of :mod:`pivotd.geometry` (docs/ARCHITECTURE.md, Conventions): pan about
base +z, tilt about the panned +y, positive tilt points down, pan = tilt = 0 looks along base +x. The gimbal
is modelled as a pure rotation about the base origin (the camera's offset from the joint axes is neglected:
it is centimetres against landmark ranges of metres).

Joint solutions: a direction has the primary solution (pan, tilt) with |tilt| ≤ π/2 and the "over the top"
solution (pan + π, π − tilt); each pan value repeats every 2π. :func:`world_direction_to_joints` picks the
reachable solution nearest the previous pan (continuous pan unwraps across ±π), preferring the primary one,
and clamps to the joint limits when nothing is reachable.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from pivotd.geometry import angle_between, direction_to_pan_tilt, pan_tilt_to_direction, quat_to_matrix

_TOL = 1e-9  # [rad] slack when testing whether a joint value lies inside its limits


def rpy_to_matrix(rpy: np.ndarray) -> np.ndarray:
    """Rotation (3, 3) from fixed-axis roll, pitch, yaw [rad] (ROS/URDF convention: R = Rz(y) Ry(p) Rx(r))."""
    r, p, y = (float(v) for v in np.asarray(rpy, dtype=float).reshape(3))
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


@dataclass(frozen=True, eq=False)
class Mount:
    """Gimbal base pose in the body frame: rotation (3, 3) base→body and translation (3,) [m]."""

    rotation: np.ndarray = field(default_factory=lambda: np.eye(3))
    translation: np.ndarray = field(default_factory=lambda: np.zeros(3))

    def __post_init__(self) -> None:
        rot = np.array(self.rotation, dtype=float).reshape(3, 3)
        trans = np.array(self.translation, dtype=float).reshape(3)
        rot.setflags(write=False)
        trans.setflags(write=False)
        object.__setattr__(self, "rotation", rot)
        object.__setattr__(self, "translation", trans)

    def __eq__(self, other: object) -> bool:
        if not isinstance(other, Mount):
            return NotImplemented
        same_rotation = np.array_equal(self.rotation, other.rotation)
        return bool(same_rotation and np.array_equal(self.translation, other.translation))

    def __hash__(self) -> int:
        return hash((self.rotation.tobytes(), self.translation.tobytes()))

    @classmethod
    def from_xyz_rpy(cls, xyz: np.ndarray, rpy_rad: np.ndarray) -> Mount:
        """Mount from a position ``xyz`` (3,) [m] and fixed-axis roll/pitch/yaw ``rpy_rad`` (3,) [rad]."""
        return cls(rotation=rpy_to_matrix(rpy_rad), translation=np.asarray(xyz, dtype=float))


@dataclass(frozen=True)
class JointLimits:
    """Joint ranges [rad]. With ``continuous_pan`` (slip ring) the pan range is ignored."""

    pan_min: float = -np.pi
    pan_max: float = np.pi
    tilt_min: float = -np.pi / 2
    tilt_max: float = np.pi / 2
    continuous_pan: bool = False

    def clamp(self, pan: float, tilt: float) -> tuple[float, float]:
        """(pan, tilt) clamped into the limits (pan untouched when continuous)."""
        if not self.continuous_pan:
            pan = min(max(pan, self.pan_min), self.pan_max)
        return pan, min(max(tilt, self.tilt_min), self.tilt_max)

    def contains(self, pan: float, tilt: float, tol: float = _TOL) -> bool:
        """Whether (pan, tilt) lies inside the limits (within ``tol``)."""
        pan_ok = self.continuous_pan or (self.pan_min - tol <= pan <= self.pan_max + tol)
        return pan_ok and self.tilt_min - tol <= tilt <= self.tilt_max + tol


def base_from_world(body_quats: np.ndarray, mount: Mount) -> np.ndarray:
    """Rotations (N, 3, 3) or (3, 3) taking world vectors into the gimbal base frame.

    ``body_quats`` (N, 4) or (4,) are body→world attitudes (x, y, z, w). Result = (R_world_body · R_body_base)ᵀ.
    """
    R_wb = quat_to_matrix(np.asarray(body_quats, dtype=float))
    R_wbase = R_wb @ mount.rotation
    return np.swapaxes(R_wbase, -1, -2)


def joints_to_world_direction(pan: float, tilt: float, body_quat: np.ndarray, mount: Mount) -> np.ndarray:
    """Unit optical axis (3,) in the world frame for joint angles ``pan``, ``tilt`` [rad]."""
    d_base = pan_tilt_to_direction(pan, tilt)
    return base_from_world(body_quat, mount).T @ d_base


def camera_position(body_position: np.ndarray, body_quat: np.ndarray, mount: Mount) -> np.ndarray:
    """Sensor centre (3,) [m] in the world frame: the gimbal base origin of a body at ``body_position``."""
    R_wb = quat_to_matrix(np.asarray(body_quat, dtype=float))
    return np.asarray(body_position, dtype=float) + R_wb @ mount.translation


def _wrap_near(angle: float, reference: float) -> float:
    """The value angle + 2πk closest to ``reference``."""
    return reference + float(np.remainder(angle - reference + np.pi, 2.0 * np.pi) - np.pi)


def _pan_candidates(pan: float, reference: float, limits: JointLimits) -> list[float]:
    """Equivalent pan values (pan + 2πk) ordered by distance to ``reference``; inside the limits when bounded."""
    near = _wrap_near(pan, reference)
    if limits.continuous_pan:
        return [near]
    values = [near + 2.0 * np.pi * k for k in range(-2, 3)]
    inside = [v for v in values if limits.pan_min - _TOL <= v <= limits.pan_max + _TOL]
    return sorted(inside or values, key=lambda v: abs(v - reference))


def world_direction_to_joints(
    direction: np.ndarray,
    body_quat: np.ndarray,
    mount: Mount,
    limits: JointLimits,
    previous_pan: float | None = None,
) -> tuple[float, float, bool]:
    """Joint angles pointing the optical axis along the world ``direction`` (3,) for a body at ``body_quat`` (4,).

    Returns (pan, tilt, clamped) [rad]. Among the reachable solutions the one nearest ``previous_pan``
    (default: 0, or the middle of a range that excludes 0) is chosen; the primary solution (|tilt| ≤ π/2) is
    preferred over the over-the-top one. When no solution is reachable, the clamped joint values nearest
    ``previous_pan`` (when given; the end of the range the gimbal is at), and of those the ones whose axis is closest
    to the requested direction, are returned with ``clamped=True``.
    """
    d = np.asarray(direction, dtype=float)
    if d.shape != (3,) or not np.all(np.isfinite(d)) or np.linalg.norm(d) < 1e-12:
        raise ValueError(f"direction must be a finite non-zero 3-vector, got {direction!r}")
    d_base = base_from_world(body_quat, mount) @ d
    pan0, tilt0 = (float(v) for v in direction_to_pan_tilt(d_base))
    if previous_pan is not None:
        reference = float(previous_pan)
    elif limits.continuous_pan or limits.pan_min <= 0.0 <= limits.pan_max:
        reference = 0.0
    else:
        reference = 0.5 * (limits.pan_min + limits.pan_max)

    flipped_tilt = float(np.remainder(np.pi - tilt0 + np.pi, 2.0 * np.pi) - np.pi)
    branches = [(pan0, tilt0), (pan0 + np.pi, flipped_tilt)]
    for pan_b, tilt_b in branches:
        if not limits.tilt_min - _TOL <= tilt_b <= limits.tilt_max + _TOL:
            continue
        for pan_c in _pan_candidates(pan_b, reference, limits):
            if limits.contains(pan_c, tilt_b):
                pan_c, tilt_c = limits.clamp(pan_c, tilt_b)  # remove the tolerance slack
                return pan_c, tilt_c, False

    # Unreachable: with a previous pan, the clamped joints nearest it (held at the end of the range the gimbal is
    # at, not sent the long way round to the other end, which sees no more of a direction it cannot reach either);
    # of those, and without a previous pan, the ones whose axis is closest to the requested direction.
    best: tuple[float, float] | None = None
    best_key = (np.inf, np.inf)
    for pan_b, tilt_b in branches:
        for pan_c in _pan_candidates(pan_b, reference, limits):
            pan_k, tilt_k = limits.clamp(pan_c, tilt_b)
            err = float(angle_between(pan_tilt_to_direction(pan_k, tilt_k), d_base))
            key = (round(abs(pan_k - reference), 9) if previous_pan is not None else 0.0, err)
            if key[0] < best_key[0] or (key[0] == best_key[0] and err < best_key[1] - 1e-12):
                best, best_key = (pan_k, tilt_k), key
    assert best is not None
    return best[0], best[1], True


def world_directions_to_joints(
    directions: np.ndarray,
    body_quats: np.ndarray,
    mount: Mount,
    limits: JointLimits,
    previous_pan: float | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Joint angles for a sequence of world ``directions`` (N, 3) at attitudes ``body_quats`` (N, 4) or (4,).

    Each element is solved like :func:`world_direction_to_joints` with the previous element's pan as the
    reference, so a plan becomes a continuous joint trajectory (unwrapped for continuous pan).
    Returns pan (N,), tilt (N,) [rad] and clamped (N,) bool.
    """
    directions = np.asarray(directions, dtype=float).reshape(-1, 3)
    quats = np.broadcast_to(np.asarray(body_quats, dtype=float), (directions.shape[0], 4))
    pan = np.empty(directions.shape[0])
    tilt = np.empty(directions.shape[0])
    clamped = np.zeros(directions.shape[0], dtype=bool)
    reference = previous_pan
    for i in range(directions.shape[0]):
        pan[i], tilt[i], clamped[i] = world_direction_to_joints(directions[i], quats[i], mount, limits, reference)
        reference = float(pan[i])
    return pan, tilt, clamped
