"""PanTiltConstraint: reachability and nearest-point projection."""

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize, pan_tilt_to_direction, yaw_to_matrix
from pivotd.pivot.constraints import PanTiltConstraint


def _constraint(n, yaw=0.0, pan=(-1.0, 1.5), tilt=(-0.4, 0.7)):
    base_from_world = np.transpose(yaw_to_matrix(np.full(n, yaw)), (0, 2, 1))
    return PanTiltConstraint(base_from_world, pan[0], pan[1], tilt[0], tilt[1])


def _reachable_samples(con, k=400):
    pan = np.linspace(con.pan_min, con.pan_max, k) if not con.continuous else np.linspace(-np.pi, np.pi, k)
    tilt = np.linspace(con.tilt_min, con.tilt_max, k // 2)
    P, T = np.meshgrid(pan, tilt)
    return pan_tilt_to_direction(P.ravel(), T.ravel())  # base frame


@pytest.mark.parametrize("yaw", [0.0, 2.0])
def test_projection_is_reachable_and_nearest(yaw):
    rng = np.random.default_rng(0)
    n = 300
    con = _constraint(n, yaw)
    d = normalize(rng.normal(size=(n, 3)))
    p = con.project(d)
    assert np.allclose(np.linalg.norm(p, axis=1), 1)
    assert con.reachable(p).all()
    world_from_base = np.transpose(con.base_from_world, (0, 2, 1))
    samples = _reachable_samples(con) @ world_from_base[0].T
    best = np.min(np.arccos(np.clip(d @ samples.T, -1, 1)), axis=1)
    got = angle_between(d, p)
    assert np.all(got <= best + 1e-2)  # sample grid is ~0.6e-2 rad apart


def test_reachable_directions_are_unchanged():
    con = _constraint(50)
    rng = np.random.default_rng(1)
    pan = rng.uniform(con.pan_min, con.pan_max, 50)
    tilt = rng.uniform(con.tilt_min, con.tilt_max, 50)
    d = pan_tilt_to_direction(pan, tilt)
    assert con.reachable(d).all()
    assert np.allclose(con.project(d), d, atol=1e-12)


def test_unreachable_directions_are_detected():
    con = _constraint(3)
    d = np.array([[-1.0, 0, 0], [0, 0, -1.0], [np.cos(1.2), np.sin(1.2), 0]])  # behind, straight up, reachable
    assert con.reachable(d).tolist() == [False, False, True]


def test_continuous_pan_only_clamps_tilt():
    con = _constraint(2, pan=(-np.inf, np.inf), tilt=(-0.2, 0.2))
    d = np.array([[-1.0, 0, 0], [0.0, 0.0, 1.0]])
    p = con.project(d)
    assert np.allclose(p[0], [-1, 0, 0])
    assert con.reachable(p).all()
    assert np.degrees(angle_between(p[1], d[1])) == pytest.approx(90 - np.degrees(0.2), abs=1e-6)


def test_pan_range_wrapping_across_pi():
    con = _constraint(2, pan=(2.5, 3.8), tilt=(-0.5, 0.5))  # spans the ±π seam
    d = pan_tilt_to_direction(np.array([-3.0, 0.0]), np.array([0.0, 0.0]))
    assert con.reachable(d).tolist() == [True, False]


def test_bad_arguments():
    with pytest.raises(ValueError):
        PanTiltConstraint(np.zeros((2, 3)), -1, 1, -1, 1)
    with pytest.raises(ValueError):
        PanTiltConstraint(np.eye(3)[None], 1, -1, -1, 1)
    with pytest.raises(ValueError):
        _constraint(3).project(np.ones((2, 3)))
