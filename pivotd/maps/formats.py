"""Landmark map files (docs/FORMATS.md): ``.npy``, text ``x y z [w]``, PLY, PCD and COLMAP models.

:func:`load_landmarks` is the single entry point; it picks the reader by extension (or, for a
directory, by its COLMAP content) and returns a :class:`LandmarkCloud`.

Policy for bad input: every reader raises :class:`~pivotd.errors.InputError` with a one-line
message naming the file and the row, line or byte offset. Rows holding NaN or inf are rejected
(not silently dropped): a map with undefined coordinates is a broken export, and dropping rows
would shift every landmark index the user may refer to. An empty map is an error unless
``allow_empty=True`` (the daemon may start before targets arrive).
"""

from __future__ import annotations

import array
import io
import logging
import os
import re
import warnings
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from pathlib import Path
from tokenize import TokenError

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import MAX_COORDINATE
from pivotd.progress import Progress

log = logging.getLogger(__name__)

TEXT_SUFFIXES = (".txt", ".csv", ".xyz")
POINT_DTYPE = np.float32


@dataclass(frozen=True)
class LandmarkCloud:
    """Landmarks as loaded from a file.

    points: (N, 3) float32 world coordinates [m], C-contiguous; weights: (N,) float32 ≥ 0 (1 when
    the file has none); directions: (N, 3) float32 unit mean observation directions (landmark →
    cameras; all-zero for a landmark without usable observations), or None when unknown.

    float32 halves memory for 10M-landmark maps; its resolution is ≤ 1 mm up to 8 km from the
    origin, far below landmark accuracy. Arithmetic with float64 arrays promotes as usual.
    """

    points: np.ndarray
    weights: np.ndarray
    directions: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @staticmethod
    def empty() -> LandmarkCloud:
        """A cloud with no landmarks."""
        return LandmarkCloud(np.zeros((0, 3), POINT_DTYPE), np.zeros(0, POINT_DTYPE))


def load_landmarks(
    path: str | Path, *, weight_property: str | None = None, allow_empty: bool = False
) -> LandmarkCloud:
    """Load a landmark map from ``path``.

    Formats: ``.npy`` (N,3)/(N,4); ``.txt``/``.csv``/``.xyz`` rows ``x y z [w]``, or any columns under a
    header row naming ``x``, ``y``, ``z`` (and a weight); ``.ply`` (ASCII or binary; ``weight_property``
    names the vertex property holding weights, default ``weight`` when present); ``.pcd`` (PCL, ASCII,
    binary or binary_compressed; fields as PLY properties); COLMAP ``points3D.bin``/``.txt`` or a model
    directory (with ``images.bin|txt`` beside it the cloud carries mean observation directions).
    ``weight_property`` applies to PLY, PCD and text maps with a header row.
    """
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if path.is_dir() or (path.stem == "points3D" and suffix in (".bin", ".txt")):
        from pivotd.maps.colmap import load_colmap

        _no_weight_property(path, weight_property)
        cloud = load_colmap(path)
    elif suffix == ".ply":
        from pivotd.maps.formats_ply import load_ply

        cloud = load_ply(path, weight_property=weight_property)
    elif suffix == ".npy":
        _no_weight_property(path, weight_property)
        cloud = _npy_cloud(path, _read_npy(path))
    elif suffix in TEXT_SUFFIXES:
        columns = TextMapColumns(weight_property)
        arr = read_numeric_text(path, (3, 4), what="landmark", dtype=POINT_DTYPE, select=columns)
        if weight_property is not None and not columns.header:
            raise InputError(f"{path}: {_needs_header(weight_property)}")
        cloud = cloud_from_array(path, arr)
    elif suffix == ".pcd":
        from pivotd.maps.formats_pcd import load_pcd

        cloud = load_pcd(path, weight_property=weight_property)
    else:
        raise InputError(
            f"{path}: unknown map format '{suffix or path.name}' "
            "(expected .npy, .txt, .csv, .xyz, .ply, .pcd, a COLMAP points3D file or model directory)"
        )
    if len(cloud) == 0 and not allow_empty:
        raise InputError(f"{path}: map is empty (no landmarks)")
    log.debug("%s: %d landmarks", path, len(cloud))
    return cloud


