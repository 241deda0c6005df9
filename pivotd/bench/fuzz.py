"""``pivotd bench fuzz``: ``pivotd plan`` / ``check`` over mutated maps, paths and configs, in-process.

A corpus of honest files (``.npy`` (N,3)/(N,4), text and CSV maps, ASCII and binary PLY, COLMAP
text and binary models, 3- and 8-column paths, a config) is mutated: bit flips, byte overwrites,
insertions and deletions, truncation, duplicated chunks, numeric tokens replaced by extreme values
(2³¹, 2⁶³, 1e200, -1, nan, …) and, for PLY / ``.npy`` / COLMAP, header counts and ids replaced by
huge ones. Each case runs the CLI's ``main`` (``plan`` for maps and paths, ``check`` for configs) and
the reader alone under ``tracemalloc``.

Reported per run: cases, **tracebacks** (any exception escaping ``main`` or a reader other than our
one-line :class:`~pivotd.errors.PivotdError`), exit codes, the slowest case [s], and the largest
ratio of the readers' peak traced memory to the file's honest size: max(file bytes, 24 B per
landmark loaded — the landmarks as float64 x, y, z), above a fixed allowance of :data:`MEMORY_ALLOWANCE` bytes
for constant overheads.

The same corpus and mutations drive ``tests/test_hostile_fuzz.py`` (through hypothesis).
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import logging
import re
import tempfile
import time
import tracemalloc
from collections import Counter
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import PivotdError
from pivotd.progress import with_progress

log = logging.getLogger(__name__)

MEMORY_ALLOWANCE = 1 << 20  # bytes of reader overhead not tied to the file (imports, parser state)
BYTES_PER_LANDMARK = 24  # honest decoded size of one landmark: float64 x, y, z
EXTREMES = (b"2147483648", b"4294967296", b"9223372036854775808", b"99999999999999999999999", b"1e200",
            b"-1e200", b"1e-300", b"-1", b"0", b"nan", b"inf", b"4611686018427387904")
MUTATIONS = ("flip", "byte", "insert", "delete", "truncate", "duplicate", "token", "count")
_NUMBER = re.compile(rb"-?\d+(\.\d+)?([eE][-+]?\d+)?")


@dataclass(frozen=True)
class Seed:
    """One honest input: ``kind`` is map, path or config; ``files`` the files making it (a COLMAP model
    has two); ``target`` what the CLI is given (a file or a model directory)."""

    name: str
    kind: str
    files: tuple[Path, ...]
    target: Path


def write_corpus(directory: Path, seed: int = 0, landmarks: int = 40) -> list[Seed]:
    """Write the honest corpus (maps of ``landmarks`` points) under ``directory``; returns its seeds."""
    import plyfile

    from pivotd.bench.maps import write_colmap_bin, write_pcd

    rng = np.random.default_rng(seed)
    d = Path(directory)
    pts = rng.uniform(-8.0, 8.0, (landmarks, 3))
    w = rng.uniform(0.5, 2.0, landmarks)
    seeds: list[Seed] = []

    def add(name: str, kind: str, *files: Path, target: Path | None = None) -> None:
        seeds.append(Seed(name, kind, tuple(files), target or files[0]))

    np.save(d / "map4.npy", np.column_stack([pts, w]))
    add("npy4", "map", d / "map4.npy")
    np.save(d / "map3.npy", pts.astype(np.float32))
    add("npy3", "map", d / "map3.npy")
    (d / "map.txt").write_text("# x y z w\n" + "".join(f"{a:.4f} {b:.4f} {c:.4f} {e:.3f}\n"
                                                      for (a, b, c), e in zip(pts, w, strict=True)))
    add("txt", "map", d / "map.txt")
    (d / "map.csv").write_text("".join(f"{a:.4f},{b:.4f},{c:.4f}\n" for a, b, c in pts))
    add("csv", "map", d / "map.csv")
    vertex = np.empty(landmarks, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("weight", "f4")])
    vertex["x"], vertex["y"], vertex["z"], vertex["weight"] = pts[:, 0], pts[:, 1], pts[:, 2], w
    face = np.empty(3, dtype=[("vertex_indices", "i4", (3,))])
    face["vertex_indices"] = [[0, 1, 2], [3, 4, 5], [6, 7, 8]]
    elements = [plyfile.PlyElement.describe(vertex, "vertex"), plyfile.PlyElement.describe(face, "face")]
    for name, text, order in (("ply_ascii", True, "="), ("ply_le", False, "<"), ("ply_be", False, ">")):
        plyfile.PlyData(elements, text=text, byte_order=order).write(str(d / f"{name}.ply"))
        add(name, "map", d / f"{name}.ply")
    (d / "map_header.csv").write_text("x,y,z,intensity,weight\n" + "".join(
        f"{a:.4f},{b:.4f},{c:.4f},7,{e:.3f}\n" for (a, b, c), e in zip(pts, w, strict=True)))
    add("csv_header", "map", d / "map_header.csv")
    fields = {"x": pts[:, 0].astype(np.float32), "y": pts[:, 1].astype(np.float32), "z": pts[:, 2].astype(np.float32),
              "rgb": rng.integers(0, 1 << 24, landmarks).astype(np.uint32), "weight": w.astype(np.float32)}
    for data in ("ascii", "binary", "binary_compressed"):
        write_pcd(d / f"pcd_{data}.pcd", fields, data)
        add(f"pcd_{data}", "map", d / f"pcd_{data}.pcd")
    (d / "colmap_bin").mkdir()
    write_colmap_bin(d / "colmap_bin", pts, rng, images=6)
    add("colmap_bin_points", "map", d / "colmap_bin" / "points3D.bin", d / "colmap_bin" / "images.bin",
        target=d / "colmap_bin")
    add("colmap_bin_images", "map", d / "colmap_bin" / "images.bin", d / "colmap_bin" / "points3D.bin",
        target=d / "colmap_bin")
    (d / "colmap_txt").mkdir()
    _write_colmap_text(d / "colmap_txt", pts, rng)
    add("colmap_txt_points", "map", d / "colmap_txt" / "points3D.txt", d / "colmap_txt" / "images.txt",
        target=d / "colmap_txt")
    add("colmap_txt_images", "map", d / "colmap_txt" / "images.txt", d / "colmap_txt" / "points3D.txt",
        target=d / "colmap_txt")
    xs = np.linspace(-6.0, 6.0, 12)
    (d / "path3.csv").write_text("".join(f"{x:.3f},{0.5 * x:.3f},0.0\n" for x in xs))
    add("path3", "path", d / "path3.csv")
    (d / "path_header.csv").write_text("t,x,y,z,qx,qy,qz,qw\n" + "".join(
        f"{0.1 * i:.2f},{x:.3f},0.0,0.0,0.0,0.0,0.0,1.0\n" for i, x in enumerate(xs)))
    add("path_header", "path", d / "path_header.csv")
    (d / "path8.csv").write_text("".join(f"{int(1.7e18 + i * 1e8)},{x:.3f},0.0,0.0,1.0,0.0,0.0,0.0\n"
                                         for i, x in enumerate(xs)))
    add("path8", "path", d / "path8.csv")
    (d / "pivotd.yaml").write_text(_CONFIG.format(map=d / "map.txt"))
    add("config", "config", d / "pivotd.yaml")
    return seeds


_CONFIG = """\
name: fuzz  # a complete config
zenoh:
  mode: peer
  listen: [tcp/127.0.0.1:0]
