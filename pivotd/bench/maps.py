"""``pivotd bench maps``: map loading, retained-set queries and occlusion tests at scale.

Measures (medians over repeats, single-threaded):

* loading M landmarks from ``.npy`` and from a COLMAP ``points3D.bin`` (with and without
  ``images.bin``), and the map store's memory per landmark including the spatial index;
* retained-set queries for one waypoint and a 40-waypoint horizon (~20k landmarks each) on the
  large map and on a map holding only the landmarks those queries return (the ratio shows the
  cost depends on local density, not map size);
* the occlusion ray test: 20k sensor→landmark rays through a 0.2 m grid of a furnished room, to
  surface points anywhere in the room and to surface points within the 8 m query range.

Big-vs-small query timings are interleaved call by call and the ratio is the median of per-pair
ratios, so background load affects both sides alike. ``*_best_ms`` is the fastest repeat.
"""

from __future__ import annotations

import argparse
import gc
import json
import logging
import statistics
import tempfile
import time
import tracemalloc
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.maps.store import MapStore, load_map_store

log = logging.getLogger(__name__)

QUERY_RANGE = 8.0  # m
TARGET_RETAINED = 20_000
HORIZON = 40


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="1M landmarks and fewer repeats (smoke run)")
    parser.add_argument("--landmarks", type=int, default=None, help="map size (default 10M, 1M with --quick)")
    parser.add_argument("--repeats", type=int, default=None, help="timing repeats (default 5, 3 with --quick)")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--readers", action="store_true",
                        help="only the ASCII PLY reader: numpy block parser vs plyfile on 200k vertices")


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _paired_times(fa: Callable[[], object], fb: Callable[[], object], repeats: int) -> tuple[float, float, float]:
    """Interleaved timings of ``fa`` and ``fb``: (median a, median b, median of per-pair ratios a/b)."""
    ta, tb = [], []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fa()
        t1 = time.perf_counter()
        fb()
        t2 = time.perf_counter()
        ta.append(t1 - t0)
        tb.append(t2 - t1)
    return statistics.median(ta), statistics.median(tb), statistics.median(a / b for a, b in zip(ta, tb, strict=True))


def _best_time(fn: Callable[[], object], repeats: int) -> float:
    """Fastest of ``repeats`` runs (the least disturbed by other load on the machine)."""
    best = float("inf")
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        best = min(best, time.perf_counter() - t0)
    return best


