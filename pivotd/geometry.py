"""SO(3) / S² helpers, quaternions and the pan/tilt convention (pure numpy).

Conventions (docs/ARCHITECTURE.md): REP-103 frames (x forward, y left, z up), quaternions
ordered (x, y, z, w), angles in radians. Gimbal joints: pan rotates about the base +z, tilt
about the panned +y (positive tilt points the camera down); at pan = tilt = 0 the optical
axis is the base +x. All functions broadcast over leading dimensions.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-12


def hat(w: np.ndarray) -> np.ndarray:
    """Skew-symmetric matrix ω^ of vectors ``w`` (..., 3) -> (..., 3, 3), so that ω^ v = ω × v."""
    w = np.asarray(w, dtype=float)
    out = np.zeros((*w.shape[:-1], 3, 3))
    out[..., 0, 1] = -w[..., 2]
    out[..., 0, 2] = w[..., 1]
    out[..., 1, 0] = w[..., 2]
    out[..., 1, 2] = -w[..., 0]
    out[..., 2, 0] = -w[..., 1]
    out[..., 2, 1] = w[..., 0]
    return out


def so3_exp(w: np.ndarray) -> np.ndarray:
    """Exponential map exp(ω^) (Rodrigues) of rotation vectors ``w`` (..., 3) [rad] -> (..., 3, 3)."""
    w = np.asarray(w, dtype=float)
    theta = np.linalg.norm(w, axis=-1)[..., None, None]
    K = hat(w)
    small = theta < 1e-8
    safe = np.where(small, 1.0, theta)
    a = np.where(small, 1.0 - theta**2 / 6.0, np.sin(safe) / safe)
    b = np.where(small, 0.5 - theta**2 / 24.0, (1.0 - np.cos(safe)) / safe**2)
    eye = np.broadcast_to(np.eye(3), K.shape)
    return eye + a * K + b * (K @ K)


def so3_log(R: np.ndarray) -> np.ndarray:
    """Logarithm map of rotations ``R`` (..., 3, 3) -> rotation vectors (..., 3) [rad]."""
    R = np.asarray(R, dtype=float)
    cos_t = np.clip((np.trace(R, axis1=-2, axis2=-1) - 1.0) / 2.0, -1.0, 1.0)
    theta = np.arccos(cos_t)
    v = np.stack([R[..., 2, 1] - R[..., 1, 2], R[..., 0, 2] - R[..., 2, 0], R[..., 1, 0] - R[..., 0, 1]], -1)
    sin_t = np.sin(theta)
    near_pi = theta > np.pi - 1e-4
    scale = np.where(theta < 1e-8, 0.5, theta / (2.0 * np.where(sin_t == 0, 1.0, sin_t)))
    out = v * scale[..., None]
    if np.any(near_pi):
        # Axis from the diagonal of (R + I) / 2 = a a^T when theta ~ pi.
        B = (R[near_pi] + np.eye(3)) / 2.0
        idx = np.argmax(np.diagonal(B, axis1=-2, axis2=-1), axis=-1)
        axis = B[np.arange(B.shape[0]), :, idx]
        axis /= np.linalg.norm(axis, axis=-1, keepdims=True)
        sign = np.sign(np.sum(axis * v[near_pi], axis=-1))
        sign[sign == 0] = 1.0
        out[near_pi] = axis * (sign * theta[near_pi])[..., None]
    return out


def normalize(v: np.ndarray, axis: int = -1) -> np.ndarray:
    """Unit vectors along ``axis``; zero vectors stay zero."""
    v = np.asarray(v, dtype=float)
    n = np.linalg.norm(v, axis=axis, keepdims=True)
    return v / np.where(n < _EPS, 1.0, n)


def angle_between(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Angle [rad] between vectors ``a`` and ``b`` (..., 3), accurate near 0 and π."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    return np.arctan2(np.linalg.norm(np.cross(a, b), axis=-1), np.sum(a * b, axis=-1))


def slerp(a: np.ndarray, b: np.ndarray, t: np.ndarray | float) -> np.ndarray:
    """Unit vectors (..., 3) a fraction ``t`` (...) of the way from unit ``a`` to unit ``b`` (..., 3) along the
    great circle, at constant angular speed. Opposite ``a`` and ``b`` turn through the level perpendicular
    ``a × z`` (``a × x`` when ``a`` is vertical; :func:`tangent_basis`): level for a camera that looks level."""
    a = np.asarray(a, dtype=float)
    b = np.asarray(b, dtype=float)
    t = np.asarray(t, dtype=float)[..., None]
    a, b, t = np.broadcast_arrays(a, b, t)
    t = t[..., :1]
    omega = angle_between(a, b)[..., None]
    opposite = np.pi - omega < 1e-6
    if np.any(opposite):  # two quarter turns: a -> perp -> -a
        perp = a.copy()
        sel = opposite[..., 0]
        perp[sel] = tangent_basis(a[sel], polar=None)[0]
        second = opposite & (t > 0.5)
        a, b = np.where(second, perp, a), np.where(opposite, np.where(second, -a, perp), b)
        t = np.where(opposite, np.where(second, 2.0 * t - 1.0, 2.0 * t), t)
        omega = np.where(opposite, np.pi / 2, omega)
    small = omega < 1e-6
    sin_o = np.where(small, 1.0, np.sin(omega))
    wa = np.where(small, 1.0 - t, np.sin((1.0 - t) * omega) / sin_o)
    wb = np.where(small, t, np.sin(t * omega) / sin_o)
    return normalize(wa * a + wb * b)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """Rotation matrices (..., 3, 3) from quaternions (..., 4) ordered (x, y, z, w); normalizes q."""
    q = normalize(np.asarray(q, dtype=float))
    x, y, z, w = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    R = np.empty((*q.shape[:-1], 3, 3))
    R[..., 0, 0] = 1 - 2 * (y * y + z * z)
    R[..., 0, 1] = 2 * (x * y - z * w)
    R[..., 0, 2] = 2 * (x * z + y * w)
    R[..., 1, 0] = 2 * (x * y + z * w)
    R[..., 1, 1] = 1 - 2 * (x * x + z * z)
    R[..., 1, 2] = 2 * (y * z - x * w)
    R[..., 2, 0] = 2 * (x * z - y * w)
    R[..., 2, 1] = 2 * (y * z + x * w)
    R[..., 2, 2] = 1 - 2 * (x * x + y * y)
    return R


def matrix_to_quat(R: np.ndarray) -> np.ndarray:
    """Quaternions (..., 4) ordered (x, y, z, w) from rotation matrices (..., 3, 3), canonical: w > 0, or for
    half-turns (w = 0) the first non-zero component positive (as scipy's ``as_quat(canonical=True)``).

    Shepperd's method: each matrix is converted on the branch of its largest of (trace, R00, R11, R22), so
    the divisor is at least 1/2 and rotations by 180° (where the off-diagonal differences vanish and carry
    no sign) come out right.
    """
    R = np.asarray(R, dtype=float)
    m = R.reshape(-1, 3, 3)
    m00, m11, m22 = m[:, 0, 0], m[:, 1, 1], m[:, 2, 2]
    branch = np.argmax(np.stack([m00 + m11 + m22, m00, m11, m22], axis=1), axis=1)
    d21, d02, d10 = m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]
    s01, s02, s12 = m[:, 0, 1] + m[:, 1, 0], m[:, 0, 2] + m[:, 2, 0], m[:, 1, 2] + m[:, 2, 1]
    # Four times the quaternion on each branch: (x, y, z, w) scaled by 4·(the branch's own component).
    big = np.sqrt(np.maximum(1.0 + np.choose(branch, [m00 + m11 + m22, m00 - m11 - m22, m11 - m00 - m22,
                                                      m22 - m00 - m11]), 0.0))
    q = np.choose(branch[:, None], [
        np.stack([d21, d02, d10, big * big], axis=1),
        np.stack([big * big, s01, s02, d21], axis=1),
        np.stack([s01, big * big, s12, d02], axis=1),
        np.stack([s02, s12, big * big, d10], axis=1),
    ])
    q = q / (2.0 * big[:, None])
    # Canonical sign: the first non-zero of (w, x, y, z) positive.
    order = q[:, [3, 0, 1, 2]]
    first = np.argmax(order != 0.0, axis=1)
    q = np.where(order[np.arange(q.shape[0]), first][:, None] < 0, -q, q)
    return normalize(q).reshape(*R.shape[:-2], 4)


def yaw_to_matrix(yaw: np.ndarray) -> np.ndarray:
    """Rotations about +z by ``yaw`` [rad] (...,) -> (..., 3, 3)."""
    yaw = np.asarray(yaw, dtype=float)
    c, s = np.cos(yaw), np.sin(yaw)
    R = np.zeros((*yaw.shape, 3, 3))
    R[..., 0, 0] = c
    R[..., 0, 1] = -s
    R[..., 1, 0] = s
    R[..., 1, 1] = c
    R[..., 2, 2] = 1.0
    return R


def quat_angles(q1: np.ndarray, q2: np.ndarray) -> np.ndarray:
    """Rotation angles [rad] in [0, π] between unit quaternions ``q1`` and ``q2`` (..., 4) (x, y, z, w)."""
    dot = np.abs(np.einsum("...i,...i->...", np.asarray(q1, float), np.asarray(q2, float)))
    return 2.0 * np.arccos(np.minimum(dot, 1.0))


def quat_slerp(q1: np.ndarray, q2: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Unit quaternions (K, 4) (x, y, z, w) a fraction ``t`` (K,) of the shorter rotation from unit ``q1`` to ``q2``
    (4,), at constant angular speed."""
    a = np.asarray(q1, float)
    b = np.asarray(q2, float)
    if float(np.dot(a, b)) < 0.0:
        b = -b
    t = np.asarray(t, float)[:, None]
    omega = float(np.arccos(min(float(np.dot(a, b)), 1.0)))
    if omega < 1e-9:
        return normalize(np.broadcast_to(a, (t.shape[0], 4)).copy())
    return normalize((np.sin((1.0 - t) * omega) * a + np.sin(t * omega) * b) / np.sin(omega))


def pan_tilt_to_direction(pan: np.ndarray, tilt: np.ndarray) -> np.ndarray:
    """Unit optical axis in the gimbal base frame (..., 3) for joint angles ``pan``, ``tilt`` [rad].

    d = Rz(pan) Ry(tilt) x̂ = (cos p cos t, sin p cos t, −sin t): positive tilt points down.
    """
    pan = np.asarray(pan, dtype=float)
    tilt = np.asarray(tilt, dtype=float)
    ct = np.cos(tilt)
    return np.stack([np.cos(pan) * ct, np.sin(pan) * ct, -np.sin(tilt)], axis=-1)


def direction_to_pan_tilt(d: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Joint angles (pan ∈ (−π, π], tilt ∈ [−π/2, π/2]) [rad] pointing the axis along ``d`` (..., 3).

    Inverse of :func:`pan_tilt_to_direction`; ``d`` need not be normalized. Straight up/down
    (a singularity of the pan/tilt chart) returns pan = 0.
    """
    d = np.asarray(d, dtype=float)
    horiz = np.hypot(d[..., 0], d[..., 1])
    pan = np.where(horiz < 1e-12, 0.0, np.arctan2(d[..., 1], d[..., 0]))
    tilt = np.arctan2(-d[..., 2], horiz)
    return pan, tilt


def tangent_basis(c: np.ndarray, polar: float | None = 0.9) -> tuple[np.ndarray, np.ndarray]:
    """Two unit tangents t1, t2 (..., 3) at unit axes c (..., 3), with (t1, t2, c) a right-handed orthonormal frame.

    t1 = c × e_z / |c × e_z| (level), or c × e_x / |c × e_x| where |c_z| ≥ ``polar`` or c × e_z vanishes
    (|c × e_z| < 1e-9); t2 = c × t1. ``polar`` 0.9 keeps t1 well conditioned (rings and spirals of candidate
    directions); None keeps it level wherever it can be (camera frames). A single axis (3,) is computed with
    scalars (the array path costs tens of µs of call overhead), with the same floating-point operations.
    """
    c = np.asarray(c, dtype=float)
    if c.shape == (3,):
        x, y, z = (float(v) for v in c)
        tx, ty, tz = y, -x, 0.0  # c × e_z
        n = np.sqrt(tx * tx + ty * ty)
        if n < 1e-9 or (polar is not None and abs(z) >= polar):
            tx, ty, tz = 0.0, z, -y  # c × e_x
            n = np.sqrt(ty * ty + tz * tz)
        tx, ty, tz = tx / n, ty / n, tz / n
        return np.array([tx, ty, tz]), np.array([y * tz - z * ty, z * tx - x * tz, x * ty - y * tx])
    t1 = np.zeros(c.shape)
    t1[..., 0], t1[..., 1] = c[..., 1], -c[..., 0]
    n = np.sqrt(np.square(t1[..., 0]) + np.square(t1[..., 1]))
    off = n < 1e-9
    if polar is not None:
        off |= np.abs(c[..., 2]) >= polar
    if np.any(off):
        t1[off] = 0.0
        t1[off, 1], t1[off, 2] = c[off, 2], -c[off, 1]
        n[off] = np.sqrt(np.square(t1[off, 1]) + np.square(t1[off, 2]))
    t1 /= n[..., None]
    return t1, np.cross(c, t1)


def optical_frame_from_direction(c: np.ndarray) -> np.ndarray:
    """Camera-to-world rotations (..., 3, 3) whose +z (optical axis, e₃) is ``c`` (..., 3).

    ROS optical convention: x right, y down, z forward. The image "up" (−y) is kept as close as possible to
    world +z (x = c × e_z, :func:`tangent_basis` with ``polar`` None); when ``c`` is vertical, x = c × e_x.
    """
    z = normalize(c)
    x, y = tangent_basis(z, polar=None)
    return np.stack([x, y, z], axis=-1)


MAX_COORDINATE = 1e7  # [m]: positions beyond this (10 000 km) are refused as out of range (maps, paths, poses)


def safe_unit_quats(q: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(unit quaternions (N, 4), usable (N,) bool) of quaternions ``q`` (N, 4), scaled by their largest
    component first so that finite values of any magnitude (1e300 or 1e-300) normalise without overflow;
    rows that are non-finite or zero are unusable (returned as given)."""
    q = np.asarray(q, dtype=float).reshape(-1, 4)
    with np.errstate(over="ignore", invalid="ignore"):
        scale = np.max(np.abs(q), axis=1)
        usable = np.isfinite(q).all(axis=1) & (scale > 0)
        r = q / np.where(usable, scale, 1.0)[:, None]
        norms = np.where(usable, np.sqrt(np.einsum("ij,ij->i", r, r)), 1.0)
    return np.where(usable[:, None], r / norms[:, None], q), usable