topics:
  pose: /odom
  frame_id: map
map:
  file: {map}
  filters:
    min_range: 0.5
    max_range: 12.0
    occlusion_voxel: 0.25
  layers: &layers
    landmarks: 1.0
    targets: 2.0
pivot:
  fov_deg: 60
  lambda: 0.6
planner:
  waypoint_spacing: 0.5
  horizon: 20
gimbal:
  port: "mock://"
  watchdog_ms: 250
  limits:
    pan_min_deg: -170
    pan_max_deg: 170
    tilt_min_deg: -90
    tilt_max_deg: 90
  park:
    pan_deg: 0
    tilt_deg: 0
motion:
  pan: {{max_velocity_deg_s: 90, max_acceleration_deg_s2: 180, max_jerk_deg_s3: 900}}
  tilt: {{max_velocity_deg_s: 90, max_acceleration_deg_s2: 180, max_jerk_deg_s3: 900}}
control:
  rate_hz: 100
"""


def _write_colmap_text(d: Path, pts: np.ndarray, rng: np.random.Generator) -> None:
    lines = ["# 3D point list"]
    for i, p in enumerate(pts, start=1):
        track = " ".join(f"{int(rng.integers(1, 7))} {k}" for k in range(3))
        lines.append(f"{i} {p[0]:.4f} {p[1]:.4f} {p[2]:.4f} 128 128 128 0.5 {track}")
    (d / "points3D.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list"]
    for i in range(1, 7):
        c = rng.uniform(-5, 5, 3)
        lines.append(f"{i} 1 0 0 0 {-c[0]:.3f} {-c[1]:.3f} {-c[2]:.3f} 1 img{i}.jpg")
        lines.append("10.0 20.0 1 30.0 40.0 -1")
    (d / "images.txt").write_text("\n".join(lines) + "\n")


# ------------------------------------------------------------------------------------------------ mutations


def mutate(data: bytes, op: str, pos: int, value: int) -> bytes:
    """``data`` with one mutation ``op`` (one of MUTATIONS) at relative position ``pos`` (any int, taken
    modulo the length) parameterised by ``value`` (any int ≥ 0)."""
    n = len(data)
    if n == 0:
        return bytes([value % 256])
    i = pos % n
    if op == "flip":
        return data[:i] + bytes([data[i] ^ (1 << (value % 8))]) + data[i + 1:]
    if op == "byte":
        return data[:i] + bytes([value % 256]) + data[i + 1:]
    if op == "insert":
        return data[:i] + bytes([(value >> (8 * k)) % 256 for k in range(1 + value % 8)]) + data[i:]
    if op == "delete":
        return data[:i] + data[i + 1 + value % 64:]
    if op == "truncate":
        return data[:i]
    if op == "duplicate":
        chunk = data[i:i + 1 + value % 256]
        return data[:i] + chunk * (2 + value % 3) + data[i:]
    if op == "token":
        return _replace_number(data, pos, EXTREMES[value % len(EXTREMES)])
    if op == "count":
        return _replace_count(data, pos, value)
    raise ValueError(f"unknown mutation {op!r}")


def _replace_number(data: bytes, pos: int, new: bytes) -> bytes:
    """Replace one numeric token (chosen by ``pos``) of a text file by ``new``."""
    matches = list(_NUMBER.finditer(data))
    if not matches:
        return data + b" " + new
    m = matches[pos % len(matches)]
    return data[:m.start()] + new + data[m.end():]


def _replace_count(data: bytes, pos: int, value: int) -> bytes:
    """Overwrite a count-like field with a huge value: a header number of a text/PLY/npy header, else an
    aligned 4- or 8-byte little-endian integer of a binary file."""
    huge = (1 << 31, (1 << 31) - 1, 1 << 32, 1 << 62, (1 << 64) - 1, 5_800_000_000)[value % 6]
    head = data[:512]
    if b"end_header" in head or head.startswith(b"\x93NUMPY") or head[:1].isdigit() or head[:1] in b"#-":
        return _replace_number(data, pos % 8, str(huge).encode())
    width = 8 if value % 2 else 4
    i = (pos % max(1, len(data) - width + 1)) if len(data) >= width else 0
    return data[:i] + (huge % (1 << (8 * width))).to_bytes(width, "little") + data[i + width:]


# ------------------------------------------------------------------------------------------------ running


@dataclass(frozen=True)
class Outcome:
    """Result of one case: ``error`` is the escaped exception's type name (a traceback) or None; ``code``
    the CLI exit code; ``peak`` the reader's peak traced bytes and ``honest`` the file's honest size."""

    seed: str
    code: int | None
    error: str | None
    seconds: float
    peak: int
    honest: int

    @property
    def memory_ratio(self) -> float:
        return max(0, self.peak - MEMORY_ALLOWANCE) / self.honest


def measure_reader(call: Callable[[], object], file_bytes: int) -> tuple[int, int, str | None]:
    """(peak traced bytes, honest size, escaped exception type or None) of one reader call."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    error = None
    landmarks = 0
    try:
        result = call()
        landmarks = len(result) if hasattr(result, "__len__") else 0
    except PivotdError:
        pass
    except Exception as exc:  # the defect being counted
        error = type(exc).__name__
    finally:
        peak = tracemalloc.get_traced_memory()[1]
        tracemalloc.stop()
    return peak, max(file_bytes, BYTES_PER_LANDMARK * landmarks, 1), error


