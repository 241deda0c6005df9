"""PLY landmark maps (ASCII, binary little- and big-endian) read with ``plyfile``.

The ``vertex`` element must carry ``x``, ``y``, ``z``; other properties (normals, colours, …) are
ignored. Weights come from ``weight_property`` (error when missing) or, by default, from a
``weight`` property when the file has one.

ASCII files whose first element is a vertex of scalar properties are parsed in blocks by numpy's C parser
(plyfile parses ASCII one token at a time in Python: ~20× slower). Anything that block parser does not
accept (a wrong column count, a non-number, a non-finite value, too few rows) falls back to plyfile, so
that hostile files get the same one-line errors naming the element row.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np
import plyfile

from pivotd.errors import InputError
from pivotd.maps.formats import CappedReader, LandmarkCloud, make_cloud, parse_clean_block
from pivotd.progress import Progress

DEFAULT_WEIGHT_PROPERTY = "weight"
_ASCII_BLOCK = 1 << 18  # bytes of ASCII vertex data parsed at once


def load_ply(path: Path, *, weight_property: str | None = None) -> LandmarkCloud:
    """Read vertex x, y, z (and a weight) from a PLY file; errors name the file and the vertex row."""
    with Progress(f"reading {path.name}", None, "B") as progress:
        return _load_ply(path, weight_property, progress)


class _ReportingReader(CappedReader):
    """A :class:`CappedReader` that reports the bytes read through it to ``progress`` (memory-mapped element
    data is not read through it: :func:`_copy_columns` reports that)."""

    def __init__(self, path: Path, progress: Progress) -> None:
        super().__init__(path)
        self.progress = progress

    def read(self, size: int | None = -1) -> bytes:
        data = super().read(size)
        self.progress.advance(len(data))
        return data

    def read1(self, size: int = -1) -> bytes:  # what the text wrapper of ASCII PLY reads through
        data = super().read1(size)
        self.progress.advance(len(data))
        return data


def _load_ply(path: Path, weight_property: str | None, progress: Progress) -> LandmarkCloud:
    try:
        with _ReportingReader(path, progress) as fh:  # list lengths read from the file cannot over-allocate
            progress.total = os.fstat(fh.fileno()).st_size or None
            header = _check_counts(path, fh)
            fast = _ascii_vertices(fh, header, weight_property) if header.text else None
            if fast is not None:
                points, weights = fast
                return make_cloud(path, points, weights, row_name="vertex")
        progress.update(0.0)  # plyfile reads the file again from its start
        # out-of-range values become inf / wrap; make_cloud rejects them
        with _ReportingReader(path, progress) as fh, np.errstate(all="ignore"):
            ply = plyfile.PlyData.read(fh, mmap="c")  # binary scalar elements: one vectorised copy
    except plyfile.PlyElementParseError as exc:
        where = f"{exc.element.name} {exc.row}" if exc.row is not None else "data"
        raise InputError(f"{path}: corrupt or truncated PLY at {where} ({exc.message})") from None
    except plyfile.PlyHeaderParseError as exc:
        raise InputError(f"{path}: bad PLY header ({exc})") from None
    except (ValueError, OSError, EOFError, UnicodeDecodeError, IndexError, TypeError, OverflowError) as exc:
        raise InputError(f"{path}: not a readable PLY file ({' '.join(str(exc).split())[:120]})") from None
    try:
        vertex = ply["vertex"]
    except KeyError:
        names = ", ".join(e.name for e in ply.elements) or "none"
        raise InputError(f"{path}: PLY has no 'vertex' element (elements: {names})") from None
    props = [p.name for p in vertex.properties]
    missing = [c for c in ("x", "y", "z") if c not in props]
    if missing:
        raise InputError(f"{path}: PLY vertex lacks {', '.join(missing)} (properties: {', '.join(props)})")
    data = vertex.data
    for c in "xyz":
        _check_scalar(path, vertex, c)
    points = _copy_columns(data, progress)
    weights = None
    name = _weight_name(props, weight_property)
    if name is not None:
        if name not in props:
            raise InputError(
                f"{path}: PLY vertex has no weight property '{name}' (properties: {', '.join(props)})"
            )
        _check_scalar(path, vertex, name)
        weights = np.asarray(data[name], dtype=np.float32)
    return make_cloud(path, points, weights, row_name="vertex")


_COPY_BLOCK = 1 << 18  # vertices copied per block (memory-mapped data is read here)


def _copy_columns(data: np.ndarray, progress: Progress) -> np.ndarray:
    """x, y, z of the vertex records ``data`` (N,) as (N, 3) float32, in blocks; the progress line moves
    from where parsing left it to the file's size."""
    n = len(data)
    points = np.empty((n, 3), dtype=np.float32)
    start, total = progress.done, progress.total or 0.0
    for a in range(0, n, _COPY_BLOCK):
        b = min(n, a + _COPY_BLOCK)
        for k, c in enumerate("xyz"):
            points[a:b, k] = data[c][a:b]
        progress.update(max(progress.done, start + (total - start) * b / n))
    return points


