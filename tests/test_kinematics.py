"""Gimbal kinematics: round trips, attitude compensation, unwrapping, clamping."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pivotd.geometry import angle_between, matrix_to_quat, normalize, pan_tilt_to_direction, so3_exp
from pivotd.gimbal.kinematics import (
    JointLimits,
    Mount,
    base_from_world,
    camera_position,
    joints_to_world_direction,
    rpy_to_matrix,
    world_direction_to_joints,
    world_directions_to_joints,
)

WIDE = JointLimits(pan_min=-np.pi, pan_max=np.pi, tilt_min=-np.pi / 2, tilt_max=np.pi / 2)


def random_quat(rng: np.random.Generator) -> np.ndarray:
    q = rng.normal(size=4)
    return q / np.linalg.norm(q)


def random_mount(rng: np.random.Generator) -> Mount:
    return Mount.from_xyz_rpy(rng.uniform(-0.5, 0.5, 3), rng.uniform(-np.pi, np.pi, 3))


def test_rpy_matches_exponential_map_composition():
    r, p, y = 0.3, -0.4, 1.1
    expected = so3_exp([0, 0, y]) @ so3_exp([0, p, 0]) @ so3_exp([r, 0, 0])
    np.testing.assert_allclose(rpy_to_matrix([r, p, y]), expected, atol=1e-12)


def test_round_trip_random_attitudes_and_mounts():
    rng = np.random.default_rng(1)
    for _ in range(300):
        q = random_quat(rng)
        mount = random_mount(rng)
        d = normalize(rng.normal(size=3))
        pan, tilt, clamped = world_direction_to_joints(d, q, mount, WIDE)
        assert not clamped
        assert -np.pi <= pan <= np.pi and -np.pi / 2 <= tilt <= np.pi / 2
        back = joints_to_world_direction(pan, tilt, q, mount)
        assert float(angle_between(back, d)) < 1e-9


def test_joints_round_trip_from_joint_space():
    rng = np.random.default_rng(2)
    for _ in range(200):
        q = random_quat(rng)
        mount = random_mount(rng)
        pan, tilt = rng.uniform(-3.0, 3.0), rng.uniform(-1.5, 1.5)
        d = joints_to_world_direction(pan, tilt, q, mount)
        p2, t2, clamped = world_direction_to_joints(d, q, mount, WIDE, previous_pan=pan)
        assert not clamped
        assert p2 == pytest.approx(pan, abs=1e-9)
        assert t2 == pytest.approx(tilt, abs=1e-9)


def test_base_from_world_batch_matches_single():
    rng = np.random.default_rng(3)
    quats = np.array([random_quat(rng) for _ in range(5)])
    mount = random_mount(rng)
    batch = base_from_world(quats, mount)
    assert batch.shape == (5, 3, 3)
    for i in range(5):
        np.testing.assert_allclose(batch[i], base_from_world(quats[i], mount), atol=1e-12)
        np.testing.assert_allclose(batch[i] @ batch[i].T, np.eye(3), atol=1e-12)


def test_body_yaw_is_compensated():
    """A world target straight ahead of the map +x axis: a body yawed by +40° must pan by −40°."""
    mount = Mount()
    yaw = np.deg2rad(40.0)
    q = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])
    pan, tilt, clamped = world_direction_to_joints(np.array([1.0, 0.0, 0.0]), q, mount, WIDE)
    assert not clamped
    assert pan == pytest.approx(-yaw, abs=1e-12)
    assert tilt == pytest.approx(0.0, abs=1e-12)


def test_body_pitch_is_compensated():
    """Body pitched nose-down by 10° (positive pitch about +y): a level target needs tilt −10° (up)."""
    pitch = np.deg2rad(10.0)
    q = matrix_to_quat(so3_exp([0.0, pitch, 0.0]))
    pan, tilt, _ = world_direction_to_joints(np.array([1.0, 0.0, 0.0]), q, Mount(), WIDE)
    assert pan == pytest.approx(0.0, abs=1e-8)
    assert tilt == pytest.approx(-pitch, abs=1e-8)


def test_mount_rotation_is_applied():
    """Gimbal mounted looking backwards (yaw π): a world +x target is reached with pan ±π."""
    mount = Mount.from_xyz_rpy([0, 0, 0], [0, 0, np.pi])
    pan, tilt, clamped = world_direction_to_joints(np.array([1.0, 0, 0]), np.array([0, 0, 0, 1.0]), mount, WIDE)
    assert abs(abs(pan) - np.pi) < 1e-9 and abs(tilt) < 1e-12 and not clamped
    # Base +x (pan = tilt = 0) is world −x for this mount.
    np.testing.assert_allclose(joints_to_world_direction(0.0, 0.0, np.array([0, 0, 0, 1.0]), mount), [-1, 0, 0],
                               atol=1e-12)


def test_continuous_pan_unwraps_across_pi():
    limits = JointLimits(pan_min=-np.pi, pan_max=np.pi, tilt_min=-1.0, tilt_max=1.0, continuous_pan=True)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    previous = 0.0
    pans = []
    for heading in np.linspace(0.0, 4.0 * np.pi, 161):  # two full turns counter-clockwise
        d = np.array([np.cos(heading), np.sin(heading), 0.0])
        previous, _, clamped = world_direction_to_joints(d, q, Mount(), limits, previous_pan=previous)
        assert not clamped
        pans.append(previous)
    np.testing.assert_allclose(pans, np.linspace(0.0, 4.0 * np.pi, 161), atol=1e-9)


def test_bounded_pan_stays_in_range_beyond_pi():
    """A range of [−π/2, 3π/2] must reach direction pan = −170° as +190°, never outside the range."""
    limits = JointLimits(pan_min=-np.pi / 2, pan_max=1.5 * np.pi, tilt_min=-1.0, tilt_max=1.0)
    d = pan_tilt_to_direction(np.deg2rad(-170.0), 0.2)
    pan, tilt, clamped = world_direction_to_joints(d, np.array([0, 0, 0, 1.0]), Mount(), limits, previous_pan=3.0)
    assert not clamped
    assert pan == pytest.approx(np.deg2rad(190.0), abs=1e-9)
    assert tilt == pytest.approx(0.2, abs=1e-12)


def test_nearest_equivalent_to_previous_pan_within_limits():
    limits = JointLimits(pan_min=-2 * np.pi, pan_max=2 * np.pi, tilt_min=-1.0, tilt_max=1.0)
    d = pan_tilt_to_direction(np.deg2rad(170.0), 0.0)
    q = np.array([0, 0, 0, 1.0])
    pan_a, _, _ = world_direction_to_joints(d, q, Mount(), limits, previous_pan=np.deg2rad(-175.0))
    pan_b, _, _ = world_direction_to_joints(d, q, Mount(), limits, previous_pan=np.deg2rad(160.0))
    assert pan_a == pytest.approx(np.deg2rad(-190.0), abs=1e-9)
    assert pan_b == pytest.approx(np.deg2rad(170.0), abs=1e-9)


def test_clamping_reports_and_stays_inside_limits():
    limits = JointLimits(pan_min=np.deg2rad(-90), pan_max=np.deg2rad(90), tilt_min=np.deg2rad(-30),
                         tilt_max=np.deg2rad(60))
    q = np.array([0, 0, 0, 1.0])
    # Straight up: needs tilt −90°, limit is −30°.
    pan, tilt, clamped = world_direction_to_joints(np.array([0.2, 0.0, 1.0]), q, Mount(), limits)
    assert clamped
    assert tilt == pytest.approx(np.deg2rad(-30), abs=1e-12)
    assert pan == pytest.approx(0.0, abs=1e-12)
    # Behind and left at pan 135°: pan clamps to 90°, tilt kept.
    d = pan_tilt_to_direction(np.deg2rad(135), np.deg2rad(20))
    pan, tilt, clamped = world_direction_to_joints(d, q, Mount(), limits)
    assert clamped
    assert pan == pytest.approx(np.deg2rad(90), abs=1e-12)
    assert tilt == pytest.approx(np.deg2rad(20), abs=1e-12)
    # A reachable target is not clamped.
    d = pan_tilt_to_direction(np.deg2rad(45), np.deg2rad(50))
    pan, tilt, clamped = world_direction_to_joints(d, q, Mount(), limits)
    assert not clamped and pan == pytest.approx(np.deg2rad(45)) and tilt == pytest.approx(np.deg2rad(50))


def test_a_direction_in_the_dead_sector_is_held_at_the_end_of_the_range_the_gimbal_is_at():
    """A ±170° pan unit at −165° whose target drifts behind it to 175° (−185°): 5° from the +170° end, 15° from the
    −170° one. Holding −170° costs 10° more of view; going to +170° sweeps 335° through the whole range."""
    limits = JointLimits(pan_min=np.deg2rad(-170), pan_max=np.deg2rad(170), tilt_min=np.deg2rad(-45),
                         tilt_max=np.deg2rad(45))
    q = np.array([0, 0, 0, 1.0])
    d = pan_tilt_to_direction(np.deg2rad(175), 0.0)
    pan, tilt, clamped = world_direction_to_joints(d, q, Mount(), limits, previous_pan=np.deg2rad(-165))
    assert clamped and pan == pytest.approx(np.deg2rad(-170), abs=1e-12) and tilt == pytest.approx(0.0, abs=1e-12)
    pan, _, clamped = world_direction_to_joints(d, q, Mount(), limits, previous_pan=np.deg2rad(150))
    assert clamped and pan == pytest.approx(np.deg2rad(170), abs=1e-12)
    # without a previous pan: the end whose axis is closest
    pan, _, clamped = world_direction_to_joints(d, q, Mount(), limits)
    assert clamped and pan == pytest.approx(np.deg2rad(170), abs=1e-12)


def test_over_the_top_solution_used_when_pan_range_excludes_primary():
    """Tilt range past vertical lets a ±90° pan unit look backwards over the top."""
    limits = JointLimits(pan_min=np.deg2rad(-90), pan_max=np.deg2rad(90), tilt_min=np.deg2rad(-180),
                         tilt_max=np.deg2rad(30))
    d = pan_tilt_to_direction(np.pi, np.deg2rad(-20))  # behind, 20° up
    q = np.array([0, 0, 0, 1.0])
    pan, tilt, clamped = world_direction_to_joints(d, q, Mount(), limits)
    assert not clamped
    assert limits.contains(pan, tilt)
    assert float(angle_between(pan_tilt_to_direction(pan, tilt), d)) < 1e-9


def test_random_clamping_never_leaves_limits_and_is_best_effort():
    rng = np.random.default_rng(5)
    limits = JointLimits(pan_min=np.deg2rad(-120), pan_max=np.deg2rad(120), tilt_min=np.deg2rad(-45),
                         tilt_max=np.deg2rad(70))
    for _ in range(300):
        q = random_quat(rng)
        mount = random_mount(rng)
        d = normalize(rng.normal(size=3))
        pan, tilt, clamped = world_direction_to_joints(d, q, mount, limits, previous_pan=rng.uniform(-2, 2))
        assert limits.contains(pan, tilt, tol=0.0)
        err = float(angle_between(joints_to_world_direction(pan, tilt, q, mount), d))
        if not clamped:
            assert err < 1e-9
        else:
            assert err > 1e-9


def test_camera_position_uses_body_attitude():
    mount = Mount.from_xyz_rpy([0.3, 0.0, 0.2], [0, 0, 0])
    yaw = np.pi / 2
    q = np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])
    np.testing.assert_allclose(camera_position([1.0, 2.0, 0.5], q, mount), [1.0, 2.3, 0.7], atol=1e-12)


def test_rejects_degenerate_direction():
    with pytest.raises(ValueError):
        world_direction_to_joints(np.zeros(3), np.array([0, 0, 0, 1.0]), Mount(), WIDE)
    with pytest.raises(ValueError):
        world_direction_to_joints(np.array([np.nan, 0, 1]), np.array([0, 0, 0, 1.0]), Mount(), WIDE)


def test_sequence_is_continuous_and_matches_single_calls():
    limits = JointLimits(pan_min=-2 * np.pi, pan_max=2 * np.pi, tilt_min=-1.0, tilt_max=1.0)
    headings = np.linspace(0.0, 1.8 * np.pi, 50)  # sweeps past +π
    dirs = np.stack([np.cos(headings), np.sin(headings), np.full(50, -0.2)], axis=1)
    q = np.array([0.0, 0.0, 0.0, 1.0])
    pan, tilt, clamped = world_directions_to_joints(dirs, q, Mount(), limits)
    assert not clamped.any()
    assert np.all(np.abs(np.diff(pan)) < 0.2)  # no jump of 2π at ±π
    np.testing.assert_allclose(pan, headings, atol=1e-9)
    single = world_direction_to_joints(dirs[10], q, Mount(), limits, previous_pan=pan[9])
    assert single[0] == pytest.approx(pan[10]) and single[1] == pytest.approx(tilt[10])


@settings(max_examples=200, deadline=None)
@given(
    q=st.lists(st.floats(-1, 1), min_size=4, max_size=4).filter(lambda v: np.linalg.norm(v) > 0.1),
    rpy=st.lists(st.floats(-np.pi, np.pi), min_size=3, max_size=3),
    pan=st.floats(-3.0, 3.0),
    tilt=st.floats(-1.5, 1.5),
)
def test_property_joint_round_trip(q, rpy, pan, tilt):
    mount = Mount.from_xyz_rpy([0.1, 0.0, 0.2], rpy)
    d = joints_to_world_direction(pan, tilt, np.array(q), mount)
    p2, t2, clamped = world_direction_to_joints(d, np.array(q), mount, WIDE, previous_pan=pan)
    assert not clamped
    assert float(angle_between(joints_to_world_direction(p2, t2, np.array(q), mount), d)) < 1e-9
    assert abs(t2 - tilt) < 1e-7 and abs(p2 - pan) < 1e-6
