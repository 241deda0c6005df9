"""COLMAP models written by hand per COLMAP's documented text and binary layouts."""

from __future__ import annotations

import math
import shutil
import struct
from pathlib import Path

import numpy as np
import pytest

from pivotd.errors import InputError
from pivotd.maps.formats import load_landmarks

S = math.sqrt(0.5)
# Image 1: identity rotation, centre (2, 0, 0) -> t = -C.
# Image 2: rotation 90° about z (qw = qz = √½), centre (0, 3, 0) -> t = -R C = (3, 0, 0).
IMAGES = [
    (1, (1.0, 0.0, 0.0, 0.0), (-2.0, 0.0, 0.0), 1, "left.png", [(10.5, 20.5, 7), (11.0, 3.0, 8), (5.0, 5.0, -1)]),
    (2, (S, 0.0, 0.0, S), (3.0, 0.0, 0.0), 1, "right.png", [(1.0, 2.0, 7)]),
    (5, (1.0, 0.0, 0.0, 0.0), (0.0, 0.0, 0.0), 1, "unused.png", []),
]
# (id, xyz, rgb, error, track [(image_id, point2D_idx)])
POINTS = [
    (7, (0.0, 0.0, 0.0), (255, 0, 0), 0.5, [(1, 0), (2, 0)]),
    (8, (1.0, 1.0, 1.0), (0, 255, 0), 0.25, [(1, 1)]),
    (9, (-1.5, 2.25, 4.0), (0, 0, 255), 1.0, [(99, 3)]),  # image 99 is not in the model
    (12, (3.0, -1.0, 0.5), (1, 2, 3), 0.1, []),
]
EXPECTED_DIRECTIONS = np.array([
    [S, S, 0.0],  # mean of (1,0,0) and (0,1,0)
    np.array([1.0, -1.0, -1.0]) / math.sqrt(3.0),
    [0.0, 0.0, 0.0],
    [0.0, 0.0, 0.0],
])


def write_text_model(d: Path, points=POINTS, images=IMAGES) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    lines = ["# 3D point list with one line of data per point:",
             "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
             f"# Number of points: {len(points)}, mean track length: 1"]
    for pid, xyz, rgb, err, track in points:
        fields = [str(pid), *map(repr, xyz), *map(str, rgb), repr(err)]
        for img, p2 in track:
            fields += [str(img), str(p2)]
        lines.append(" ".join(fields))
    (d / "points3D.txt").write_text("\n".join(lines) + "\n")
    lines = ["# Image list with two lines of data per image:",
             "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
             "#   POINTS2D[] as (X, Y, POINT3D_ID)",
             f"# Number of images: {len(images)}, mean observations per image: 1"]
    for iid, q, t, cam, name, kps in images:
        lines.append(" ".join([str(iid), *map(repr, q), *map(repr, t), str(cam), name]))
        lines.append(" ".join(f"{x!r} {y!r} {p}" for x, y, p in kps))
    (d / "images.txt").write_text("\n".join(lines) + "\n")
    return d


def write_binary_model(d: Path, points=POINTS, images=IMAGES) -> Path:
    d.mkdir(parents=True, exist_ok=True)
    out = [struct.pack("<Q", len(points))]
    for pid, xyz, rgb, err, track in points:
        out.append(struct.pack("<QdddBBBdQ", pid, *xyz, *rgb, err, len(track)))
        for img, p2 in track:
            out.append(struct.pack("<ii", img, p2))
    (d / "points3D.bin").write_bytes(b"".join(out))
    out = [struct.pack("<Q", len(images))]
    for iid, q, t, cam, name, kps in images:
        out.append(struct.pack("<idddddddi", iid, *q, *t, cam))
        out.append(name.encode() + b"\0")
        out.append(struct.pack("<Q", len(kps)))
        for x, y, p in kps:
            out.append(struct.pack("<ddq", x, y, p))
    (d / "images.bin").write_bytes(b"".join(out))
    return d


def test_text_and_binary_models_agree_and_directions_are_hand_checked(tmp_path):
    txt = load_landmarks(write_text_model(tmp_path / "txt"))
    binary = load_landmarks(write_binary_model(tmp_path / "bin"))
    expected_xyz = np.array([p[1] for p in POINTS])
    for cloud in (txt, binary):
        np.testing.assert_allclose(cloud.points, expected_xyz)
        np.testing.assert_allclose(cloud.weights, 1.0)
        np.testing.assert_allclose(cloud.directions, EXPECTED_DIRECTIONS, atol=1e-6)
    np.testing.assert_array_equal(txt.points, binary.points)
    np.testing.assert_array_equal(txt.directions, binary.directions)


