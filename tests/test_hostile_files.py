"""Hostile map and path files: allocations bounded by the file size, every failure a one-line InputError."""

from __future__ import annotations

import struct
import tracemalloc
from pathlib import Path

import numpy as np
import plyfile
import pytest

from pivotd.cli import main
from pivotd.errors import InputError
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.grid_index import GridIndex
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.maps.store import MapStore
from pivotd.robot_path import load_path

MB = 1 << 20


def _peak(call) -> tuple[object, int]:
    """(result or raised PivotdError, peak traced bytes) of ``call()``."""
    tracemalloc.start()
    try:
        try:
            result = call()
        except InputError as exc:
            result = exc
        return result, tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()


def _colmap_model(d: Path, track_image_ids: list[int], image_ids: list[int]) -> Path:
    """points3D.bin with one point per track id (observed by that image) and images.bin with ``image_ids``."""
    d.mkdir()
    out = [struct.pack("<Q", len(track_image_ids))]
    for k, img in enumerate(track_image_ids):
        out.append(struct.pack("<QdddBBBdQ", k + 1, float(k), 0.0, 0.0, 1, 2, 3, 0.5, 1))
        out.append(struct.pack("<ii", img, 0))
    (d / "points3D.bin").write_bytes(b"".join(out))
    out = [struct.pack("<Q", len(image_ids))]
    for iid in image_ids:
        out.append(struct.pack("<idddddddi", iid, 1.0, 0.0, 0.0, 0.0, 0.0, -5.0, 0.0, 1))
        out.append(b"img.jpg\0" + struct.pack("<Q", 0))
    (d / "images.bin").write_bytes(b"".join(out))
    return d


@pytest.mark.parametrize("huge_id", [2**31 - 1, 0x5A000001])
def test_colmap_huge_image_id_in_a_track_allocates_nothing_big(tmp_path, huge_id):
    # Formerly a lookup table sized by the largest id: 16 GiB for 2³¹−1, 5.8 GB after one flipped byte.
    model = _colmap_model(tmp_path / "m", [1, huge_id, 2], [1, 2])
    cloud, peak = _peak(lambda: load_landmarks(model))
    assert isinstance(cloud, LandmarkCloud) and len(cloud) == 3
    np.testing.assert_allclose(np.linalg.norm(cloud.directions, axis=1), [1.0, 0.0, 1.0], atol=1e-6)
    assert peak < 16 * MB


def test_colmap_huge_image_id_in_images_bin_is_looked_up_exactly(tmp_path):
    # Sparse ids (one huge) take the binary-search path; the result equals the compact-id model's.
    sparse = load_landmarks(_colmap_model(tmp_path / "a", [7, 2**31 - 2, 3], [7, 2**31 - 2, 3]))
    compact = load_landmarks(_colmap_model(tmp_path / "b", [1, 2, 3], [1, 2, 3]))
    np.testing.assert_array_equal(sparse.directions, compact.directions)
    assert np.all(np.linalg.norm(sparse.directions, axis=1) > 0.99)


@pytest.mark.parametrize("fmt", ["ascii", "binary_little_endian"])
def test_ply_element_count_beyond_the_file_is_refused_before_allocating(tmp_path, fmt):
    v = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    f = tmp_path / "m.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex")], text=fmt == "ascii").write(str(f))
    f.write_bytes(f.read_bytes().replace(b"element vertex 3", b"element vertex 2147483648"))
    err, peak = _peak(lambda: load_landmarks(f))
    assert isinstance(err, InputError)
    assert "m.ply: corrupt or truncated PLY at vertex 3: the header claims 2147483648 'vertex' elements" in str(err)
    assert peak < MB


def test_ply_element_without_properties_and_a_huge_count_is_refused(tmp_path):
    f = tmp_path / "e.ply"
    f.write_bytes(b"ply\nformat binary_little_endian 1.0\nelement vertex 1\nproperty float x\nproperty float y\n"
                  b"property float z\nelement junk 4000000000\nend_header\n" + bytes(12))
    with pytest.raises(InputError, match=r"e\.ply: corrupt or truncated PLY at junk \d: the header claims 4000000000"):
        load_landmarks(f)


def _npy(path: Path, header: bytes, body: bytes = bytes(96)) -> Path:
    header = header + b" " * (118 - len(header)) + b"\n"
    path.write_bytes(b"\x93NUMPY\x01\x00" + struct.pack("<H", len(header)) + header + body)
    return path