WEIGHT_NAMES = ("weight", "w")  # header names taken as the feature weight when no weight property is named


def xyz_columns(names: Sequence[str], where: str, noun: str = "column") -> tuple[dict[str, int], list[int], str]:
    """(index of each name's first occurrence, the indices of x, y, z, the names as error messages list them) of a
    header's or a file's column names; ValueError ``"{where} has no x/… {noun} ({noun}s: …)"`` when x, y or z is
    missing."""
    index: dict[str, int] = {}
    for k, name in enumerate(names):
        index.setdefault(name, k)
    shown = ", ".join(n or "(unnamed)" for n in names[:12]) + (", …" if len(names) > 12 else "")
    missing = [c for c in ("x", "y", "z") if c not in index]
    if missing:
        raise ValueError(f"{where} has no {'/'.join(missing)} {noun} ({noun}s: {shown})")
    return index, [index["x"], index["y"], index["z"]], shown


class TextMapColumns:
    """:data:`HeaderSelect` for text maps: x, y, z and the weight column (``weight_property``, else ``weight``
    or ``w`` when present) of a header row; other columns (colours, intensity, …) are ignored.
    ``header`` tells whether the file had a header row."""

    def __init__(self, weight_property: str | None = None) -> None:
        self.weight_property = weight_property
        self.header = False

    def __call__(self, names: list[str]) -> list[int]:
        self.header = True
        index, keep, shown = xyz_columns(names, "header row")
        if self.weight_property is not None:
            key = self.weight_property.strip().lower()
            if key not in index:
                raise ValueError(f"header row has no weight column '{self.weight_property}' (columns: {shown})")
            keep.append(index[key])
        else:
            keep += [index[n] for n in WEIGHT_NAMES if n in index][:1]
        return keep


def text_map_weight_column(path: Path, weight_property: str | None = None, *,
                           columns: TextMapColumns | None = None) -> bool | None:
    """Whether a text map carries a weight column (a 4th field, or the one its header row or column-naming
    comment names: ``weight_property``, else ``weight`` or ``w``), as :func:`load_landmarks` reads it; None when
    the file has no data line, cannot be read, or has a header row the loader refuses. ``columns`` (made from
    ``weight_property`` when not given) is left telling whether the file has a header row."""
    try:
        with open(path, encoding="utf-8-sig") as fh:
            found = _first_data_line(fh.read(_TEXT_BLOCK))
    except (OSError, UnicodeDecodeError):
        return None
    if found is None:
        return None
    columns = columns if columns is not None else TextMapColumns(weight_property)
    names = header_names(found[1])
    if names is not None:
        try:
            return len(columns(names)) == 4
        except ValueError:  # the loader reports the header's problem
            return None
    keep, _ = _comment_header(found[2], found[1], columns)
    return len(keep) == 4 if keep is not None else _field_count(found[1]) >= 4


def weight_property_problem(path: Path, weight_property: str) -> str | None:
    """Why ``weight_property`` cannot name the weights of the map at ``path``, as :func:`load_landmarks` refuses
    it: a COLMAP model, a .npy array, a text map whose first data line is no header row; None otherwise (also
    when the file cannot tell: the loader reports that). Reads at most the first block of a text map."""
    suffix = path.suffix.lower()
    if path.is_dir() or (path.stem == "points3D" and suffix in (".bin", ".txt")):
        return _not_named(weight_property, "COLMAP models")
    if suffix == ".npy":
        return _not_named(weight_property, ".npy arrays")
    if suffix in TEXT_SUFFIXES:
        columns = TextMapColumns(weight_property)
        if text_map_weight_column(path, weight_property, columns=columns) is not None and not columns.header:
            return _needs_header(weight_property)
    return None


