"""PCD maps: the three data kinds, field types, padding, organized clouds with invalid points, weights, and
one-line errors for broken files."""

from __future__ import annotations

import numpy as np
import pytest

from pivotd.bench.maps import write_pcd
from pivotd.errors import InputError
from pivotd.maps.formats import load_landmarks
from pivotd.maps.formats_pcd import LZF_MAX_RATIO

KINDS = ("ascii", "binary", "binary_compressed")


def _fields(n: int = 50, seed: int = 0) -> dict[str, np.ndarray]:
    rng = np.random.default_rng(seed)
    return {
        "x": rng.uniform(-50, 50, n).astype(np.float32),
        "y": rng.uniform(-50, 50, n).astype(np.float32),
        "z": rng.uniform(-5, 5, n).astype(np.float32),
        "rgb": rng.integers(0, 1 << 24, n).astype(np.uint32),
        "weight": rng.uniform(0.1, 3.0, n).astype(np.float32),
    }


@pytest.mark.parametrize("kind", KINDS)
def test_every_data_kind_reads_the_points_and_weights(tmp_path, kind):
    f = _fields()
    write_pcd(tmp_path / "m.pcd", f, kind)
    cloud = load_landmarks(tmp_path / "m.pcd")
    np.testing.assert_array_equal(cloud.points, np.column_stack([f["x"], f["y"], f["z"]]))
    np.testing.assert_array_equal(cloud.weights, f["weight"])


@pytest.mark.parametrize("kind", KINDS)
def test_float64_and_integer_fields_padding_and_a_named_weight(tmp_path, kind):
    rng = np.random.default_rng(3)
    n = 20
    f = {
        "_": np.zeros(n, np.uint8),  # PCL's padding field
        "x": rng.uniform(-1e3, 1e3, n),  # float64
        "y": rng.integers(-30000, 30000, n).astype(np.int16),
        "z": rng.integers(0, 200, n).astype(np.uint8),
        "intensity": rng.uniform(0, 5, n).astype(np.float32),
    }
    write_pcd(tmp_path / "m.pcd", f, kind)
    cloud = load_landmarks(tmp_path / "m.pcd", weight_property="intensity")
    np.testing.assert_allclose(cloud.points, np.column_stack([f["x"], f["y"], f["z"]]).astype(np.float32))
    np.testing.assert_array_equal(cloud.weights, f["intensity"])
    assert np.all(load_landmarks(tmp_path / "m.pcd").weights == 1.0)  # no 'weight' field: uniform


@pytest.mark.parametrize("kind", KINDS)
def test_organized_cloud_drops_invalid_nan_points(tmp_path, kind):
    f = _fields(48)
    for name in ("x", "y", "z"):
        f[name][[3, 17, 40]] = np.nan
    write_pcd(tmp_path / "m.pcd", f, kind, width=8)
    cloud = load_landmarks(tmp_path / "m.pcd")
    assert len(cloud) == 45
    keep = np.setdiff1d(np.arange(48), [3, 17, 40])
    np.testing.assert_array_equal(cloud.points[:, 0], f["x"][keep])


def test_pivotd_plan_accepts_a_pcd_map(tmp_path):
    from pivotd.cli import main

    f = _fields(200)
    write_pcd(tmp_path / "m.pcd", f, "binary")
    (tmp_path / "p.csv").write_text("0,0,0\n1,0,0\n")
    assert main(["plan", "--map", str(tmp_path / "m.pcd"), "--path", str(tmp_path / "p.csv"), "--json"]) == 0


def _header(fields="x y z", size="4 4 4", type_="F F F", count="1 1 1", width="2", points="2", data="binary"):
    return (f"VERSION 0.7\nFIELDS {fields}\nSIZE {size}\nTYPE {type_}\nCOUNT {count}\nWIDTH {width}\nHEIGHT 1\n"
            f"VIEWPOINT 0 0 0 1 0 0 0\nPOINTS {points}\nDATA {data}\n").encode()


BODY = np.arange(6, dtype="<f4").tobytes()