@pytest.mark.parametrize(("header", "what"), [
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': (99999999999999999999999, 3), }", "claims"),
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': (1, 3 ", "TokenError"),
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': (4611686018427387904, 3), }", "claims"),
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': (2147483648, 4), }", "claims"),
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': (-4, 3), }", "bad shape"),
    (b"{'descr': 'c16', 'fortran_order': False, 'shape': (2, 3), }", "expected a numeric"),
    (b"{'descr': '<f8', 'fortran_order': False, 'shape': ((((((((((((((((((((((((((((((((((1, 3), }", ""),
])
def test_npy_header_errors_are_one_line_input_errors(tmp_path, header, what):
    f = _npy(tmp_path / "m.npy", header)
    err, peak = _peak(lambda: load_landmarks(f))
    assert isinstance(err, InputError), err
    assert str(err).startswith(f"{f}: ") and what in str(err) and "\n" not in str(err)
    assert peak < MB


@pytest.mark.parametrize("version", [b"\x02\x00", b"\x03\x00"])
def test_npy_header_length_beyond_the_file_reads_nothing_big(tmp_path, version):
    # A flipped version byte turns the 2-byte header length into a 4-byte one of ~660 MB: formerly read(n)
    # allocated all of it before finding the file short.
    f = tmp_path / "m.npy"
    np.save(f, np.zeros((4, 3), np.float32))
    f.write_bytes(f.read_bytes()[:6] + version + f.read_bytes()[8:])
    err, peak = _peak(lambda: load_landmarks(f))
    assert isinstance(err, InputError) and str(err).startswith(f"{f}: not a readable .npy array (bad header")
    assert peak < MB


def test_ply_list_length_beyond_the_file_reads_nothing_big(tmp_path):
    v = np.zeros(3, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4")])
    face = np.empty(1, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 2]]
    f = tmp_path / "l.ply"
    plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"),
                     plyfile.PlyElement.describe(face, "face", len_types={"vertex_indices": "u4"})]).write(str(f))
    data = f.read_bytes()
    at = data.index(b"end_header\n") + 11 + 36  # the face's list length, after three vertices
    f.write_bytes(data[:at] + struct.pack("<I", 0xFFFFFFF0) + data[at + 4:])
    err, peak = _peak(lambda: load_landmarks(f))
    assert isinstance(err, InputError) and "l.ply: corrupt or truncated PLY at face 0" in str(err)
    assert peak < MB


@pytest.mark.parametrize(("points", "images", "pattern"), [
    ("1 0 0 0 1 2 3 0.5 99999999999 0\n", None, r"points3D\.txt:1: image id 99999999999 is out of range"),
    ("1 1e400 0 0 1 2 3 0.5\n", None, r"points3D\.txt:1: coordinate is not finite"),
    ("1 1e20 0 0 1 2 3 0.5\n", None, r"points3D\.txt: point 0 lies beyond ±1e\+07 m"),
    ("1 1e300 0 0 1 2 3 0.5\n", None, r"points3D\.txt: point 0 is not finite \(NaN, inf or beyond ±3\.4e38\)"),
    ("1 0 0 0 1 2 3 0.5 1 0\n", "99999999999999999999 1 0 0 0 0 0 0 1 a.jpg\n\n",
     r"images\.txt:1: image id 99999999999999999999 is out of range"),
    ("1 0 0 0 1 2 3 0.5 1 0\n", "1 1e300 1e300 0 0 0 0 1e200 1 a.jpg\n\n",
     r"images\.txt: image 1 has a translation beyond"),
])
def test_colmap_text_overflows_are_one_line_errors(tmp_path, points, images, pattern):
    (tmp_path / "points3D.txt").write_text(points)
    if images is not None:
        (tmp_path / "images.txt").write_text(images)
    with pytest.raises(InputError, match=pattern):
        load_landmarks(tmp_path)


def test_colmap_huge_quaternion_normalises_without_overflow(tmp_path):
    (tmp_path / "points3D.txt").write_text("1 0 0 0 1 2 3 0.5 1 0\n")
    (tmp_path / "images.txt").write_text("1 1e300 0 0 0 0 0 -5 1 a.jpg\n\n")
    cloud = load_landmarks(tmp_path)
    np.testing.assert_allclose(cloud.directions, [[0.0, 0.0, 1.0]], atol=1e-6)


def test_text_map_memory_stays_within_twice_the_honest_size(tmp_path):
    rows = 100_000
    rng = np.random.default_rng(0)
    f = tmp_path / "m.txt"
    np.savetxt(f, rng.integers(0, 9, (rows, 3)), fmt="%d")  # "d d d\n": 6 bytes per row, the densest text
    cloud, peak = _peak(lambda: load_landmarks(f))
    assert len(cloud) == rows
    honest = max(f.stat().st_size, 24 * rows)  # the landmarks as float64 x, y, z
    assert peak <= 2 * honest, (peak, honest)