def _no_weight_property(path: Path, weight_property: str | None) -> None:
    problem = weight_property_problem(path, weight_property) if weight_property is not None else None
    if problem is not None:
        raise InputError(f"{path}: {problem}")


def _not_named(weight_property: str, what: str) -> str:
    return (f"weight property '{weight_property}' applies to PLY and PCD maps and text maps with a header row; "
            f"{what} carry weights in their 4th column (or none)")


def _needs_header(weight_property: str) -> str:
    return (f"weight property '{weight_property}' needs a header row naming the columns; text maps without one "
            "carry weights in their 4th column (or none)")


class CappedReader(io.BufferedReader):
    """A binary file whose ``read(n)`` never asks for more than the bytes left: a length field read from a
    corrupt file cannot make a reader allocate more than the file holds (``BufferedReader.read(n)``
    allocates n bytes before reading)."""

    def __init__(self, path: Path) -> None:
        super().__init__(io.FileIO(path, "r"))
        self._size = os.fstat(self.fileno()).st_size

    def read(self, size: int | None = -1) -> bytes:
        if size is not None and size > 0:
            size = min(size, max(0, self._size - self.tell()))
            if size == 0:
                return b""
        return super().read(size)


def _read_npy(path: Path) -> np.ndarray:
    """The array of a ``.npy`` file, memory-mapped; its header is checked against the file size first."""
    shape, dtype, offset = _npy_header(path)
    if len(shape) != 2 or shape[1] not in (3, 4) or not (
        np.issubdtype(dtype, np.integer) or np.issubdtype(dtype, np.floating)
    ):
        raise InputError(f"{path}: expected a numeric (N,3) or (N,4) array, got {dtype} {shape}")
    need = shape[0] * shape[1] * dtype.itemsize  # Python ints: no overflow
    have = path.stat().st_size - offset
    if need > have:
        raise InputError(f"{path}: header claims a {dtype} {shape} array of {need} bytes, the file holds {have}")
    if shape[0] == 0:
        return np.zeros((0, shape[1]), dtype)
    try:
        return np.load(path, allow_pickle=False, mmap_mode="r")
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({' '.join(str(exc).split())})") from None


_NPY_BLOCK = 1 << 18  # rows converted per block (progress granularity; temporaries stay small)


def _npy_cloud(path: Path, arr: np.ndarray) -> LandmarkCloud:
    """Cloud of a memory-mapped (N, 3|4) array, converted to float32 in blocks of rows (the file is read
    here, with a progress line over its bytes); values and errors as :func:`cloud_from_array`."""
    n, cols = arr.shape
    points = np.empty((n, 3), POINT_DTYPE)
    weights = np.empty(n, POINT_DTYPE) if cols == 4 else None
    row_bytes = cols * arr.dtype.itemsize
    with Progress(f"reading {path.name}", n * row_bytes, "B") as progress, \
            np.errstate(over="ignore", invalid="ignore"):  # beyond float32 becomes inf: make_cloud reports it
        for a in range(0, n, _NPY_BLOCK):
            b = min(n, a + _NPY_BLOCK)
            points[a:b] = arr[a:b, :3]
            if weights is not None:
                weights[a:b] = arr[a:b, 3]
            progress.update(b * row_bytes)
    return make_cloud(path, points, weights)


def _npy_header(path: Path) -> tuple[tuple[int, ...], np.dtype, int]:
    """(shape, dtype, data offset) from a ``.npy`` header; any malformed header is an InputError."""
    try:
        with CappedReader(path) as fh:
            version = np.lib.format.read_magic(fh)
            if version == (1, 0):
                shape, _, dtype = np.lib.format.read_array_header_1_0(fh)
            elif version in ((2, 0), (3, 0)):
                shape, _, dtype = np.lib.format.read_array_header_2_0(fh)
            else:
                raise ValueError(f"unsupported .npy version {version}")
            offset = fh.tell()
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    # A corrupt header is Python literal syntax parsed by numpy: it surfaces as any of these.
    except (ValueError, SyntaxError, TokenError, OverflowError, TypeError, KeyError, EOFError,
            UnicodeDecodeError, RecursionError, MemoryError) as exc:
        detail = " ".join(str(exc).split())[:120]
        raise InputError(f"{path}: not a readable .npy array (bad header: {type(exc).__name__}: {detail})") from None
    if not all(isinstance(d, int) and d >= 0 for d in shape):
        raise InputError(f"{path}: not a readable .npy array (bad shape {shape})")
    return tuple(shape), np.dtype(dtype), offset


