"""Projection, line of sight (occlusion, depth range, incidence) and observations of the simulated camera."""

import math

import numpy as np
import pytest

from pivotd.errors import InputError
from pivotd.localization.camera import (
    CameraModel,
    camera_rotation,
    in_view_counts,
    line_of_sight,
    observe,
    project,
    visible,
)
from pivotd.localization.stack import OccupancyGrid

CAM = CameraModel(detection_probability=1.0, pixel_noise=0.0, outlier_ratio=0.0)
ORIGIN = np.zeros(3)


def test_projection_of_constructed_points_looking_along_world_x():
    R = camera_rotation(np.array([1.0, 0.0, 0.0]))
    pts = np.array([
        [5.0, 0.0, 0.0],   # on the axis: principal point
        [5.0, -1.0, 0.0],  # to the right (world −y): u = cx + fx·1/5
        [5.0, 0.0, 1.0],   # up: v = cy − fy·1/5
        [-5.0, 0.0, 0.0],  # behind
        [12.0, 0.0, 0.0],  # beyond max_depth (10 m)
        [5.0, 4.0, 0.0],   # outside the image (u = 320 − 400 < 0)
        [0.2, 0.0, 0.0],   # closer than min_depth
    ])
    uv, depth, inside = project(CAM, R, ORIGIN, pts)
    np.testing.assert_allclose(uv[:3], [[320, 240], [420, 240], [320, 140]], atol=1e-9)
    np.testing.assert_allclose(depth[:3], 5.0)
    assert inside.tolist() == [True, True, True, False, False, False, False]


def test_roll_is_level_for_a_tilted_view():
    d = np.array([math.cos(0.4), 0.0, math.sin(0.4)])  # looking 23° up along +x
    R = camera_rotation(d)
    x_axis = R[:, 0]  # image right
    assert abs(x_axis[2]) < 1e-12  # no roll: the image x axis stays horizontal
    np.testing.assert_allclose(R[:, 2], d, atol=1e-12)


def test_in_view_counts_match_per_orientation_projection():
    rng = np.random.default_rng(1)
    pts = rng.uniform(-6, 6, (300, 3))
    dirs = rng.normal(size=(20, 3))
    R = camera_rotation(dirs / np.linalg.norm(dirs, axis=1, keepdims=True))
    counts = in_view_counts(CAM, R, ORIGIN, pts)
    expected = [int(project(CAM, r, ORIGIN, pts)[2].sum()) for r in R]
    assert counts.tolist() == expected
    assert max(expected) > 0


def _wall_grid(x: float, voxel: float = 0.2) -> OccupancyGrid:
    y, z = np.meshgrid(np.arange(-3, 3, 0.1), np.arange(-2, 2, 0.1))
    wall = np.column_stack([np.full(y.size, x), y.ravel(), z.ravel()])
    return OccupancyGrid.from_points(wall, voxel)


def test_wall_occludes_landmarks_behind_it_only():
    grid = _wall_grid(3.0)
    pts = np.array([[2.0, 0.0, 0.0], [5.0, 0.0, 0.0], [5.0, 0.5, 0.3], [5.0, 6.5, 0.0]])
    sight = line_of_sight(CAM, grid, ORIGIN, pts)
    # in front of the wall; behind it (twice); behind, but the sight line passes the wall's end (y = 3.9 at x = 3)
    assert sight.tolist() == [0, 3]
    assert line_of_sight(CAM, None, ORIGIN, pts).tolist() == [0, 1, 2, 3]


def test_depth_range_and_incidence_limit():
    pts = np.array([[4.0, 0.0, 0.0], [4.0, 0.0, 0.0], [4.0, 0.0, 0.0], [11.0, 0.0, 0.0], [0.1, 0.0, 0.0]])
    normals = np.array([
        [-1.0, 0.0, 0.0],  # faces the camera
        [1.0, 0.0, 0.0],  # faces away
        [-math.cos(math.radians(80)), math.sin(math.radians(80)), 0.0],  # seen 80° off its normal (> 75°)
        [-1.0, 0.0, 0.0],  # too far
        [-1.0, 0.0, 0.0],  # too close
    ])
    assert line_of_sight(CAM, None, ORIGIN, pts, normals).tolist() == [0]
    no_limit = CameraModel(max_incidence_deg=None)
    assert line_of_sight(no_limit, None, ORIGIN, pts, normals).tolist() == [0, 1, 2]


def test_clean_observation_is_the_exact_projection_and_outliers_are_wrong_matches():
    rng = np.random.default_rng(0)
    pts = np.column_stack([rng.uniform(3, 8, 200), rng.uniform(-2, 2, 200), rng.uniform(-1, 1, 200)])
    R = camera_rotation(np.array([1.0, 0.0, 0.0]))
    seen = visible(CAM, R, ORIGIN, pts, np.arange(200))
    assert seen.size > 100
    uv, X = observe(CAM, R, ORIGIN, pts, seen, np.random.default_rng(1))
    np.testing.assert_allclose(uv, project(CAM, R, ORIGIN, pts[seen])[0])
    np.testing.assert_array_equal(X, pts[seen])
    noisy = CameraModel(detection_probability=0.5, pixel_noise=1.0, outlier_ratio=1.0)
    uv2, X2 = observe(noisy, R, ORIGIN, pts, seen, np.random.default_rng(1))
    assert 0.3 * seen.size < uv2.shape[0] < 0.7 * seen.size
    reproj = project(CAM, R, ORIGIN, X2)[0]
    assert np.median(np.linalg.norm(reproj - uv2, axis=1)) > 20.0  # every match is wrong


@pytest.mark.parametrize("kwargs", [{"fx": 0.0}, {"min_depth": 5.0, "max_depth": 4.0}, {"outlier_ratio": 1.5},
                                    {"pixel_noise": -1.0}])
def test_bad_camera_settings_raise_a_one_line_error(kwargs):
    with pytest.raises(InputError, match="camera"):
        CameraModel(**kwargs)