def test_text_map_with_a_bad_last_line_keeps_memory_bounded(tmp_path):
    f = tmp_path / "m.txt"
    f.write_text("1 2 3\n" * 100_000 + "1 2 x\n")  # the line parser runs on the last block only
    err, peak = _peak(lambda: load_landmarks(f))
    assert isinstance(err, InputError) and str(err) == f"{f}:100001: not a number in '1 2 x'"
    assert peak <= 2 * 24 * 100_000


def test_path_file_to_1e200_and_huge_stamps_are_refused(tmp_path):
    f = tmp_path / "p.csv"
    f.write_text("0,0,0\n1e200,0,0\n")
    with pytest.raises(InputError, match=r"p\.csv: row 2 has a position beyond ±1e\+07 m"):
        load_path(f)
    f.write_text("1e308,0,0,0,1,0,0,0\n-1e308,1,0,0,1,0,0,0\n")
    with pytest.raises(InputError, match=r"p\.csv: row 2 has a timestamp out of range"):
        load_path(f)
    f.write_text("0,0,0,0,1e300,0,0,0\n1,1,0,0,0,0,0,1e-300\n")
    p = load_path(f)
    np.testing.assert_allclose(p.quats, [[0, 0, 0, 1], [0, 0, 1, 0]])


def test_grid_index_far_apart_points_do_not_wrap_and_queries_stay_exact():
    # Cell keys of a 1 cm grid over ±1e7 m would need ~10^27 cells: formerly np.prod wrapped.
    rng = np.random.default_rng(1)
    near = rng.uniform(-3, 3, (500, 3)).astype(np.float32)
    far = np.array([[1e7, -1e7, 1e7], [-1e7, 1e7, -5e6]], np.float32)
    pts = np.concatenate([near, far])
    index, order = GridIndex.build(pts, 0.01)
    assert index.cell > 0.01 and int(np.prod(index.dims.astype(object))) <= 1 << 62
    w = np.array([[0.0, 0.0, 0.0], [1.0, -1.0, 0.5], [1e7, -1e7, 1e7 - 1]])
    idx, counts = index.query(pts[order], w, 0.2, 2.5)
    got = np.split(idx, np.cumsum(counts)[:-1])
    for i, wi in enumerate(w):
        d = np.linalg.norm(pts[order].astype(np.float64) - wi, axis=1)
        np.testing.assert_array_equal(got[i], np.flatnonzero((d >= 0.2) & (d <= 2.5)))
    assert counts[2] == 1


def test_map_store_accepts_far_away_clouds_and_retains_exactly():
    store = MapStore()
    pts = np.array([[0, 0, 0], [1, 1, 1], [9e6, -9e6, 0], [-9e6, 0, 9e6]], np.float32)
    store.set_layer("targets", LandmarkCloud(pts, np.ones(4, np.float32)))
    snap = store.snapshot()
    got = snap.retained(np.array([[0.0, 0.0, 0.0], [9e6, -9e6, 1.0]]), RetainedFilter(max_range=5.0))
    assert [sorted(snap.points[b].tolist()) for b in got] == [[[0, 0, 0], [1, 1, 1]], [[9e6, -9e6, 0]]]


def test_tiny_occlusion_voxel_is_a_clear_error(tmp_path, capsys):
    pts = np.random.default_rng(2).uniform(-5, 5, (50, 3))
    with pytest.raises(InputError, match=r"occlusion voxel 1e-06 m is too small for the occupancy extent"):
        OccupancyGrid.from_points(pts, 1e-6)
    np.save(tmp_path / "m.npy", pts)
    (tmp_path / "p.csv").write_text("0,0,0\n1,0,0\n")
    code = main(["plan", "--map", str(tmp_path / "m.npy"), "--path", str(tmp_path / "p.csv"),
                 "--occlusion-voxel", "1e-6"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "occlusion voxel 1e-06 m is too small" in err[0]


def test_long_rays_are_processed_in_bounded_batches():
    # A grid 60 000 voxels across: every ray has ~60 000 samples; batches shrink to fit the sample budget.
    grid = OccupancyGrid.from_points(np.array([[0.0, 0, 0], [60.0, 0, 0], [30.0, 0, 0]]), 0.001)
    targets = np.tile([[59.9, 0.0, 0.0]], (64, 1))
    blocked, peak = _peak(lambda: grid.occluded(np.array([0.1, 0.0, 0.0]), targets))
    assert blocked.all()  # the occupied voxel at x = 30 m is on every ray
    assert peak < 64 * MB
