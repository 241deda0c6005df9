"""PCD landmark maps (the Point Cloud Library's format, header versions 0.5–0.7).

``DATA ascii``, ``binary`` and ``binary_compressed`` (LZF; needs the ``pcd`` extra, ``python-neo-lzf``).
The cloud's ``x``, ``y``, ``z`` fields are the landmarks; the weight comes from the field named by
``weight_property`` (error when missing) or, by default, from a ``weight`` field when the file has one.
Other fields (``rgb``, ``intensity``, normals, ``_`` padding) are ignored.

Points whose coordinates hold NaN are PCL's invalid points (organized clouds keep them as place holders):
they are dropped and counted in the log. ``VIEWPOINT`` is the acquisition pose, which PCL does not apply to
the points either; the points are read as stored.

Hostile files: the header is read from at most :data:`HEADER_LIMIT` bytes; binary data must hold
``POINTS`` records before any array is made (it is memory-mapped); compressed data must fit the file and
claim no more than LZF can expand (:data:`LZF_MAX_RATIO`). Every problem is one line naming the file and
the header line, point or byte offset.
"""

from __future__ import annotations

import array
import io
import logging
import math
import os
import warnings
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.maps.formats import CappedReader, LandmarkCloud, make_cloud, xyz_columns
from pivotd.progress import Progress

log = logging.getLogger(__name__)

DEFAULT_WEIGHT_FIELD = "weight"
HEADER_LIMIT = 1 << 20  # bytes searched for the DATA line
LZF_MAX_RATIO = 90  # LZF expands at most ~88× (a 3-byte back reference copies ≤ 264 bytes)
_ASCII_BLOCK = 1 << 18  # bytes of ASCII point data parsed at once
_TYPES = {("F", 4): "f4", ("F", 8): "f8", ("I", 1): "i1", ("I", 2): "i2", ("I", 4): "i4", ("I", 8): "i8",
          ("U", 1): "u1", ("U", 2): "u2", ("U", 4): "u4", ("U", 8): "u8"}
_DATA_KINDS = ("ascii", "binary", "binary_compressed")


@dataclass(frozen=True)
class PcdHeader:
    """A parsed PCD header. fields/types/counts per field (types are numpy little-endian codes such as
    ``f4``); points = width × height; data: ascii, binary or binary_compressed; offset: first data byte."""

    fields: tuple[str, ...]
    types: tuple[str, ...]
    counts: tuple[int, ...]
    width: int
    height: int
    points: int
    data: str
    offset: int
    viewpoint: tuple[float, ...]

    @property
    def field_bytes(self) -> list[int]:
        """Bytes of each field in one point record (item size × count)."""
        return [np.dtype(t).itemsize * c for t, c in zip(self.types, self.counts, strict=True)]

    @property
    def point_step(self) -> int:
        """Bytes per point record."""
        return sum(self.field_bytes)


def load_pcd(path: Path, *, weight_property: str | None = None) -> LandmarkCloud:
    """Read x, y, z (and a weight) from a PCD file; errors name the file and the header line or point."""
    size = os.path.getsize(path)
    with CappedReader(path) as fh:
        header = read_header(path, fh.read(min(size, HEADER_LIMIT)))
        wanted = _wanted_fields(path, header, weight_property)
        with Progress(f"reading {path.name}", size, "B") as progress:
            if header.data == "ascii":
                columns = _ascii_columns(path, fh, header, wanted, progress)
            elif header.data == "binary":
                columns = _binary_columns(path, header, wanted, size)
            else:
                columns = _compressed_columns(path, fh, header, wanted, size)
    points = np.stack(columns[:3], axis=1)
    weights = columns[3] if len(columns) > 3 else None
    invalid = np.isnan(points).any(axis=1)
    for name, bad in (("coordinate", np.isinf(points).any(axis=1)),
                      ("weight", None if weights is None else ~np.isfinite(weights) & ~invalid)):
        if bad is not None and bad.any():  # named by the point's index in the file, before the drop below
            raise InputError(f"{path}: point {int(np.argmax(bad))} has a non-finite {name}")
    if invalid.any():
        keep = ~invalid
        log.info("%s: dropped %d invalid (NaN) points of %d", path, int(invalid.sum()), len(points))
        points, weights = points[keep], None if weights is None else weights[keep]
    return make_cloud(path, points, weights, row_name="point")


def read_header(path: Path, head: bytes) -> PcdHeader:
    """Parse the header in ``head`` (the file's first bytes) up to and including its DATA line."""
    values: dict[str, list[str]] = {}
    lines: dict[str, int] = {}  # the line of each key's first occurrence, for error messages
    pos = 0
    lineno = 0
    while True:
        end = head.find(b"\n", pos)
        if end < 0:
            raise InputError(f"{path}: not a PCD file (no DATA line in the first {len(head)} bytes)")
        lineno += 1
        try:
            line = head[pos:end].decode("ascii").strip()
        except UnicodeDecodeError:
            raise InputError(f"{path}:{lineno}: not a PCD header line (binary bytes)") from None
        pos = end + 1
        if not line or line.startswith("#"):
            continue
        key, *rest = line.split()
        key = key.upper()
        if key == "COLUMNS":  # the oldest header versions' name for FIELDS
            key = "FIELDS"
        if key not in ("VERSION", "FIELDS", "SIZE", "TYPE", "COUNT", "WIDTH", "HEIGHT", "VIEWPOINT", "POINTS", "DATA"):
            raise InputError(f"{path}:{lineno}: unknown PCD header key {key[:40]!r}")
        values[key] = rest
        lines.setdefault(key, lineno)
        if key == "DATA":
            break
    return _header(path, values, lines, pos)


