"""MapStore: layers, weight multipliers, versions, and atomic snapshots under concurrent updates."""

from __future__ import annotations

import threading

import numpy as np
import pytest

from pivotd.errors import InputError
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import MapStore, load_map_store


def _cloud(points, weight=1.0, directions=None) -> LandmarkCloud:
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    d = None if directions is None else np.asarray(directions, np.float32)
    return LandmarkCloud(points, np.full(len(points), weight, np.float32), d)


def test_layers_versions_and_multipliers():
    rng = np.random.default_rng(1)
    store = MapStore()
    assert store.version == 0 and len(store.snapshot()) == 0
    base = rng.uniform(-3, 3, (200, 3))
    v1 = store.set_layer("base", _cloud(base))
    v2 = store.set_layer("targets", _cloud([[0.5, 0, 0], [0, 0.5, 0]], weight=2.0), weight_multiplier=5.0)
    assert (v1, v2) == (1, 2)
    snap = store.snapshot()
    assert len(snap) == 202
    assert snap.layers["base"].rows == slice(0, 200) and snap.layers["targets"].rows == slice(200, 202)
    np.testing.assert_allclose(snap.weights[snap.layers["targets"].rows], 10.0)
    np.testing.assert_allclose(snap.weights[snap.layers["base"].rows], 1.0)
    # Same multiset of base points (order is the index's).
    np.testing.assert_allclose(np.sort(snap.points[:200], axis=0), np.sort(base.astype(np.float32), axis=0))
    kept = snap.retained(np.zeros((1, 3)), RetainedFilter(max_range=0.6))[0]
    assert {200, 201} <= set(kept.tolist())
    assert np.all(np.diff(kept) > 0)
    d = np.linalg.norm(snap.points.astype(float), axis=1)
    np.testing.assert_array_equal(kept, np.flatnonzero(d <= 0.6))
    # add_to_layer keeps the multiplier; remove_layer drops the rows.
    v3 = store.add_to_layer("targets", _cloud([[0, 0, 0.5]], weight=1.0))
    snap3 = store.snapshot()
    assert v3 == 3 and snap3.layers["targets"].count == 3
    np.testing.assert_allclose(np.sort(snap3.weights[200:]), [5.0, 10.0, 10.0])
    assert store.remove_layer("targets") == 4
    assert len(store.snapshot()) == 200 and "targets" not in store.snapshot().layers
    # The old snapshot is untouched by later updates.
    assert len(snap) == 202 and snap.version == 2
    with pytest.raises(InputError, match="no map layer 'nope'"):
        store.remove_layer("nope")


def test_snapshot_arrays_are_read_only():
    store = MapStore()
    store.set_layer("base", _cloud([[1, 2, 3]]))
    with pytest.raises(ValueError):
        store.snapshot().points[0, 0] = 5.0


def test_directions_merge_across_layers_unknown_as_zero():
    store = MapStore()
    store.set_layer("base", _cloud([[0, 0, 0]], directions=[[1, 0, 0]]))
    store.set_layer("targets", _cloud([[5, 0, 0]]))
    snap = store.snapshot()
    np.testing.assert_allclose(snap.directions, [[1, 0, 0], [0, 0, 0]])
    # From behind: base landmark dropped by the view filter, target (unknown direction) kept.
    kept = snap.retained(np.array([[-3.0, 0, 0]]), RetainedFilter(max_view_angle_deg=60))[0]
    np.testing.assert_array_equal(kept, [1])


def test_occupancy_rebuilt_from_the_map_on_update():
    store = MapStore(occupancy_voxel=0.2)
    store.set_layer("base", _cloud([[4, 0, 0]]))
    w = np.zeros((1, 3))
    assert store.snapshot().retained(w, RetainedFilter(occlusion=True))[0].size == 1
    g = np.arange(-1, 1.01, 0.1)
    yy, zz = np.meshgrid(g, g)
    store.set_layer("wall", _cloud(np.c_[np.full(yy.size, 2.0), yy.ravel(), zz.ravel()]))
    snap = store.snapshot()
    kept = snap.retained(w, RetainedFilter(occlusion=True))[0]
    assert 0 not in kept.tolist()  # the base landmark at x = 4 is now behind the wall
    assert kept.size == snap.layers["wall"].count