def first_nonfinite_row(arr: np.ndarray) -> int | None:
    """Index of the first row of ``arr`` (N, C) holding NaN or inf, or None (one fast pass when clean)."""
    if arr.shape[0] == 0:
        return None
    # Column sums in float64 propagate NaN/inf and cannot overflow for float32 data: one fast pass.
    with np.errstate(over="ignore", invalid="ignore"):
        clean = all(np.isfinite(arr[:, k].sum(dtype=np.float64)) for k in range(arr.shape[1]))
    if clean:
        return None
    bad = ~np.isfinite(arr).all(axis=1)
    return int(np.argmax(bad)) if bad.any() else None


def first_far_row(points: np.ndarray) -> int | None:
    """Index of the first row of finite ``points`` (N, 3) with a coordinate beyond ±MAX_COORDINATE, or None."""
    if points.shape[0] == 0 or all(np.abs(points[:, k]).max() <= MAX_COORDINATE for k in range(3)):
        return None
    return int(np.argmax((np.abs(points) > MAX_COORDINATE).any(axis=1)))


def make_cloud(
    path: str | Path,
    points: np.ndarray,
    weights: np.ndarray | None = None,
    directions: np.ndarray | None = None,
    row_name: str = "row",
    row_base: int = 0,
) -> LandmarkCloud:
    """Validate and convert arrays to a float32 :class:`LandmarkCloud`.

    points: (N, 3); weights: (N,) or None (ones); directions: (N, 3) or None. ``path`` names the source
    in errors (a file, or e.g. a topic for clouds received over the bus). Raises InputError naming it
    and the first bad ``row_name`` (index + ``row_base``) for a wrong shape, non-finite coordinates or
    weights, or negative weights.
    """
    points = np.asarray(points)
    if points.ndim != 2 or points.shape[1] != 3:
        raise InputError(f"{path}: expected landmark points of shape (N, 3), got {points.shape}")
    n = points.shape[0]
    for name, arr, shape in (("weights", weights, (n,)), ("directions", directions, (n, 3))):
        if arr is not None and np.shape(arr) != shape:
            raise InputError(f"{path}: expected {name} of shape {shape}, got {np.shape(arr)}")
    with np.errstate(over="ignore", invalid="ignore"):  # values beyond float32 become inf: reported below
        points = np.ascontiguousarray(points, dtype=POINT_DTYPE)
    bad = first_nonfinite_row(points)
    if bad is not None:
        raise InputError(f"{path}: {row_name} {bad + row_base} is not finite (NaN, inf or beyond ±3.4e38)")
    far = first_far_row(points)
    if far is not None:
        raise InputError(f"{path}: {row_name} {far + row_base} lies beyond ±{MAX_COORDINATE:g} m")
    if weights is None:
        weights = np.ones(points.shape[0], POINT_DTYPE)
    else:
        with np.errstate(over="ignore", invalid="ignore"):
            weights = np.ascontiguousarray(weights, dtype=POINT_DTYPE)
        bad = first_nonfinite_row(weights[:, None])
        if bad is not None:
            raise InputError(f"{path}: {row_name} {bad + row_base} has a non-finite weight")
        neg = weights < 0
        if neg.any():
            raise InputError(f"{path}: {row_name} {int(np.argmax(neg)) + row_base} has a negative weight")
    if directions is not None:
        directions = np.ascontiguousarray(directions, dtype=POINT_DTYPE)
    return LandmarkCloud(points=points, weights=weights, directions=directions)