def _uniform_map(m: int, rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    """M points uniform in a box whose density puts ~20k inside a QUERY_RANGE ball; returns (points, center)."""
    density = TARGET_RETAINED / (4.0 / 3.0 * np.pi * QUERY_RANGE**3)
    height = 2.5 * QUERY_RANGE
    side = float(np.sqrt(m / density / height))
    pts = rng.random((m, 3), dtype=np.float32)
    pts *= np.array([side, side, height], np.float32)
    return pts, np.array([side / 2, side / 2, height / 2])


def write_pcd(path: Path, fields: dict[str, np.ndarray], data: str = "binary", *, width: int | None = None,
              viewpoint: str = "0 0 0 1 0 0 0") -> None:
    """Write a PCD file (the Point Cloud Library's format, v0.7) holding ``fields`` (name → (N,) array; its
    dtype gives SIZE and TYPE; ``_`` names padding bytes, uint8), as ``data`` ascii, binary or
    binary_compressed (LZF, needs the ``pcd`` extra); ``width`` < N writes an organized cloud."""
    names = list(fields)
    arrays = [np.ascontiguousarray(fields[n]) for n in names]
    n = int(arrays[0].shape[0]) if arrays else 0
    width = n if width is None else width
    height = n // width if width else 1
    kinds = ["F" if a.dtype.kind == "f" else "U" if a.dtype.kind == "u" else "I" for a in arrays]
    header = (
        "# .PCD v0.7 - Point Cloud Data file format\nVERSION 0.7\n"
        f"FIELDS {' '.join(names)}\nSIZE {' '.join(str(a.dtype.itemsize) for a in arrays)}\n"
        f"TYPE {' '.join(kinds)}\nCOUNT {' '.join('1' for _ in names)}\nWIDTH {width}\nHEIGHT {height}\n"
        f"VIEWPOINT {viewpoint}\nPOINTS {n}\nDATA {data}\n"
    )
    if data == "ascii":
        rows = np.column_stack([a.astype(np.float64) for a in arrays]) if n else np.zeros((0, len(names)))
        body = "".join(" ".join(f"{v:.9g}" for v in row) + "\n" for row in rows).encode()
    else:
        rec = np.empty(n, dtype=[(f"f{k}", "<" + a.dtype.str[1:]) for k, a in enumerate(arrays)])
        for k, a in enumerate(arrays):
            rec[f"f{k}"] = a
        if data == "binary":
            body = rec.tobytes()
        else:
            import lzf

            planes = b"".join(a.astype("<" + a.dtype.str[1:]).tobytes() for a in arrays)  # field after field
            packed = lzf.compress(planes, len(planes) * 2 + 16) if planes else b""
            body = np.array([len(packed), len(planes)], "<u4").tobytes() + packed
    Path(path).write_bytes(header.encode() + body)


def write_colmap_bin(directory: Path, points: np.ndarray, rng: np.random.Generator, images: int = 500) -> None:
    """Write points3D.bin (tracks of 2–5 observations) and images.bin for ``points`` (M, 3), vectorised."""
    m = points.shape[0]
    tl = rng.integers(2, 6, m).astype(np.int64)
    rec = 51 + 8 * tl
    offsets = 8 + np.concatenate([[0], np.cumsum(rec)[:-1]])
    buf = bytearray(8 + int(rec.sum()))
    buf[:8] = np.uint64(m).tobytes()
    _scatter(buf, offsets, "<u8", np.arange(1, m + 1, dtype=np.uint64))
    for k in range(3):
        _scatter(buf, offsets + 8 + 8 * k, "<f8", points[:, k].astype(np.float64))
    _scatter(buf, offsets + 35, "<f8", np.full(m, 0.5))
    _scatter(buf, offsets + 43, "<u8", tl.astype(np.uint64))
    total = int(tl.sum())
    starts = np.cumsum(tl) - tl
    elem = np.arange(total) - np.repeat(starts, tl)
    toff = np.repeat(offsets + 51, tl) + 8 * elem
    _scatter(buf, toff, "<i4", rng.integers(1, images + 1, total).astype(np.int32))
    _scatter(buf, toff + 4, "<i4", elem.astype(np.int32))
    (directory / "points3D.bin").write_bytes(bytes(buf))
    parts = [np.uint64(images).tobytes()]
    lo, hi = points.min(axis=0), points.max(axis=0)
    for i in range(1, images + 1):
        c = rng.uniform(lo, hi)
        parts.append(np.array([i], "<i4").tobytes() + np.array([1, 0, 0, 0, *(-c)], "<f8").tobytes()
                     + np.array([1], "<i4").tobytes() + f"img{i}.jpg".encode() + b"\0" + np.uint64(0).tobytes())
    (directory / "images.bin").write_bytes(b"".join(parts))


def _scatter(buf: bytearray, offsets: np.ndarray, dtype: str, values: np.ndarray) -> None:
    width = np.dtype(dtype).itemsize
    shift = offsets % width
    for s in np.unique(shift):
        view = np.frombuffer(buf, dtype=dtype, offset=int(s), count=(len(buf) - int(s)) // width)
        sel = shift == s
        view[(offsets[sel] - s) // width] = values[sel]


def _room_scene(rng: np.random.Generator, voxel: float) -> tuple[OccupancyGrid, np.ndarray, np.ndarray, np.ndarray]:
    """A 20 × 20 × 4 m room with pillars; returns (grid, sensor (3,), 20k surface landmarks anywhere,
    20k surface landmarks within QUERY_RANGE of the sensor, i.e. a retained set)."""
    surf = []
    n = 400_000
    u = rng.random((n, 2))
    for axis, value in ((0, -10.0), (0, 10.0), (1, -10.0), (1, 10.0)):
        p = np.empty((n // 8, 3))
        p[:, axis] = value
        p[:, 1 - axis] = -10 + 20 * u[: n // 8, 0]
        p[:, 2] = 4 * u[: n // 8, 1]
        surf.append(p)
    surf.append(np.c_[rng.uniform(-10, 10, (n // 4, 2)), np.zeros(n // 4)])
    for cx, cy in rng.uniform(-8, 8, (12, 2)):
        k = n // 48
        a = rng.uniform(0, 2 * np.pi, k)
        surf.append(np.c_[cx + 0.4 * np.cos(a), cy + 0.4 * np.sin(a), rng.uniform(0, 4, k)])
    occ = np.concatenate(surf)
    grid = OccupancyGrid.from_points(occ, voxel)
    sensor = np.array([0.0, 0.0, 1.5])
    targets = occ[rng.choice(occ.shape[0], 20_000, replace=False)]
    near = occ[np.linalg.norm(occ - sensor, axis=1) <= QUERY_RANGE]
    return grid, sensor, targets, near[rng.choice(near.shape[0], 20_000, replace=False)]


def run(args: argparse.Namespace) -> int:
    quick = bool(args.quick)
    m = args.landmarks or (1_000_000 if quick else 10_000_000)
    repeats = args.repeats or (3 if quick else 5)
    rng = np.random.default_rng(args.seed)
    results: dict[str, float | int | str] = {"landmarks": m, "repeats": repeats}

    def report(key: str, value: float, unit: str) -> None:
        results[key] = value
        print(f"{key:<44} {value:12.4g} {unit}", flush=True)

    if args.readers:
        _bench_ascii_ply(rng, repeats, report)
        if args.json:
            Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
        return 0

    pts, center = _uniform_map(m, rng)
    with tempfile.TemporaryDirectory(prefix="pivotd-bench-maps-") as tmp:
        tmpdir = Path(tmp)
        npy = tmpdir / "map.npy"
        np.save(npy, pts.astype(np.float64))
        report("load_npy_s", _median_time(lambda: load_landmarks(npy), max(1, repeats // 2)), "s")
        report("load_npy_store_s", _median_time(lambda: load_map_store(npy), max(1, repeats // 2)), "s")
        gc.collect()
        tracemalloc.start()
        base = tracemalloc.get_traced_memory()[0]
        store = load_map_store(npy)
        current, peak = tracemalloc.get_traced_memory()
        tracemalloc.stop()
        report("store_bytes_per_landmark", (current - base) / m, "B")
        report("store_peak_bytes_per_landmark", (peak - base) / m, "B")
        report("index_bytes_per_landmark", store.snapshot().index_nbytes / m, "B")
        del store
        npy.unlink()
        gc.collect()

        colmap = tmpdir / "colmap"
        colmap.mkdir()
        write_colmap_bin(colmap, pts, rng)
        report("load_colmap_bin_with_images_s", _median_time(lambda: load_landmarks(colmap), 1), "s")
        lone = tmpdir / "lone"
        lone.mkdir()
        (colmap / "points3D.bin").rename(lone / "points3D.bin")
        report("load_colmap_bin_s", _median_time(lambda: load_landmarks(lone / "points3D.bin"), 1), "s")
        gc.collect()

    _bench_queries(pts, center, repeats, report)
    del pts
    gc.collect()
    _bench_occlusion(rng, repeats, report)
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=2) + "\n")
    return 0


def _bench_ascii_ply(rng: np.random.Generator, repeats: int, report, n: int = 200_000) -> None:
    """An ASCII PLY of ``n`` vertices (x y z float, red green blue uchar, faces after them): the block parser
    against plyfile's own ASCII reader (the fallback path), timed alternately in one run."""
    from unittest import mock

    import plyfile

    from pivotd.maps import formats_ply

    v = np.zeros(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("red", "u1"), ("green", "u1"), ("blue", "u1")])
    for c in "xyz":
        v[c] = rng.uniform(-50, 50, n)
    f = np.zeros(n // 2, dtype=[("vertex_indices", "i4", (3,))])
    f["vertex_indices"] = rng.integers(0, n, (n // 2, 3))
    with tempfile.TemporaryDirectory(prefix="pivotd-bench-ply-") as tmp:
        path = Path(tmp) / "map.ply"
        plyfile.PlyData([plyfile.PlyElement.describe(v, "vertex"), plyfile.PlyElement.describe(f, "face")],
                        text=True).write(str(path))

        def slow() -> None:
            with mock.patch.object(formats_ply, "_ascii_vertices", lambda *a: None):
                load_landmarks(path)

        fast_t, slow_t, ratio = _paired_times(lambda: load_landmarks(path), slow, max(3, repeats))
    report("load_ply_ascii_200k_block_parser_s", fast_t, "s")
    report("load_ply_ascii_200k_plyfile_s", slow_t, "s")
    report("load_ply_ascii_plyfile_over_block_parser", 1.0 / ratio, "x")


def _bench_queries(pts: np.ndarray, center: np.ndarray, repeats: int, report) -> None:
    store = MapStore()
    store.set_layer("base", LandmarkCloud(pts, np.ones(pts.shape[0], np.float32)))
    big = store.snapshot()
    flt = RetainedFilter(max_range=QUERY_RANGE)
    one = center[None, :]
    horizon = center + np.c_[np.linspace(-5, 5, HORIZON), np.zeros((HORIZON, 2))]
    r_one = big.retained(one, flt)
    r_hor = big.retained(horizon, flt)
    report("retained_one_count", float(r_one[0].size), "landmarks")
    report("retained_horizon_mean_count", float(np.mean([r.size for r in r_hor])), "landmarks")
    reps = max(repeats * 4, 10)
    small_one = _store_of(big.points[r_one[0]])
    small_hor = _store_of(big.points[np.unique(np.concatenate(r_hor))])
    t_one_big, t_one_small, r_one_ratio = _paired_times(
        lambda: big.retained(one, flt), lambda: small_one.retained(one, flt), reps)
    t_hor_big, t_hor_small, r_hor_ratio = _paired_times(
        lambda: big.retained(horizon, flt), lambda: small_hor.retained(horizon, flt), reps)
    report("retained_one_big_ms", 1e3 * t_one_big, "ms")
    report("retained_one_big_best_ms", 1e3 * _best_time(lambda: big.retained(one, flt), reps), "ms")
    report("retained_one_small_ms", 1e3 * t_one_small, "ms")
    report("retained_one_big_over_small", r_one_ratio, "x")
    report("retained_horizon40_big_ms", 1e3 * t_hor_big, "ms")
    report("retained_horizon40_big_best_ms", 1e3 * _best_time(lambda: big.retained(horizon, flt), reps), "ms")
    report("retained_horizon40_small_ms", 1e3 * t_hor_small, "ms")
    report("retained_horizon40_big_over_small", r_hor_ratio, "x")
    view = RetainedFilter(max_range=QUERY_RANGE, max_view_angle_deg=60.0)
    dirs = np.zeros_like(pts)
    dirs[:, 2] = 1.0
    store.set_layer("base", LandmarkCloud(pts, np.ones(pts.shape[0], np.float32), dirs))
    snap = store.snapshot()
    report("retained_horizon40_view_filter_ms", 1e3 * _median_time(lambda: snap.retained(horizon, view), reps), "ms")


def _store_of(points: np.ndarray):
    store = MapStore()
    store.set_layer("base", LandmarkCloud(np.ascontiguousarray(points), np.ones(points.shape[0], np.float32)))
    return store.snapshot()


def _bench_occlusion(rng: np.random.Generator, repeats: int, report) -> None:
    grid, sensor, targets, near = _room_scene(rng, 0.2)
    reps = max(repeats * 4, 10)
    report("occlusion_20k_blocked_fraction", float(grid.occluded(sensor, targets).mean()), "")
    for step in (0.5, 1.0):
        t = _median_time(lambda step=step: grid.occluded(sensor, targets, step=step), reps)
        best = _best_time(lambda step=step: grid.occluded(sensor, targets, step=step), reps)
        report(f"occlusion_20k_rays_step{step:g}_ms", 1e3 * t, "ms")
        report(f"occlusion_20k_rays_step{step:g}_best_ms", 1e3 * best, "ms")
    report("occlusion_20k_within_8m_blocked_fraction", float(grid.occluded(sensor, near).mean()), "")
    t = _median_time(lambda: grid.occluded(sensor, near), reps)
    report("occlusion_20k_rays_within_8m_step1_ms", 1e3 * t, "ms")