def test_readers_never_see_a_half_updated_map():
    """A writer replaces a layer whose size and weights encode the update number; readers check consistency."""
    rng = np.random.default_rng(2)
    store = MapStore(index_cell=0.5)
    store.set_layer("base", _cloud(rng.uniform(-5, 5, (3000, 3))))
    updates = 150
    errors: list[str] = []
    stop = threading.Event()

    def writer() -> None:
        for k in range(1, updates + 1):
            pts = rng.uniform(-2, 2, (10 + k, 3))
            store.set_layer("targets", _cloud(pts, weight=float(k)), weight_multiplier=2.0)
        stop.set()

    def reader() -> None:
        last = 0
        flt = RetainedFilter(max_range=3.0)
        while not stop.is_set() or last < store.version:
            snap = store.snapshot()
            if snap.version < last:
                errors.append(f"version went back {last} -> {snap.version}")
            last = snap.version
            info = snap.layers.get("targets")
            if info is None:
                continue
            w = snap.weights[info.rows]
            k = round(float(w[0]) / 2.0)
            if not (np.all(w == 2.0 * k) and info.count == 10 + k and len(snap) == 3000 + info.count):
                errors.append(f"inconsistent snapshot v{snap.version}: count {info.count}, weight {w[0]}")
            kept = snap.retained(np.zeros((1, 3)), flt)[0]
            d = np.linalg.norm(snap.points[kept].astype(float), axis=1)
            if kept.size and (d.max() > 3.0 or kept.max() >= len(snap)):
                errors.append("retained set does not match its snapshot")

    threads = [threading.Thread(target=writer)] + [threading.Thread(target=reader) for _ in range(2)]
    for t in threads:
        t.start()
    for t in threads:
        t.join(timeout=60)
    assert not any(t.is_alive() for t in threads)
    assert errors == []
    assert store.version == updates + 1


def test_load_map_store_from_file(fif_dir, tmp_path):
    store = load_map_store(fif_dir / "four_walls_points_w.txt")
    snap = store.snapshot()
    assert len(snap) == 1000 and snap.version == 1 and list(snap.layers) == ["base"]
    assert snap.occupancy is None
    empty = tmp_path / "empty.txt"
    empty.write_text("# 0\n")
    with pytest.raises(InputError, match="empty"):
        load_map_store(empty)
    assert len(load_map_store(empty, allow_empty=True).snapshot()) == 0
    with pytest.raises(InputError, match="needs an occlusion voxel"):
        load_map_store(fif_dir / "four_walls_points_w.txt", occupancy_file=fif_dir / "two_walls_points_w.txt")


def test_layers_are_stored_as_float32_and_shapes_checked():
    store = MapStore()
    store.set_layer("base", LandmarkCloud(np.array([[1.0, 2.0, 3.0]]), np.array([2.0])))
    snap = store.snapshot()
    assert snap.points.dtype == np.float32 and snap.weights.dtype == np.float32
    with pytest.raises(InputError, match="inconsistent cloud shapes"):
        store.set_layer("bad", LandmarkCloud(np.zeros((3, 3)), np.ones(2)))
    assert store.version == 1


def test_summary_describes_the_snapshot(fif_dir):
    import json

    store = load_map_store(fif_dir / "two_walls_points_w.txt", occlusion_voxel=0.5)
    store.set_layer("targets", _cloud([[0, 0, 0]], weight=3.0), weight_multiplier=2.0)
    info = store.snapshot().summary()
    json.dumps(info)
    assert info["landmarks"] == 1001 and info["version"] == 2 and info["directions"] is False
    assert info["layers"] == {"base": {"count": 1000, "weight_multiplier": 1.0},
                              "targets": {"count": 1, "weight_multiplier": 2.0}}
    np.testing.assert_allclose(info["bounds_max"], [2.5, 2.5, 1.0], atol=1e-4)
    assert info["occupancy_voxel"] == 0.5 and info["occupied_voxels"] > 20


def test_non_finite_waypoints_are_rejected():
    store = MapStore()
    store.set_layer("base", _cloud([[1, 0, 0]]))
    with pytest.raises(InputError, match="waypoint 1 is not finite"):
        store.snapshot().retained(np.array([[0, 0, 0], [np.nan, 0, 0]]), RetainedFilter(max_range=2))


def test_snapshot_order_is_fixed_by_the_landmarks_not_the_file():
    rng = np.random.default_rng(4)
    pts = rng.normal(0, 1.5, (5000, 3)).astype(np.float32)
    pts[:40] = pts[40:80]  # coincident landmarks, told apart by weight
    w = rng.uniform(0.5, 2, 5000).astype(np.float32)
    snaps = []
    for perm in (np.arange(5000), rng.permutation(5000), rng.permutation(5000)):
        store = MapStore()
        store.set_layer("base", LandmarkCloud(pts[perm], w[perm]))
        snaps.append(store.snapshot())
    for s in snaps[1:]:
        np.testing.assert_array_equal(s.points, snaps[0].points)
        np.testing.assert_array_equal(s.weights, snaps[0].weights)
    # far landmarks elsewhere in the map leave the near ones' order (hence every retained set) unchanged
    far = rng.uniform(300, 900, (20000, 3)).astype(np.float32)
    store = MapStore()
    store.set_layer("base", LandmarkCloud(np.concatenate([far, pts]), np.concatenate([np.ones(20000, np.float32), w])))
    big = store.snapshot()
    flt = RetainedFilter(max_range=6.0)
    way = np.array([[0.0, 0, 0], [2.0, 1, 0]])
    for a, b in zip(snaps[0].retained(way, flt), big.retained(way, flt), strict=True):
        np.testing.assert_array_equal(big.points[b], snaps[0].points[a])
    # rows run cell by cell (the index's layout, cells on the fixed 1 m lattice) and, inside a cell, along the
    # Z-order curve of the position in the cell: the first quarter of a crowded cell's rows lies in one half
    # of the cell along z, the axis of the curve's top bit
    cells = np.floor(snaps[0].points.astype(float)).astype(np.int64)
    change = np.flatnonzero(np.any(cells[1:] != cells[:-1], axis=1)) + 1
    assert np.unique(cells, axis=0).shape[0] == change.size + 1  # every cell is one contiguous run
    crowded = [r for r in np.split(np.arange(5000), change) if len(r) >= 40]
    assert crowded
    for run in crowded:
        z = snaps[0].points[run, 2].astype(float) - cells[run, 2]
        assert np.all(np.diff((z >= 0.5).astype(int)) >= 0)  # lower half first, then upper half