def _header(path: Path, values: dict[str, list[str]], lines: dict[str, int], offset: int) -> PcdHeader:
    def where(key: str) -> str:
        return f"{path}:{lines[key]}" if key in lines else str(path)

    def ints(key: str, n: int, default: list[int]) -> list[int]:
        if key not in values:
            return default
        try:
            out = [int(v) for v in values[key]]
        except ValueError:
            got = " ".join(values[key])[:80]
            raise InputError(f"{where(key)}: {key} values must be integers, got {got!r}") from None
        if len(out) != n or any(v < 0 for v in out):
            raise InputError(f"{where(key)}: {key} needs {n} non-negative integer(s), got {len(out)}")
        return out

    fields = values.get("FIELDS")
    if not fields:
        raise InputError(f"{where('FIELDS')}: PCD header has no FIELDS")
    n = len(fields)
    sizes = ints("SIZE", n, [4] * n)
    kinds = values.get("TYPE", ["F"] * n)
    if len(kinds) != n:
        raise InputError(f"{where('TYPE')}: TYPE has {len(kinds)} entries for {n} fields")
    counts = ints("COUNT", n, [1] * n)
    types = []
    for name, kind, size, count in zip(fields, kinds, sizes, counts, strict=True):
        code = _TYPES.get((kind.upper(), size))
        if code is None or count < 1:
            raise InputError(
                f"{where('TYPE')}: field {name!r} has an unsupported type {kind} of size {size} or count {count}"
            )
        types.append(code)
    width = ints("WIDTH", 1, [-1])[0]
    height = ints("HEIGHT", 1, [1])[0]
    points = ints("POINTS", 1, [-1])[0]
    if width < 0 and points < 0:
        raise InputError(f"{path}: PCD header has neither WIDTH nor POINTS")
    if width < 0:
        width, height = points, 1
    if points < 0:
        points = width * height
    if width * height != points:
        raise InputError(f"{where('POINTS')}: POINTS {points} is not WIDTH × HEIGHT = {width} × {height}")
    data = values.get("DATA", [""])
    kind = data[0].lower() if data else ""
    if kind not in _DATA_KINDS:
        raise InputError(f"{where('DATA')}: unknown PCD data kind {kind[:40]!r} (expected {', '.join(_DATA_KINDS)})")
    viewpoint = tuple(_floats(path, where("VIEWPOINT"), values.get("VIEWPOINT", ["0", "0", "0", "1", "0", "0", "0"])))
    if len(viewpoint) != 7:
        raise InputError(f"{where('VIEWPOINT')}: VIEWPOINT needs 7 values (tx ty tz qw qx qy qz), got {len(viewpoint)}")
    if viewpoint != (0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0):
        log.warning("%s: VIEWPOINT %s is ignored: points are read as stored, as PCL does", path, viewpoint)
    return PcdHeader(tuple(fields), tuple(types), tuple(counts), width, height, points, kind, offset, viewpoint)


def _floats(path: Path, where: str, items: list[str]) -> list[float]:
    try:
        out = [float(v) for v in items]
    except ValueError:
        raise InputError(f"{where}: not a number in {' '.join(items)[:80]!r}") from None
    if not all(math.isfinite(v) for v in out):
        raise InputError(f"{where}: value is not finite")
    return out


def _wanted_fields(path: Path, header: PcdHeader, weight_property: str | None) -> list[int]:
    """Field indices of x, y, z and the weight (when there is one)."""
    try:
        index, wanted, shown = xyz_columns(header.fields, "PCD", "field")
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    weight = weight_property if weight_property is not None else DEFAULT_WEIGHT_FIELD
    if weight in index:
        wanted.append(index[weight])
    elif weight_property is not None:
        raise InputError(f"{path}: PCD has no weight field {weight_property!r} (fields: {shown})")
    for k in wanted:
        if header.counts[k] != 1:
            raise InputError(f"{path}: PCD field {header.fields[k]!r} has COUNT {header.counts[k]}, expected 1")
    return wanted


def _binary_columns(path: Path, header: PcdHeader, wanted: list[int], size: int) -> list[np.ndarray]:
    need = header.points * header.point_step
    if header.offset + need > size:
        raise InputError(
            f"{path}: truncated PCD: {header.points} points of {header.point_step} bytes need {need} bytes after "
            f"byte {header.offset}, the file holds {max(0, size - header.offset)}"
        )
    if header.points == 0:
        return [np.zeros(0, np.float32) for _ in wanted]
    offsets = np.cumsum([0, *header.field_bytes])
    dtype = np.dtype({
        "names": [f"f{k}" for k in wanted],
        "formats": ["<" + header.types[k] for k in wanted],
        "offsets": [int(offsets[k]) for k in wanted],
        "itemsize": header.point_step,
    })
    records = np.memmap(path, dtype=dtype, mode="r", offset=header.offset, shape=(header.points,))
    with np.errstate(over="ignore", invalid="ignore"):
        return [np.asarray(records[f"f{k}"], dtype=np.float32) for k in wanted]