def run_cli(argv: list[str]) -> tuple[int | None, str | None]:
    """(exit code, escaped exception type or None) of ``pivotd ARGV`` run in-process, output discarded."""
    from pivotd.cli import main

    sink = io.StringIO()
    try:
        with contextlib.redirect_stdout(sink), contextlib.redirect_stderr(sink):
            return main(argv), None
    except SystemExit as exc:  # argparse
        return int(exc.code or 0), None
    except Exception as exc:
        return None, type(exc).__name__


def run_case(seed: Seed, corpus: dict[str, Seed], data: bytes, workdir: Path) -> Outcome:
    """Write ``data`` over a copy of the seed's first file in ``workdir`` and run the CLI and reader on it."""
    from pivotd.config import load_config
    from pivotd.maps.formats import load_landmarks
    from pivotd.robot_path import load_path

    for f in seed.files[1:]:
        (workdir / f.name).write_bytes(f.read_bytes())
    target = workdir / seed.files[0].name
    target.write_bytes(data)
    given = workdir if seed.target.is_dir() else target
    t0 = time.perf_counter()
    if seed.kind == "map":
        # Every other case also runs the range and occlusion filters (grid index and occupancy grid).
        filters = ["--max-range", "12", "--occlusion-voxel", "0.25"] if len(data) % 2 else []
        code, error = run_cli(["plan", "--map", str(given), "--path", str(corpus["path3"].target), *filters])
        reader: Callable[[], object] = lambda: load_landmarks(given)  # noqa: E731
    elif seed.kind == "path":
        code, error = run_cli(["plan", "--map", str(corpus["npy4"].target), "--path", str(given)])
        reader = lambda: load_path(given)  # noqa: E731
    else:
        code, error = run_cli(["check", "--config", str(given)])
        reader = lambda: load_config(given)  # noqa: E731
    seconds = time.perf_counter() - t0
    peak, honest, reader_error = measure_reader(reader, len(data))
    return Outcome(seed.name, code, error or reader_error, seconds, peak, honest)