def test_dense_cells_are_read_through_an_even_subsample_fixed_at_load():
    """A map packed densely (12.5k landmarks per 1 m cell): the retained-set query returns at most the cell cap of
    each cell in range, the same landmarks whatever the file order, spread over each cell; sparse cells whole."""
    rng = np.random.default_rng(7)
    dense = rng.uniform([0, 0, 0], [4, 4, 3], (600_000, 3)).astype(np.float32)  # 48 cells of the 1 m lattice
    sparse = rng.uniform([6, 0, 0], [7, 1, 1], (50, 3)).astype(np.float32)  # one cell under the cap
    pts = np.concatenate([dense, sparse])
    flt = RetainedFilter(max_range=10.0)
    way = np.array([[2.0, 2.0, 1.5]])
    kept = []
    for perm in (np.arange(pts.shape[0]), rng.permutation(pts.shape[0])):
        store = MapStore(cell_cap=100)
        store.set_layer("base", LandmarkCloud(pts[perm], np.ones(pts.shape[0], np.float32)))
        snap = store.snapshot()
        (idx,) = snap.retained(way, flt)
        assert idx.size == 48 * 100 + 50  # not 600 050: the query reads the cap of every dense cell
        assert snap.queried_landmarks == 48 * 100 + 50 and len(snap) == pts.shape[0]
        assert np.all(np.diff(idx) > 0)
        np.testing.assert_array_equal(snap.retained(way, RetainedFilter(max_range=np.inf))[0], idx)  # brute path
        kept.append(snap.points[idx])
    np.testing.assert_array_equal(kept[0], kept[1])
    got = kept[0]
    assert np.sum(got[:, 0] >= 6) == 50  # the sparse cell is read whole
    corner = got[np.all(got < 1.0, axis=1)]  # the subsample of cell (0, 0, 0) covers its eight octants
    assert corner.shape[0] == 100
    octants = np.bincount((corner >= 0.5).astype(int) @ np.array([4, 2, 1]), minlength=8)
    assert octants.min() >= 6, octants
    # without a cap every landmark in range is read, as before
    store = MapStore()
    store.set_layer("base", LandmarkCloud(pts, np.ones(pts.shape[0], np.float32)))
    assert store.snapshot().retained(way, flt)[0].size == pts.shape[0]
    with pytest.raises(InputError, match="landmarks per map cell"):
        MapStore(cell_cap=0)


def test_a_thinned_cell_weighs_in_the_queries_as_much_as_it_holds():
    """With the cell cap the queries read ``cap`` of a dense cell's landmarks; those carry the cell's weight in
    ``query_weights`` (n / kept each), so the weight the planner sees in range is the map's, cell by cell."""
    rng = np.random.default_rng(3)
    dense = rng.uniform([2, 0, 0], [3, 1, 1], (1000, 3))  # one cell, ten times the cap
    sparse = rng.uniform([-4, 0, 0], [-1, 1, 1], (240, 3))  # three cells, 80 each on average: under the cap
    store = MapStore(cell_cap=100)
    store.set_layer("base", _cloud(np.concatenate([dense, sparse]), weight=2.0))
    snap = store.snapshot()
    (idx,) = snap.retained(np.zeros((1, 3)), RetainedFilter(max_range=10.0))
    w = snap.query_weights[idx]
    near = snap.points[idx, 0] > 0
    assert near.sum() == 100 and (~near).sum() == 240
    np.testing.assert_allclose(w[near], 20.0)  # 2 × 1000 / 100
    np.testing.assert_allclose(w[~near], 2.0)
    assert w[near].sum() == pytest.approx(2.0 * 1000) and w[~near].sum() == pytest.approx(2.0 * 240)
    np.testing.assert_allclose(snap.weights, 2.0)  # the map's own weights are untouched
    unthinned = MapStore()
    unthinned.set_layer("base", _cloud(dense))
    assert unthinned.snapshot().query_weights is unthinned.snapshot().weights