def _compressed_columns(
    path: Path, fh: CappedReader, header: PcdHeader, wanted: list[int], size: int
) -> list[np.ndarray]:
    fh.seek(header.offset)
    sizes = fh.read(8)
    if len(sizes) < 8:
        raise InputError(f"{path}: truncated PCD: no compressed-size fields at byte {header.offset}")
    compressed, uncompressed = (int(v) for v in np.frombuffer(sizes, "<u4"))
    need = header.points * header.point_step
    if uncompressed != need:
        raise InputError(
            f"{path}: corrupt PCD: the compressed data holds {uncompressed} bytes, {header.points} points of "
            f"{header.point_step} bytes need {need}"
        )
    if header.offset + 8 + compressed > size:
        raise InputError(
            f"{path}: truncated PCD: {compressed} compressed bytes after byte {header.offset + 8}, the file holds "
            f"{max(0, size - header.offset - 8)}"
        )
    if uncompressed > LZF_MAX_RATIO * compressed + 64:
        raise InputError(f"{path}: corrupt PCD: {compressed} compressed bytes cannot expand to {uncompressed}")
    if header.points == 0:
        return [np.zeros(0, np.float32) for _ in wanted]
    try:
        import lzf
    except ImportError:
        raise InputError(
            f"{path}: PCD binary_compressed data needs the 'pcd' extra (pip install 'pivotd[pcd]'); "
            "or save the cloud with DATA binary"
        ) from None
    try:
        raw = lzf.decompress(fh.read(compressed), uncompressed)
    except ValueError:  # a malformed stream (a back reference before the start)
        raw = None
    if raw is None or len(raw) != uncompressed:
        raise InputError(f"{path}: corrupt PCD: the LZF data at byte {header.offset + 8} does not decompress")
    starts = np.cumsum([0, *header.field_bytes]) * header.points  # fields are stored one after another
    with np.errstate(over="ignore", invalid="ignore"):
        return [
            np.frombuffer(raw, "<" + header.types[k], count=header.points, offset=int(starts[k])).astype(np.float32)
            for k in wanted
        ]


def _ascii_columns(
    path: Path, fh: CappedReader, header: PcdHeader, wanted: list[int], progress: Progress
) -> list[np.ndarray]:
    starts = np.cumsum([0, *header.counts])
    values = int(starts[-1])  # numbers per point
    use = [int(starts[k]) for k in wanted]
    out = array.array("f")  # the wanted values, point after point
    fh.seek(header.offset)
    rows = 0
    tail = b""
    while True:
        chunk = fh.read(_ASCII_BLOCK)
        block = tail + chunk
        if chunk:
            cut = block.rfind(b"\n") + 1
            block, tail = block[:cut], block[cut:]
        elif not block.strip():
            break
        progress.advance(len(chunk))
        parsed = _parse_ascii(path, block, values, rows, header.points)
        rows += parsed.shape[0]
        with np.errstate(over="ignore"):
            out.frombytes(parsed[:, use].astype(np.float32).tobytes())
        if not chunk:
            break
    if rows != header.points:
        raise InputError(f"{path}: PCD header says {header.points} points, the ASCII data holds {rows}")
    table = np.frombuffer(out, dtype=np.float32).reshape(-1, len(use))
    return [table[:, j] for j in range(len(use))]


def _parse_ascii(path: Path, block: bytes, values: int, before: int, limit: int) -> np.ndarray:
    """(rows, values) float64 of one block of ASCII point lines; errors name the point (0-based)."""
    try:
        text = block.decode("ascii")
    except UnicodeDecodeError:
        raise InputError(f"{path}: point {before}+: ASCII PCD data holds binary bytes") from None
    try:  # fast path: numpy's C parser; anything odd is parsed line by line below to name the point
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            fast = np.loadtxt(io.StringIO(text), dtype=np.float64, ndmin=2)
        if fast.shape[0] == 0 or (fast.shape[1] == values and before + fast.shape[0] <= limit):
            return fast.reshape(-1, values)
    except ValueError:
        pass
    rows: list[list[float]] = []
    for line in text.splitlines():
        fields = line.split()
        if not fields:
            continue
        point = before + len(rows)
        if point >= limit:
            raise InputError(f"{path}: PCD header says {limit} points, the ASCII data holds more")
        if len(fields) != values:
            raise InputError(f"{path}: point {point}: expected {values} values, got {len(fields)}")
        try:
            rows.append([float(f) for f in fields])
        except ValueError:
            raise InputError(f"{path}: point {point}: not a number in {line[:80]!r}") from None
    return np.array(rows, dtype=np.float64).reshape(-1, values)