@pytest.mark.parametrize(
    ("content", "message"),
    [
        (_header() + BODY[:-1], "truncated PCD: 2 points of 12 bytes"),
        (_header(points="3") + BODY, "POINTS 3 is not WIDTH × HEIGHT"),
        (_header(fields="x y q") + BODY, "no z field"),
        (_header(type_="F F X") + BODY, "unsupported type X"),
        (_header(size="4 4 3") + BODY, "unsupported type F of size 3"),
        (_header(count="1 1 2") + BODY + BODY, "field 'z' has COUNT 2"),
        (_header(data="zip") + BODY, "unknown PCD data kind 'zip'"),
        (_header(width="two") + BODY, "WIDTH values must be integers"),
        (_header(fields="x y z", size="4 4") + BODY, "SIZE needs 3"),
        (b"VERSION 0.7\nFIELDS x y z\n" + BODY, "no DATA line"),
        (b"FROB 1\n" + _header(), "unknown PCD header key 'FROB'"),
        (_header(data="ascii") + b"1 2 3\n4 5\n", "point 1: expected 3 values, got 2"),
        (_header(data="ascii") + b"1 2 3\n4 5 six\n", "point 1: not a number"),
        (_header(data="ascii") + b"1 2 3\n", "header says 2 points, the ASCII data holds 1"),
        (_header(data="ascii") + b"1 2 3\n4 5 6\n7 8 9\n", "the ASCII data holds more"),
        (_header(data="ascii") + b"nan 2 3\ninf 5 6\n", "point 1 has a non-finite coordinate"),
        (_header(fields="x y z weight", size="4 4 4 4", type_="F F F F", count="1 1 1 1", data="ascii")
         + b"nan 2 3 1\n4 5 6 nan\n", "point 1 has a non-finite weight"),
    ],
)
def test_broken_files_give_one_line_errors(tmp_path, content, message):
    p = tmp_path / "bad.pcd"
    p.write_bytes(content)
    with pytest.raises(InputError) as err:
        load_landmarks(p)
    assert message in str(err.value)
    assert str(p) in str(err.value) and "\n" not in str(err.value)


def test_compressed_sizes_are_checked_before_decompressing(tmp_path):
    import lzf

    planes = np.arange(6, dtype="<f4").tobytes()
    packed = lzf.compress(planes, 64)
    ok = _header(data="binary_compressed") + np.array([len(packed), len(planes)], "<u4").tobytes() + packed
    (tmp_path / "ok.pcd").write_bytes(ok)
    np.testing.assert_array_equal(load_landmarks(tmp_path / "ok.pcd").points, [[0, 2, 4], [1, 3, 5]])
    cases = {
        "wrong_total": (np.array([len(packed), 99], "<u4").tobytes() + packed, "holds 99 bytes"),
        "past_end": (np.array([len(packed) + 10, len(planes)], "<u4").tobytes() + packed, "truncated PCD"),
        "garbage": (np.array([len(packed), len(planes)], "<u4").tobytes() + b"\xff" * len(packed),
                    "does not decompress"),
        "no_sizes": (b"\x01\x00", "no compressed-size fields"),
        "back_reference_first": (np.array([2, len(planes)], "<u4").tobytes() + b"\x20\x00", "does not decompress"),
    }
    for name, (body, message) in cases.items():
        p = tmp_path / f"{name}.pcd"
        p.write_bytes(_header(data="binary_compressed") + body)
        with pytest.raises(InputError, match=message):
            load_landmarks(p)
    # a claim no LZF stream can meet is refused before any buffer of that size exists
    n = 2 * LZF_MAX_RATIO * 8
    p = tmp_path / "bomb.pcd"
    p.write_bytes(_header(width=str(n), points=str(n), data="binary_compressed")
                  + np.array([8, n * 12], "<u4").tobytes() + b"\x00" * 8)
    with pytest.raises(InputError, match="cannot expand"):
        load_landmarks(p)


def test_pcl_style_trailing_bytes_after_binary_data_are_ignored(tmp_path):
    """PCL's writer stretches the file to a page beyond the data; the bytes after the points are not read."""
    p = tmp_path / "m.pcd"
    p.write_bytes(_header() + BODY + b"\x00" * 4096)
    np.testing.assert_array_equal(load_landmarks(p).points, [[0, 1, 2], [3, 4, 5]])


def test_viewpoint_is_reported_not_applied(tmp_path, caplog):
    write_pcd(tmp_path / "m.pcd", _fields(5), "binary", viewpoint="1 2 3 0.7071 0 0 0.7071")
    cloud = load_landmarks(tmp_path / "m.pcd")
    np.testing.assert_array_equal(cloud.points[:, 0], _fields(5)["x"])
    assert "VIEWPOINT" in caplog.text


def test_compressed_data_without_the_extra_names_it(tmp_path, monkeypatch):
    import sys

    write_pcd(tmp_path / "m.pcd", _fields(10), "binary_compressed")
    monkeypatch.setitem(sys.modules, "lzf", None)  # as if python-neo-lzf were not installed
    with pytest.raises(InputError, match=r"m\.pcd: PCD binary_compressed data needs the 'pcd' extra"):
        load_landmarks(tmp_path / "m.pcd")
    write_pcd(tmp_path / "b.pcd", _fields(10), "binary")
    assert len(load_landmarks(tmp_path / "b.pcd")) == 10  # the other kinds need nothing extra