def test_points3d_file_itself_and_without_images(tmp_path):
    d = write_binary_model(tmp_path / "m")
    with_images = load_landmarks(d / "points3D.bin")
    assert with_images.directions is not None
    lone = tmp_path / "lone"
    lone.mkdir()
    shutil.copy(d / "points3D.bin", lone / "points3D.bin")
    cloud = load_landmarks(lone / "points3D.bin")
    assert cloud.directions is None
    assert len(cloud) == 4


def test_binary_reader_matches_text_on_a_larger_random_model(tmp_path):
    rng = np.random.default_rng(3)
    images = [(i, tuple((q / np.linalg.norm(q)).tolist()), tuple(rng.normal(size=3).tolist()), 1, f"im{i}.jpg", [])
              for i, q in ((i, rng.normal(size=4)) for i in range(1, 30))]
    points = []
    for k in range(500):
        track = [(int(rng.integers(1, 30)), int(rng.integers(0, 1000))) for _ in range(int(rng.integers(0, 7)))]
        points.append((k * 3 + 1, tuple((rng.normal(size=3) * 10).tolist()), (1, 2, 3), float(rng.random()), track))
    txt = load_landmarks(write_text_model(tmp_path / "t", points, images))
    binary = load_landmarks(write_binary_model(tmp_path / "b", points, images))
    np.testing.assert_array_equal(txt.points, binary.points)
    np.testing.assert_array_equal(txt.directions, binary.directions)
    # Every landmark with a track has a unit direction.
    has_track = np.array([len(p[4]) > 0 for p in points])
    np.testing.assert_allclose(np.linalg.norm(binary.directions[has_track], axis=1), 1.0, atol=1e-6)


def _bad(tmp_path: Path, name: str, data: bytes) -> str:
    d = tmp_path / "bad"
    d.mkdir(exist_ok=True)
    f = d / name
    f.write_bytes(data)
    with pytest.raises(InputError) as exc:
        load_landmarks(f)
    msg = str(exc.value)
    assert "\n" not in msg and str(f) in msg
    return msg


def test_truncated_and_corrupt_binary_points(tmp_path):
    good = (write_binary_model(tmp_path / "m") / "points3D.bin").read_bytes()
    assert "truncated at byte" in _bad(tmp_path, "points3D.bin", good[:-3])
    assert "truncated at byte 4" in _bad(tmp_path, "points3D.bin", good[:4])
    assert "header claims 1000000 points" in _bad(tmp_path, "points3D.bin", struct.pack("<Q", 10**6) + good[8:])
    assert "unexpected trailing bytes" in _bad(tmp_path, "points3D.bin", good + b"\0\0")
    huge = bytearray(good)
    struct.pack_into("<Q", huge, 8 + 43, 2**62)  # track length of the first point
    assert "corrupt track length in point record 0 at byte 8" in _bad(tmp_path, "points3D.bin", bytes(huge))
    struct.pack_into("<Q", huge, 8 + 43, 10**9)
    assert "truncated at byte" in _bad(tmp_path, "points3D.bin", bytes(huge))
    nan = bytearray(good)
    struct.pack_into("<d", nan, 8 + 8 + 8, float("nan"))  # y of the first point
    assert "point 0 is not finite" in _bad(tmp_path, "points3D.bin", bytes(nan))


def test_truncated_images_bin(tmp_path):
    d = write_binary_model(tmp_path / "m")
    data = (d / "images.bin").read_bytes()
    (d / "images.bin").write_bytes(data[:-10])
    with pytest.raises(InputError, match=r"images\.bin: truncated at byte"):
        load_landmarks(d)


def test_bad_text_lines_are_named(tmp_path):
    d = write_text_model(tmp_path / "m")
    lines = (d / "points3D.txt").read_text().splitlines()
    lines[4] = "8 1.0 1.0"
    (d / "points3D.txt").write_text("\n".join(lines) + "\n")
    with pytest.raises(InputError, match=r"points3D\.txt:5: expected POINT3D_ID"):
        load_landmarks(d)
    d2 = write_text_model(tmp_path / "m2")
    text = (d2 / "images.txt").read_text().replace("2 0.7071", "2 zero", 1)
    (d2 / "images.txt").write_text(text)
    with pytest.raises(InputError, match=r"images\.txt:7: not a number"):
        load_landmarks(d2)


def test_directory_without_model(tmp_path):
    with pytest.raises(InputError, match="holds no COLMAP points3D"):
        load_landmarks(tmp_path)
