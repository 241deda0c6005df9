"""Retained-set filters: range (against brute force), view direction, occlusion on constructed cases."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pivotd.maps.filters import RetainedFilter, retained_for_path
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.grid_index import GridIndex
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.maps.store import MapStore, load_map_store


def _cloud(points, weights=None, directions=None) -> LandmarkCloud:
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    w = np.ones(len(points), np.float32) if weights is None else np.asarray(weights, np.float32)
    d = None if directions is None else np.asarray(directions, np.float32)
    return LandmarkCloud(points, w, d)


def _brute(points: np.ndarray, w: np.ndarray, rmin: float, rmax: float) -> np.ndarray:
    d = np.linalg.norm(points.astype(np.float64) - w, axis=1)
    return np.flatnonzero((d >= rmin) & (d <= rmax))


@settings(max_examples=40, deadline=None)
@given(
    seed=st.integers(0, 10**6),
    cell=st.floats(0.15, 4.0),
    rmin=st.floats(0.0, 3.0),
    span=st.floats(0.05, 12.0),
)
def test_grid_range_query_equals_brute_force(seed, cell, rmin, span):
    rng = np.random.default_rng(seed)
    pts = (rng.random((3000, 3)) * rng.uniform(1, 15, 3) - 2).astype(np.float32)
    index, order = GridIndex.build(pts, cell)
    sorted_pts = pts[order]
    waypoints = rng.uniform(-6, 18, (11, 3))  # more than one query group
    idx, counts = index.query(sorted_pts, waypoints, rmin, rmin + span)
    blocks = np.split(idx, np.cumsum(counts)[:-1])
    for w, got in zip(waypoints, blocks, strict=True):
        np.testing.assert_array_equal(got, _brute(sorted_pts, w, rmin, rmin + span))


def test_snapshot_retained_range_and_order():
    rng = np.random.default_rng(0)
    store = MapStore(index_cell=0.7)
    store.set_layer("base", _cloud(rng.uniform(-5, 5, (4000, 3))))
    snap = store.snapshot()
    wps = np.array([[0, 0, 0], [1, 2, -1], [40, 0, 0]], float)
    flt = RetainedFilter(min_range=0.5, max_range=3.0)
    out = retained_for_path(snap, wps, flt)
    assert len(out) == 3
    for w, got in zip(wps, out, strict=True):
        np.testing.assert_array_equal(got, _brute(snap.points, w, 0.5, 3.0))
        assert np.all(np.diff(got) > 0)
    assert out[2].size == 0
    # Unbounded max range: everything outside min_range.
    everything = snap.retained(wps[:1], RetainedFilter(min_range=1.0))[0]
    np.testing.assert_array_equal(everything, _brute(snap.points, wps[0], 1.0, math.inf))


def test_view_direction_filter_drops_landmarks_seen_from_behind():
    # Landmarks observed from +x; a third has no known direction and is always kept.
    pts = [[0, 0, 0], [0, 1, 0], [0, -1, 0]]
    dirs = [[1, 0, 0], [1, 0, 0], [0, 0, 0]]
    store = MapStore()
    store.set_layer("base", _cloud(pts, directions=dirs))
    snap = store.snapshot()
    flt = RetainedFilter(max_view_angle_deg=60.0)
    front, side, back = snap.retained(np.array([[5.0, 0, 0], [1.0, 2.0, 0], [-5, 0, 0]]), flt)
    np.testing.assert_array_equal(np.sort(snap.points[front][:, 1]), [-1, 0, 1])
    # From (1, 2, 0): landmark (0,1,0) is seen 45° off its direction (kept), (0,0,0) 63.4° off (dropped).
    np.testing.assert_array_equal(np.sort(snap.points[side][:, 1]), [-1, 1])
    np.testing.assert_array_equal(snap.points[back][:, 1], [-1])
    # Filter off: everything retained.
    assert snap.retained(np.array([[-5.0, 0, 0]]), RetainedFilter())[0].size == 3


def _wall(x: float, half: float, spacing: float) -> np.ndarray:
    g = np.arange(-half, half + 1e-9, spacing)
    yy, zz = np.meshgrid(g, g)
    return np.c_[np.full(yy.size, x), yy.ravel(), zz.ravel()]


def test_occlusion_behind_wall_dropped_front_kept_grazing_documented():
    wall = _wall(2.0, 2.0, 0.1)
    grid = OccupancyGrid.from_points(wall, 0.2)
    origin = np.array([0.0, 0.0, 0.0])
    targets = np.array([
        [4.0, 0.0, 0.0],  # straight behind the wall
        [4.0, 1.5, -1.0],  # obliquely behind
        [1.0, 0.5, 0.3],  # in front
        [2.0, 0.5, 0.5],  # on the wall itself: its own voxel does not hide it
        [4.0, 5.0, 0.0],  # beside the wall's end: ray passes outside the wall
        [2.3, 2.3, 0.0],  # grazing: crosses x = 2 at y = 2.0, the wall's last row (inside its edge voxel)
        [2.3, 2.75, 0.0],  # grazing: passes 0.3 m beyond the last row, outside the edge voxel
        [2.05, 0.0, 0.0],  # inside the wall's voxel layer, in its own voxel: stays visible
    ])
    occ = grid.occluded(origin, targets)
    # Obstacles are voxel-sized: the wall reaches up to one voxel beyond its last landmark row.
    assert occ.tolist() == [True, True, False, False, False, True, False, False]


def test_occlusion_sensor_inside_an_occupied_voxel_and_thin_oblique_walls():
    wall = _wall(1.0, 3.0, 0.05)
    grid = OccupancyGrid.from_points(wall, 0.2)
    # Sensor sits in the wall's own voxel layer: it still sees the side it faces.
    assert not grid.occluded(np.array([1.0, 0.0, 0.0]), np.array([[-1.0, 0.3, 0.0]]))[0]
    # Steep oblique rays across a one-voxel-thick wall are always caught.
    rng = np.random.default_rng(5)
    far = np.c_[rng.uniform(2.5, 4.0, 500), rng.uniform(-1.5, 1.5, 500), rng.uniform(-1.5, 1.5, 500)]
    assert grid.occluded(np.array([-0.5, 0.2, -0.1]), far).all()


@pytest.mark.parametrize("step", [0.5, 1.0])
def test_occlusion_matches_dense_sampling_reference(step):
    rng = np.random.default_rng(9)
    blobs = rng.normal(size=(60, 3)) * 3
    occ_pts = np.concatenate([b + rng.normal(scale=0.3, size=(40, 3)) for b in blobs])
    grid = OccupancyGrid.from_points(occ_pts, 0.25)
    origin = np.array([0.1, -0.2, 0.05])
    targets = rng.uniform(-8, 8, (400, 3))
    targets[:40, 1:] = origin[1:]  # axis-aligned rays (exact zero components)
    targets[40:60, 2] = origin[2]
    got = grid.occluded(origin, targets, step=step)
    # Reference: fine sampling (5 mm) with the same exclusions (own voxels, clearance of one voxel). A ray with a
    # stretch at least one sample spacing long inside occupied voxels must be caught, and no ray may be
    # reported without an occupied voxel on it.
    ref_any = np.zeros(len(targets), bool)
    ref_sure = np.zeros(len(targets), bool)
    ov = np.floor((origin - grid.origin) / grid.voxel)
    for i, t in enumerate(targets):
        length = np.linalg.norm(t - origin)
        reach = length - grid.voxel
        if reach <= 0:
            continue
        ds = 0.005
        s = np.arange(ds, reach + 1e-12, ds) / length
        p = origin + s[:, None] * (t - origin)
        vox = np.floor((p - grid.origin) / grid.voxel)
        own = (vox == ov).all(1) | (vox == np.floor((t - grid.origin) / grid.voxel)).all(1)
        occ = grid.is_occupied(p) & ~own
        ref_any[i] = occ.any()
        if occ.any():
            # Longest stretch of the sight line lying in occupied voxels.
            edges = np.diff(np.concatenate([[0], occ.astype(np.int8), [0]]))
            stretch = (np.flatnonzero(edges == -1) - np.flatnonzero(edges == 1)).max() * ds
            spacing = reach * step * grid.voxel / max(np.abs((t - origin) * reach / length).max(), 1e-9)
            ref_sure[i] = stretch >= spacing + 2 * ds
    assert not np.any(got & ~ref_any)
    assert not np.any(ref_sure & ~got)
    assert ref_sure.sum() > 30 and np.sum(got) >= (0.85 if step < 1 else 0.75) * ref_any.sum()


def test_fif_two_walls_no_landmark_retained_behind_the_near_wall(fif_dir):
    # two_walls: wall A in the plane x = 2.5 (|y| ≤ 2.5, |z| ≤ 1) and wall B in y = 2.5 (|x| ≤ 2.5).
    # From (4.5, 0, 0), outside wall A, every wall-B landmark lies behind wall A.
    store = load_map_store(fif_dir / "two_walls_points_w.txt", occlusion_voxel=0.5)
    snap = store.snapshot()
    w = np.array([[4.5, 0.0, 0.0]])
    kept = snap.retained(w, RetainedFilter(occlusion=True))[0]
    pts = snap.points[kept]
    on_a = np.abs(pts[:, 0] - 2.5) < 1e-6
    on_b = ~on_a
    assert on_a.sum() == 500  # the whole near wall stays visible
    # Behind wall A: the sight line crosses x = 2.5 inside wall A's rectangle.
    t = (4.5 - 2.5) / (4.5 - pts[:, 0].astype(float))
    cross_y = t * pts[:, 1]
    behind = on_b & (np.abs(cross_y) <= 2.5)
    # Only landmarks in the grazing band next to the corner may survive (sight line within one voxel + one
    # sample spacing of the landmark, see pivotd/maps/occlusion.py); none deeper than 0.5 m behind the plane.
    assert not np.any(behind & (pts[:, 0] < 2.0))
    all_b = np.abs(snap.points[:, 1] - 2.5) < 1e-6
    assert all_b.sum() - on_b.sum() >= 400
    # Without occlusion every landmark is retained; from inside the room too.
    assert snap.retained(w, RetainedFilter())[0].size == 1000
    assert snap.retained(np.zeros((1, 3)), RetainedFilter(occlusion=True))[0].size == 1000


def test_occlusion_needs_a_grid():
    store = MapStore()
    store.set_layer("base", _cloud([[1, 0, 0]]))
    with pytest.raises(Exception, match="no occupancy grid"):
        store.snapshot().retained(np.zeros((1, 3)), RetainedFilter(occlusion=True))


def test_separate_occupancy_cloud(tmp_path):
    wall = _wall(2.0, 2.0, 0.1)
    occ_file = tmp_path / "occ.npy"
    np.save(occ_file, wall)
    map_file = tmp_path / "map.txt"
    map_file.write_text("4 0 0\n1 0 0\n")
    store = load_map_store(map_file, occlusion_voxel=0.2, occupancy_file=occ_file)
    snap = store.snapshot()
    kept = snap.retained(np.zeros((1, 3)), RetainedFilter(occlusion=True))[0]
    np.testing.assert_allclose(snap.points[kept], [[1, 0, 0]])


def test_filter_and_store_validation_are_user_errors():
    from pivotd.errors import InputError

    with pytest.raises(InputError, match="min_range"):
        RetainedFilter(min_range=2, max_range=1)
    with pytest.raises(InputError, match="max_view_angle_deg"):
        RetainedFilter(max_view_angle_deg=200)
    with pytest.raises(InputError, match="occlusion_step"):
        RetainedFilter(occlusion_step=1.5)
    with pytest.raises(InputError, match="occupancy voxel"):
        MapStore(occupancy_voxel=0.0)
    with pytest.raises(InputError, match="index cell"):
        MapStore(index_cell=-1.0)


@pytest.mark.parametrize("max_deg", [30.0, 60.0, 120.0])
def test_view_filter_matches_angle_reference_with_empty_waypoints(max_deg):
    from pivotd.geometry import angle_between

    rng = np.random.default_rng(11)
    pts = rng.uniform(-3, 3, (2000, 3))
    dirs = rng.normal(size=(2000, 3))
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    dirs[::7] = 0.0  # unknown
    store = MapStore(index_cell=0.5)
    store.set_layer("base", _cloud(pts, directions=dirs))
    snap = store.snapshot()
    wps = np.array([[0.5, 0.0, 0.2], [100.0, 0, 0], [-1.0, 1.0, 0.0], [100.0, 5, 0]])
    out = snap.retained(wps, RetainedFilter(max_range=2.5, max_view_angle_deg=max_deg))
    assert out[1].size == 0 and out[3].size == 0
    for w, got in zip(wps, out, strict=True):
        p = snap.points.astype(float)
        ang = np.degrees(angle_between(w - p, snap.directions.astype(float)))
        unknown = ~snap.directions.any(axis=1)
        d = np.linalg.norm(p - w, axis=1)
        ref = np.flatnonzero((d <= 2.5) & (unknown | (ang <= max_deg)))
        # Float32 evaluation may flip landmarks within 1e-3° of the limit only.
        diff = np.setxor1d(got, ref)
        assert np.all(np.abs(ang[diff] - max_deg) < 1e-3)
        assert ref.size > 50 or w[0] == 100.0


@pytest.mark.parametrize(("cell", "dense"), [(2.0, True), (0.1, False)])
def test_dense_and_sparse_index_layouts_agree_with_brute_force(cell, dense):
    rng = np.random.default_rng(4)
    pts = (rng.random((4000, 3)) * [10, 10, 3]).astype(np.float32)
    index, order = GridIndex.build(pts, cell)
    assert (index.keys is None) == dense
    sorted_pts = pts[order]
    # Waypoints inside, beside, far above and below the map.
    wps = np.array([[5, 5, 1.5], [-2, 5, 1], [5, 5, 40], [5, 5, -40], [9.9, 0.1, 2.9]])
    idx, counts = index.query(sorted_pts, wps, 0.3, 4.0)
    for w, got in zip(wps, np.split(idx, np.cumsum(counts)[:-1]), strict=True):
        np.testing.assert_array_equal(got, _brute(sorted_pts, w, 0.3, 4.0))
    assert counts[0] > 100 and counts[2] == 0 and counts[3] == 0


def test_sparse_occupancy_grid_matches_dense(monkeypatch):
    import pivotd.maps.occlusion as occlusion

    rng = np.random.default_rng(8)
    occ_pts = rng.normal(size=(600, 3)) * 2
    dense = OccupancyGrid.from_points(occ_pts, 0.3)
    monkeypatch.setattr(occlusion, "DENSE_LIMIT", 0)
    sparse = OccupancyGrid.from_points(occ_pts, 0.3)
    assert dense.dense is not None and sparse.dense is None and sparse.keys is not None
    assert dense.occupied_count == sparse.occupied_count
    targets = rng.uniform(-6, 6, (2000, 3))
    origin = np.array([0.3, -0.1, 0.2])
    got = sparse.occluded(origin, targets)
    np.testing.assert_array_equal(got, dense.occluded(origin, targets))
    assert 0.2 < got.mean() < 0.95
    np.testing.assert_array_equal(sparse.is_occupied(targets), dense.is_occupied(targets))


def test_degenerate_and_non_finite_rays_are_not_blocked():
    wall = _wall(1.0, 2.0, 0.1)
    grid = OccupancyGrid.from_points(wall, 0.2)
    origin = np.array([0.0, 0.1, 0.0])
    targets = np.array([[0.0, 0.1, 0.0], [np.nan, 0.0, 0.0], [3.0, 0.1, 0.0], [0.05, 0.1, 0.0]])
    np.testing.assert_array_equal(grid.occluded(origin, targets), [False, False, True, False])