def random_cases(seeds: list[Seed], cases: int, rng: np.random.Generator):
    """Yield (seed, mutated bytes): 1–3 random mutations of a random seed's first file."""
    for _ in range(cases):
        seed = seeds[int(rng.integers(len(seeds)))]
        data = seed.files[0].read_bytes()
        for _ in range(int(rng.integers(1, 4))):
            op = MUTATIONS[int(rng.integers(len(MUTATIONS)))]
            data = mutate(data, op, int(rng.integers(1 << 30)), int(rng.integers(1 << 30)))
        yield seed, data


# ------------------------------------------------------------------------------------------------ bench


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--cases", type=int, default=2000, help="mutated inputs to run (default 2000)")
    parser.add_argument("--seed", type=int, default=0)
    parser.add_argument("--honest-landmarks", type=int, default=100_000,
                        help="also load every map format holding this many landmarks and report the readers' peak "
                             "memory / honest size (default 100000; 0 skips)")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")


def honest_memory(landmarks: int, seed: int = 0) -> dict[str, dict]:
    """Per map format: file bytes, honest size, reader peak traced bytes and their ratio for honest files of
    ``landmarks`` points (each loaded once before measuring, so imports are not counted)."""
    from pivotd.maps.formats import load_landmarks

    out: dict[str, dict] = {}
    with tempfile.TemporaryDirectory(prefix="pivotd-honest-") as tmp:
        for s in write_corpus(Path(tmp), seed, landmarks):
            if s.kind != "map" or s.name.endswith("_images"):
                continue
            size = sum(f.stat().st_size for f in s.files)
            load_landmarks(s.target)
            t0 = time.perf_counter()
            peak, honest, error = measure_reader(lambda s=s: load_landmarks(s.target), size)
            out[s.name] = {"file_bytes": size, "honest_bytes": honest, "peak_bytes": peak,
                           "peak_over_honest": round(peak / honest, 2), "seconds": round(time.perf_counter() - t0, 2),
                           "error": error}
    return out