def cloud_from_array(path: Path, arr: np.ndarray) -> LandmarkCloud:
    """Cloud from an (N, 3) or (N, 4) array whose 4th column is a weight; rows are 0-based in errors."""
    weights = arr[:, 3] if arr.shape[1] == 4 else None
    return make_cloud(path, arr[:, :3], weights)


_SPLIT = re.compile(r"[,\s]+")
_NAME = re.compile(r"[\"']?[/#%]*[A-Za-z_]")  # a header field starts like a name (never like a number)
_ALIASES = {"tx": "x", "ty": "y", "tz": "z"}  # TUM trajectories: "# timestamp tx ty tz qx qy qz qw"
_TEXT_BLOCK = 1 << 17  # characters per block: numpy 2.5 parses one in ~13x its size, 1.7 MB (numpy 2.4: ~9x)


HeaderSelect = Callable[[list[str]], list[int]]
"""Maps a header row's normalised column names to the indices of the columns to keep, in order; raises
ValueError with a message for a header it cannot use."""


def header_names(line: str) -> list[str] | None:
    """Column names of a header row, or None for a data row. A header row is a line none of whose fields is a
    number (``x,y,z``, ``X Y Z intensity``, CloudCompare's ``//X,Y,Z``, pandas' ``,x,y,z`` with an unnamed
    index column). Names are lower-cased without quotes and leading ``/``, ``#`` or ``%``; ``tx``/``ty``/``tz``
    become x/y/z, and ROS field paths (dotted or with slashes) keep their last part
    (``field.pose.position.x`` → ``x``, ``…/orientation/w`` → ``qw``, ``field.header.stamp`` → ``stamp``)."""
    text = line.strip().lstrip("\ufeff")
    fields = [f.strip() for f in text.split(",")] if "," in text else text.split()
    if not any(fields) or not all(_NAME.match(f) for f in fields if f):
        return None
    return [_canonical(f.strip("\"'").lstrip("/#%").strip().lower()) for f in fields]


def _canonical(name: str) -> str:
    parts = re.split(r"[./]", name)
    if len(parts) > 1:
        name = ("q" if parts[-2] == "orientation" else "") + parts[-1]
    return _ALIASES.get(name, name)


def read_numeric_text(
    path: Path, columns: tuple[int, ...], what: str, dtype: type = np.float64, select: HeaderSelect | None = None
) -> np.ndarray:
    """Parse rows of numbers separated by spaces, tabs or commas; ``#`` starts a comment line.

    Every row must have one of ``columns`` fields (the first data row fixes the count) and be
    finite. With ``select``, the first data line may instead be a header row (:func:`header_names`): then
    every row has the header's number of fields and the columns ``select`` picks are returned. Returns an
    (N, C) array of ``dtype`` (float64 or float32; values beyond float32 become inf); errors name the file
    and 1-based line number. The file is read in blocks of about _TEXT_BLOCK characters, so memory is the
    parsed numbers plus one block.
    """
    values = array.array("d" if np.dtype(dtype) == np.float64 else "f")
    ncols: int | None = None
    delimiter: str | None = None
    keep: list[int] | None = None
    for lineno, block in text_blocks(path):
        if ncols is None:
            found = _first_data_line(block)
            names = header_names(found[1]) if found is not None and select is not None else None
            if names is not None:
                try:
                    keep = select(names)
                except ValueError as exc:
                    raise InputError(f"{path}:{lineno + found[0]}: {exc}") from None
                delimiter = "," if "," in found[1] else None
                ncols = len(names)
                rest = block.split("\n", found[0])  # drop the lines up to and including the header
                block = rest[-1] if len(rest) > found[0] else ""
                lineno += found[0]
            elif found is not None:
                delimiter = "," if "," in found[1] else None
                keep, named = _comment_header(found[2], found[1], select)
                ncols = named or _column_count(path, lineno + found[0], found[1], columns, what)
        if ncols is not None:
            parsed = parse_clean_block(block, ncols, delimiter)
            if parsed is None:
                parsed = _parse_lines(path, block, lineno, ncols)
            if keep is not None:  # only the selected columns are kept, block by block
                parsed = parsed.reshape(-1, ncols)[:, keep]
            with np.errstate(over="ignore"):
                values.frombytes(parsed.astype(dtype, copy=False).tobytes())
    if ncols is None:
        return np.zeros((0, columns[0]), dtype)
    return np.frombuffer(values, dtype=dtype).reshape(-1, ncols if keep is None else len(keep))


