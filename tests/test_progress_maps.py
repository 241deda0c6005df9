"""Progress lines of map loading: PLY (ASCII, binary memory-mapped, binary with lists), .npy and COLMAP (binary
and text models, observation directions), on a fake terminal; values unchanged, errors end the line first."""

from __future__ import annotations

import numpy as np
import plyfile
import pytest
from test_progress import FakeTTY, frames, not_silenced, terminal  # noqa: F401 (autouse fixture)

from pivotd import progress
from pivotd.bench.maps import write_colmap_bin
from pivotd.errors import InputError
from pivotd.maps.formats import load_landmarks

N = 20_000


@pytest.fixture(scope="module")
def pts() -> np.ndarray:
    return np.random.default_rng(3).uniform(-50, 50, (N, 3)).astype(np.float32)


def percents(tty: FakeTTY, label: str) -> list[float]:
    """The percentages drawn on lines starting with ``label:``."""
    return [float(f.split(":")[1].split("%")[0]) for f in frames(tty.getvalue()) if f.startswith(label + ":")]


def assert_climbs_to_full(values: list[float]) -> None:
    assert len(values) >= 2 and values[-1] == 100.0
    assert values == sorted(values)  # never goes backwards
    assert min(values) < 100.0  # something was drawn before the end


@pytest.mark.parametrize("kind", ["ascii", "binary", "binary_with_faces"])
def test_ply_loading_shows_bytes_read(tmp_path, pts, kind, monkeypatch):
    tty = terminal(monkeypatch)
    n = 4000  # plyfile parses ASCII row by row
    pts = pts[:n]
    weights = np.linspace(0, 1, n, dtype=np.float32)
    vertex = np.empty(n, dtype=[("x", "f4"), ("y", "f4"), ("z", "f4"), ("weight", "f4")])
    for k, c in enumerate("xyz"):
        vertex[c] = pts[:, k]
    vertex["weight"] = weights
    elements = [plyfile.PlyElement.describe(vertex, "vertex")]
    if kind == "binary_with_faces":  # a list element: plyfile reads it through the stream, record by record
        faces = np.empty(2000, dtype=[("vertex_indices", "i4", (3,))])
        faces["vertex_indices"] = np.arange(6000).reshape(-1, 3)
        elements.append(plyfile.PlyElement.describe(faces, "face"))
    path = tmp_path / "map.ply"
    plyfile.PlyData(elements, text=kind == "ascii").write(str(path))
    cloud = load_landmarks(path)
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.weights, weights)
    assert_climbs_to_full(percents(tty, "reading map.ply"))
    size = path.stat().st_size / 1e6
    assert frames(tty.getvalue())[-1].startswith(f"reading map.ply: 100% {size:.1f}/{size:.1f} MB")
    assert tty.getvalue().endswith("\n")


@pytest.mark.parametrize("cols", [3, 4])
def test_npy_loading_shows_bytes_converted(tmp_path, pts, cols, monkeypatch):
    tty = terminal(monkeypatch)
    monkeypatch.setattr("pivotd.maps.formats._NPY_BLOCK", 4096)  # several blocks on a small file
    arr = np.column_stack([pts.astype(np.float64), np.linspace(0, 2, N)])[:, :cols]
    np.save(tmp_path / "map.npy", arr)
    cloud = load_landmarks(tmp_path / "map.npy")
    np.testing.assert_array_equal(cloud.points, pts)
    np.testing.assert_array_equal(cloud.weights, arr[:, 3].astype(np.float32) if cols == 4 else np.ones(N))
    values = percents(tty, "reading map.npy")
    assert_climbs_to_full(values)
    assert len(values) >= N // 4096  # one line per block at least
    mb = N * cols * 8 / 1e6
    assert frames(tty.getvalue())[-1].startswith(f"reading map.npy: 100% {mb:.1f}/{mb:.1f} MB ")


def test_colmap_binary_model_shows_points_and_directions(tmp_path, pts, monkeypatch):
    tty = terminal(monkeypatch)
    monkeypatch.setattr("pivotd.maps.colmap._PROGRESS_BLOCK", 1024)
    model, lone = tmp_path / "model", tmp_path / "lone"
    model.mkdir()
    lone.mkdir()
    write_colmap_bin(model, pts.astype(np.float64), np.random.default_rng(0), images=50)
    (lone / "points3D.bin").write_bytes((model / "points3D.bin").read_bytes())
    plain = load_landmarks(lone / "points3D.bin")  # without images: no directions
    np.testing.assert_array_equal(plain.points, pts)
    assert_climbs_to_full(percents(tty, "reading points3D.bin"))
    assert percents(tty, "observation directions") == []
    cloud = load_landmarks(model)
    np.testing.assert_array_equal(cloud.points, pts)
    assert cloud.directions is not None and np.allclose(np.linalg.norm(cloud.directions, axis=1), 1, atol=1e-5)
    assert_climbs_to_full(percents(tty, "observation directions"))


def _write_text_model(d, pts: np.ndarray) -> None:
    rows = [f"{i} {x:.3f} {y:.3f} {z:.3f} 9 9 9 0.5 {1 + i % 3} 0 {1 + (i + 1) % 3} 1"
            for i, (x, y, z) in enumerate(pts, start=1)]
    (d / "points3D.txt").write_text("# POINT3D_ID X Y Z R G B ERROR TRACK[]\n" + "\n".join(rows) + "\n")
    (d / "images.txt").write_text("".join(f"{i} 1 0 0 0 {i} 0 0 1 im{i}.jpg\n\n" for i in (1, 2, 3)))


def test_colmap_text_model_shows_bytes_read(tmp_path, pts, monkeypatch):
    tty = terminal(monkeypatch)
    monkeypatch.setattr("pivotd.maps.colmap._PROGRESS_LINES", 1000)
    _write_text_model(tmp_path, pts)
    cloud = load_landmarks(tmp_path)
    np.testing.assert_allclose(cloud.points, pts, atol=6e-4)
    values = percents(tty, "reading points3D.txt")
    assert_climbs_to_full(values)
    assert len(values) >= N // 1000
    assert percents(tty, "reading images.txt")[-1] == 100.0


def test_a_bad_line_ends_the_progress_line_before_the_error_propagates(tmp_path, pts, monkeypatch):
    tty = terminal(monkeypatch)
    monkeypatch.setattr("pivotd.maps.colmap._PROGRESS_LINES", 1000)
    _write_text_model(tmp_path, pts)
    path = tmp_path / "points3D.txt"
    lines = path.read_text().splitlines(keepends=True)
    lines[15_001] = "15001 1.0 nan 2.0 9 9 9 0.5\n"
    path.write_text("".join(lines))
    with pytest.raises(InputError) as err:
        load_landmarks(path)
    # the reader's generator is still referenced by the traceback here: its line must already be ended
    assert str(err.value) == f"{path}:15002: coordinate is not finite (NaN or inf)"
    assert tty.getvalue().endswith("\n") and percents(tty, "reading points3D.txt")


def test_quiet_when_silenced(tmp_path, pts, monkeypatch):
    tty = terminal(monkeypatch)
    np.save(tmp_path / "map.npy", pts)
    progress.silence()
    assert len(load_landmarks(tmp_path / "map.npy")) == N
    assert tty.getvalue() == ""
