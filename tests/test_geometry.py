import math

import numpy as np
import pytest

from pivotd import geometry as g


def _random_rotvecs(n, rng):
    axes = g.normalize(rng.normal(size=(n, 3)))
    return axes * rng.uniform(0, np.pi - 1e-3, size=(n, 1))


def test_exp_is_rotation_and_log_inverts():
    rng = np.random.default_rng(0)
    w = _random_rotvecs(500, rng)
    R = g.so3_exp(w)
    np.testing.assert_allclose(R @ np.swapaxes(R, -1, -2), np.broadcast_to(np.eye(3), R.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    np.testing.assert_allclose(g.so3_log(R), w, atol=1e-9)


def test_exp_matches_cross_product_for_small_angles():
    w = np.array([1e-9, -2e-9, 3e-9])
    v = np.array([0.3, 0.5, -0.2])
    np.testing.assert_allclose(g.so3_exp(w) @ v, v + np.cross(w, v), atol=1e-15)
    np.testing.assert_allclose(g.hat(w) @ v, np.cross(w, v))


def test_log_near_pi():
    axis = g.normalize(np.array([0.2, -0.7, 0.4]))
    w = axis * (np.pi - 1e-7)
    np.testing.assert_allclose(g.so3_exp(g.so3_log(g.so3_exp(w))), g.so3_exp(w), atol=1e-6)


def test_quaternion_round_trip_and_known_value():
    rng = np.random.default_rng(1)
    R = g.so3_exp(_random_rotvecs(200, rng))
    np.testing.assert_allclose(g.quat_to_matrix(g.matrix_to_quat(R)), R, atol=1e-12)
    # 90° about z: (x, y, z, w) = (0, 0, sin45, cos45) maps x -> y
    q = np.array([0, 0, np.sqrt(0.5), np.sqrt(0.5)])
    np.testing.assert_allclose(g.quat_to_matrix(q) @ [1, 0, 0], [0, 1, 0], atol=1e-12)
    np.testing.assert_allclose(g.yaw_to_matrix(np.pi / 2), g.quat_to_matrix(q), atol=1e-12)


@pytest.mark.parametrize(
    ("pan", "tilt", "expected"),
    [(0, 0, [1, 0, 0]), (np.pi / 2, 0, [0, 1, 0]), (0, np.pi / 4, [np.sqrt(0.5), 0, -np.sqrt(0.5)])],
)
def test_pan_tilt_convention(pan, tilt, expected):
    np.testing.assert_allclose(g.pan_tilt_to_direction(pan, tilt), expected, atol=1e-12)


def test_pan_tilt_round_trip():
    rng = np.random.default_rng(2)
    pan = rng.uniform(-np.pi + 1e-6, np.pi, 1000)
    tilt = rng.uniform(-np.pi / 2 + 1e-3, np.pi / 2 - 1e-3, 1000)
    p2, t2 = g.direction_to_pan_tilt(3.0 * g.pan_tilt_to_direction(pan, tilt))
    np.testing.assert_allclose(p2, pan, atol=1e-9)
    np.testing.assert_allclose(t2, tilt, atol=1e-9)


def test_optical_frame_axes():
    rng = np.random.default_rng(3)
    c = g.normalize(rng.normal(size=(100, 3)))
    c[0] = [0, 0, 1]  # parallel to the default up
    R = g.optical_frame_from_direction(c)
    np.testing.assert_allclose(R[..., :, 2], c, atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(R), 1.0, atol=1e-12)
    R1 = g.optical_frame_from_direction(np.array([1.0, 0, 0]))
    np.testing.assert_allclose(R1[:, 0], [0, -1, 0], atol=1e-12)  # image right = world -y
    np.testing.assert_allclose(R1[:, 1], [0, 0, -1], atol=1e-12)  # image down = world -z


def test_angle_between_accuracy():
    a = np.array([1.0, 0, 0])
    b = np.array([np.cos(1e-8), np.sin(1e-8), 0])
    assert abs(g.angle_between(a, b) - 1e-8) < 1e-15
    assert abs(g.angle_between(a, -a) - np.pi) < 1e-12


def _axis_rotation(axis: int, angle: float) -> np.ndarray:
    w = np.zeros(3)
    w[axis] = angle
    return g.so3_exp(w)


@pytest.mark.parametrize("axis", [0, 1, 2])
@pytest.mark.parametrize("angle_deg", [0.0, 90.0, 180.0, -90.0, 179.999])
def test_matrix_to_quat_about_each_axis(axis, angle_deg):
    """Exact quaternions at 0°, ±90° and 180° about x, y and z (180°: w = 0, the copysign trap)."""
    angle = np.radians(angle_deg)
    q = g.matrix_to_quat(_axis_rotation(axis, angle))
    expected = np.zeros(4)
    expected[axis] = np.sin(angle / 2)
    expected[3] = np.cos(angle / 2)
    if expected[3] < 0 or (expected[3] == 0 and expected[axis] < 0):
        expected = -expected
    np.testing.assert_allclose(q, expected, atol=1e-12)
    np.testing.assert_allclose(g.quat_to_matrix(q), _axis_rotation(axis, angle), atol=1e-12)


def test_matrix_to_quat_half_turns_about_oblique_axes():
    """Every 180° rotation round-trips, whatever its axis (w = 0: only the branch on the diagonal works)."""
    rng = np.random.default_rng(7)
    axes = g.normalize(rng.normal(size=(300, 3)))
    R = g.so3_exp(axes * np.pi)
    q = g.matrix_to_quat(R)
    np.testing.assert_allclose(np.abs(q[:, 3]), 0.0, atol=1e-7)
    np.testing.assert_allclose(g.quat_to_matrix(q), R, atol=1e-9)
    np.testing.assert_allclose(np.abs(np.sum(q[:, :3] * axes, axis=1)), 1.0, atol=1e-9)


def test_optical_frame_quaternion_keeps_the_optical_axis():
    """The camera frame looking along (0, −1, −0.01) is a near-half-turn; its quaternion must still look there."""
    c = g.normalize(np.array([0.0, -1.0, -0.01]))
    R = g.optical_frame_from_direction(c)
    q = g.matrix_to_quat(R)
    np.testing.assert_allclose(g.quat_to_matrix(q) @ [0.0, 0.0, 1.0], c, atol=1e-12)
    np.testing.assert_allclose(g.quat_to_matrix(q), R, atol=1e-12)


def test_matrix_to_quat_keeps_batch_shape():
    R = np.broadcast_to(np.eye(3), (2, 5, 3, 3))
    q = g.matrix_to_quat(R)
    assert q.shape == (2, 5, 4)
    np.testing.assert_allclose(q[..., 3], 1.0)


def test_matrix_to_quat_matches_scipy_on_random_and_half_turn_rotations():
    """scipy's Rotation is the reference (same (x, y, z, w) order and canonical sign)."""
    from scipy.spatial.transform import Rotation

    rng = np.random.default_rng(3)
    axes = g.normalize(rng.normal(size=(400, 3)))
    angles = np.concatenate([rng.uniform(0, np.pi, 200), np.full(100, np.pi), np.pi - rng.uniform(0, 1e-6, 100)])
    R = g.so3_exp(axes * angles[:, None])
    np.testing.assert_allclose(g.matrix_to_quat(R), Rotation.from_matrix(R).as_quat(canonical=True), atol=1e-9)


def test_slerp_moves_at_constant_speed_on_the_great_circle_even_between_opposite_directions():
    rng = np.random.default_rng(4)
    a, b = g.normalize(rng.normal(size=(200, 3))), g.normalize(rng.normal(size=(200, 3)))
    a[:3] = [[1.0, 0, 0], [0, 0, 1.0], [0.6, 0, 0.8]]
    b[:3] = -a[:3]  # opposite: level, vertical and oblique starts
    t = np.linspace(0.0, 1.0, 11)
    path = g.slerp(a[:, None, :], b[:, None, :], t[None, :])  # (200, 11, 3) by broadcasting
    np.testing.assert_allclose(np.linalg.norm(path, axis=-1), 1.0, atol=1e-12)
    np.testing.assert_allclose(path[:, 0], a, atol=1e-12)
    np.testing.assert_allclose(path[:, -1], b, atol=1e-9)
    steps = g.angle_between(path[:, 1:], path[:, :-1])
    np.testing.assert_allclose(steps, np.broadcast_to(g.angle_between(a, b)[:, None] / 10, steps.shape), atol=1e-9)
    # the half turn from a level direction stays level; from straight up it passes a horizontal direction
    np.testing.assert_allclose(path[0, :, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(path[1, 5, 2], 0.0, atol=1e-12)
    np.testing.assert_allclose(g.slerp(a[3], a[3], 0.3), a[3], atol=1e-12)


def _random_axes_with_poles(n, seed):
    c = g.normalize(np.random.default_rng(seed).normal(size=(n, 3)))
    c[:6] = g.normalize(np.array([[0, 0, 1], [0, 0, -1], [0, 1e-12, 1], [0.3, 0.2, 0.9], [0.5, 0, 0.85], [1, 0, 0.0]]))
    return c


@pytest.mark.parametrize("polar", [0.9, None])
def test_tangent_basis_is_a_right_handed_frame_level_away_from_the_poles(polar):
    c = _random_axes_with_poles(500, 4)
    t1, t2 = g.tangent_basis(c, polar=polar)
    F = np.stack([t1, t2, c], axis=-1)  # (n, 3, 3) columns t1, t2, c
    np.testing.assert_allclose(np.swapaxes(F, 1, 2) @ F, np.broadcast_to(np.eye(3), F.shape), atol=1e-12)
    np.testing.assert_allclose(np.linalg.det(F), 1.0, atol=1e-12)
    limit = 0.9 if polar is not None else 1.0 - 1e-15
    level = np.abs(c[:, 2]) < limit
    assert level.sum() > 400
    np.testing.assert_allclose(t1[level, 2], 0.0, atol=1e-15)  # c × e_z: horizontal
    np.testing.assert_allclose(t1[level], g.normalize(np.cross(c[level], [0.0, 0.0, 1.0])), atol=1e-15)
    np.testing.assert_allclose(t1[~level], g.normalize(np.cross(c[~level], [1.0, 0.0, 0.0])), atol=1e-15)


def test_tangent_basis_of_one_axis_is_the_array_result_bit_for_bit():
    c = _random_axes_with_poles(300, 5)
    for polar in (0.9, None):
        t1, t2 = g.tangent_basis(c, polar=polar)
        for k in range(c.shape[0]):
            s1, s2 = g.tangent_basis(c[k], polar=polar)
            assert s1.shape == s2.shape == (3,)
            assert np.array_equal(s1, t1[k]) and np.array_equal(s2, t2[k]), (k, polar)


def test_optical_frame_is_the_level_tangent_basis():
    c = _random_axes_with_poles(200, 6) * 3.0  # any length: the frame normalises the axis first
    z = g.normalize(c)
    t1, t2 = g.tangent_basis(z, polar=None)
    assert np.array_equal(g.optical_frame_from_direction(c), np.stack([t1, t2, z], axis=-1))
    assert g.optical_frame_from_direction(c[3]).shape == (3, 3)


def test_slerp_between_opposite_vertical_directions_turns_through_the_horizontal():
    up = np.array([0.0, 1e-8, 1.0]) / np.hypot(1e-8, 1.0)
    mid = g.slerp(up, -up, 0.5)
    assert abs(mid[2]) < 1e-7 and abs(float(mid @ up)) < 1e-12  # a level direction ⟂ up, as for any other axis


def test_quat_slerp_turns_at_constant_angular_speed_the_short_way():
    from pivotd.geometry import quat_angles, quat_slerp

    a = np.array([0.0, 0.0, 0.0, 1.0])
    b = -np.array([0.0, 0.0, math.sin(math.radians(60)), math.cos(math.radians(60))])  # 120° about z, other sign
    q = quat_slerp(a, b, np.linspace(0.0, 1.0, 5))
    np.testing.assert_allclose(np.degrees(quat_angles(a, q)), [0.0, 30.0, 60.0, 90.0, 120.0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(q, axis=1), 1.0)
    np.testing.assert_allclose(quat_slerp(a, a, np.array([0.5])), [a])