def text_blocks(path: Path, size: int = _TEXT_BLOCK) -> Iterator[tuple[int, str]]:
    """(lines before the block, block) of a text file read in blocks of about ``size`` characters, each ending
    at a line end (the last one may not); errors name the file."""
    lineno = 0
    try:
        with (
            open(path, encoding="utf-8-sig") as fh,
            Progress(f"reading {path.name}", os.fstat(fh.fileno()).st_size, "B") as progress,
        ):
            while True:
                block = fh.read(size)
                if not block:
                    return
                if not block.endswith("\n"):
                    block += fh.readline()  # complete the last line
                progress.advance(len(block))  # characters: bytes for the ASCII of numeric text
                yield lineno, block
                lineno += block.count("\n")
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None


def _first_data_line(block: str) -> tuple[int, str, str | None] | None:
    """(1-based line number within ``block``, line, the comment line right before it or None) of the block's
    first non-blank, non-comment line."""
    comment = None
    for k, line in enumerate(io.StringIO(block), start=1):
        stripped = line.strip()
        if stripped.startswith("#"):
            comment = stripped
        elif stripped:
            return k, line, comment
    return None


def _comment_header(comment: str | None, line: str, select: HeaderSelect | None) -> tuple[list[int] | None, int]:
    """(columns to keep, their count in a row) when the comment line right before the first data row names as
    many columns as that row holds and ``select`` can use them (``# timestamp tx ty tz qx qy qz qw``); else
    (None, 0): the columns are taken by position."""
    if comment is None or select is None:
        return None, 0
    names = header_names(comment.lstrip("#"))
    if names is None or len(names) != _field_count(line):
        return None, 0
    try:
        return select(names), len(names)
    except ValueError:  # free text that happens to hold words: positions as usual
        return None, 0


def _field_count(line: str) -> int:
    """Fields of a data line (separated by spaces, tabs or commas)."""
    return len([f for f in _SPLIT.split(line.strip()) if f])


def _column_count(path: Path, lineno: int, line: str, columns: tuple[int, ...], what: str) -> int:
    n = _field_count(line)
    if n not in columns:
        raise InputError(
            f"{path}:{lineno}: expected {' or '.join(map(str, columns))} columns in a {what} row, got {n}"
        )
    return n


def _parse_lines(path: Path, block: str, lineno: int, ncols: int) -> np.ndarray:
    """Line-by-line parse of one block of text (lines after ``lineno``); errors name the offending line."""
    out = array.array("d")
    for k, raw in enumerate(io.StringIO(block), start=lineno + 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(line) if f]
        if len(fields) != ncols:
            raise InputError(f"{path}:{k}: expected {ncols} columns, got {len(fields)}")
        try:
            row = [float(f) for f in fields]
        except ValueError:
            raise InputError(f"{path}:{k}: not a number in {line[:80]!r}") from None
        if not all(np.isfinite(row)):
            raise InputError(f"{path}:{k}: value is not finite (NaN or inf)")
        out.extend(row)
    return np.frombuffer(out, dtype=np.float64)


def parse_clean_block(block: str, ncols: int, delimiter: str | None) -> np.ndarray | None:
    """Fast path for a well-formed block (numpy's C parser); None when anything is off, so that the
    line-by-line parser can name the offending line."""
    try:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            arr = np.loadtxt(io.StringIO(block), dtype=np.float64, comments="#", delimiter=delimiter, ndmin=2)
    except ValueError:
        return None
    if arr.size == 0:
        return arr.reshape(0)
    if arr.shape[1] != ncols or first_nonfinite_row(arr) is not None:
        return None
    return arr