def run(args: argparse.Namespace) -> int:
    logging.getLogger("pivotd").setLevel(logging.CRITICAL)  # the cases' own error lines are expected
    rng = np.random.default_rng(args.seed)
    outcomes: list[Outcome] = []
    with tempfile.TemporaryDirectory(prefix="pivotd-fuzz-") as tmp:
        corpus_dir, work = Path(tmp) / "corpus", Path(tmp) / "work"
        corpus_dir.mkdir()
        seeds = write_corpus(corpus_dir, args.seed)
        by_name = {s.name: s for s in seeds}
        t0 = time.perf_counter()
        cases = with_progress(random_cases(seeds, args.cases, rng), "fuzz cases", total=args.cases)
        for k, (seed, data) in enumerate(cases):
            case_dir = work / str(k)
            case_dir.mkdir(parents=True)
            out = run_case(seed, by_name, data, case_dir)
            if out.error:
                log.error("case %d (%s): %s escaped", k, seed.name, out.error)
            outcomes.append(out)
            for f in case_dir.iterdir():
                f.unlink()
            case_dir.rmdir()
        total = time.perf_counter() - t0
    result = summarize(outcomes, total)
    if args.honest_landmarks:
        result["honest_files"] = honest_memory(args.honest_landmarks, args.seed)
    print(json.dumps(result, indent=2))
    if args.json:
        Path(args.json).write_text(json.dumps(result, indent=2) + "\n")
    return 1 if result["tracebacks"] else 0



def summarize(outcomes: list[Outcome], total_s: float) -> dict:
    """JSON-friendly totals of a fuzz run."""
    seconds = sorted(o.seconds for o in outcomes)
    worst = max(outcomes, key=lambda o: o.memory_ratio)
    return {
        "cases": len(outcomes),
        "tracebacks": sum(o.error is not None for o in outcomes),
        "traceback_types": dict(Counter(o.error for o in outcomes if o.error)),
        "exit_codes": {str(k): v for k, v in sorted(Counter(o.code for o in outcomes).items(), key=str)},
        "cases_per_seed": dict(Counter(o.seed for o in outcomes)),
        "median_case_s": round(seconds[len(seconds) // 2], 4),
        "max_case_s": round(seconds[-1], 3),
        "runs_over_10_s": sum(s > 10.0 for s in seconds),
        "max_reader_peak_bytes": max(o.peak for o in outcomes),
        "max_memory_ratio_above_allowance": round(worst.memory_ratio, 3),
        "worst_memory_case": {"seed": worst.seed, "peak": worst.peak, "honest": worst.honest},
        "total_s": round(total_s, 1),
    }