def _weight_name(props: list[str], weight_property: str | None) -> str | None:
    if weight_property is None and DEFAULT_WEIGHT_PROPERTY in props:
        return DEFAULT_WEIGHT_PROPERTY
    return weight_property


def _ascii_vertices(fh, header: plyfile.PlyData, weight_property: str | None
                    ) -> tuple[np.ndarray, np.ndarray | None] | None:
    """Points (N, 3) and weights (N,) or None of an ASCII PLY whose first element is the vertex element of scalar
    properties, parsed block by block from ``fh`` (at the start of the data); None when the file does not
    qualify or any block is not clean (the caller then reads it with plyfile). Memory: the outputs (16 bytes
    per vertex; the count was checked against the file size) plus one block."""
    if not header.elements or header.elements[0].name != "vertex":
        return None
    vertex = header.elements[0]
    if any(isinstance(p, plyfile.PlyListProperty) for p in vertex.properties):
        return None
    props = [p.name for p in vertex.properties]
    name = _weight_name(props, weight_property)
    if any(c not in props for c in "xyz") or (name is not None and name not in props):
        return None
    cols = [props.index(c) for c in "xyz"]
    count, ncols = int(vertex.count), len(props)
    points = np.empty((count, 3), dtype=np.float32)
    weights = None if name is None else np.empty(count, dtype=np.float32)
    done = 0
    rest = b""
    while done < count:
        chunk = fh.read(_ASCII_BLOCK)
        data = rest + chunk
        if not chunk:
            if not data.strip():
                return None  # too few rows: plyfile names the row where the data ends
            data += b"\n"
        cut = data.rfind(b"\n") + 1
        if cut == 0:
            rest = data
            continue
        block, rest = data[:cut], data[cut:]
        lines = block.split(b"\n", count - done)
        if len(lines) > count - done:  # the vertex rows end inside this block
            block = b"\n".join(lines[: count - done]) + b"\n"
        try:
            text = block.decode("ascii")
        except UnicodeDecodeError:
            return None
        arr = parse_clean_block(text, ncols, None)
        if arr is None or arr.shape[0] != text.count("\n") or done + arr.shape[0] > count:
            return None  # blank lines, a short or long row, a non-number, a non-finite value
        with np.errstate(over="ignore"):  # beyond float32: inf, rejected by make_cloud with its row
            points[done:done + arr.shape[0]] = arr[:, cols]
            if weights is not None:
                weights[done:done + arr.shape[0]] = arr[:, props.index(name)]
        done += arr.shape[0]
    return points, weights


def _check_counts(path: Path, fh) -> plyfile.PlyData:
    """Reject element counts the file cannot hold, before plyfile allocates arrays for them.

    Each element needs at least its scalar properties and list lengths in binary, or one character and a
    separator per property in ASCII (an element without properties counts one byte: plyfile would loop
    over its count).
    """
    header = plyfile.PlyData._parse_header(fh)  # plyfile's own parser (what PlyData.read calls)
    body = os.fstat(fh.fileno()).st_size - fh.tell()
    need = 0
    for element in header.elements:
        if header.text:
            per = 2 * len(element.properties)
        else:
            per = sum(np.dtype(p.list_dtype()[0] if isinstance(p, plyfile.PlyListProperty) else p.val_dtype).itemsize
                      for p in element.properties)
        per = max(per, 1)
        if need + int(element.count) * per > body + 1:  # + 1: an ASCII file may end without a newline
            fit = max(0, body + 1 - need) // per
            raise InputError(
                f"{path}: corrupt or truncated PLY at {element.name} {fit}: the header claims {element.count} "
                f"'{element.name}' elements, the {body} data bytes hold at most {fit}"
            )
        need += int(element.count) * per
    return header


def _check_scalar(path: Path, vertex: plyfile.PlyElement, name: str) -> None:
    prop = vertex.ply_property(name)
    if isinstance(prop, plyfile.PlyListProperty):
        raise InputError(f"{path}: PLY vertex property '{name}' is a list, expected a scalar")
