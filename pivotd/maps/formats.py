"""Landmark map file readers (DESIGN.md §5): ``.npy`` and text (``x y z [w]``).

Every reader returns a :class:`LandmarkCloud`. Bad files raise
:class:`~pivotd.errors.InputError` with a one-line message naming the file and the line/offset.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import InputError

TEXT_SUFFIXES = (".txt", ".csv", ".xyz")


@dataclass(frozen=True)
class LandmarkCloud:
    """Landmarks as loaded from a file.

    points: (N, 3) float64 world coordinates [m]; weights: (N,) float64 ≥ 0 (1 when absent);
    directions: (N, 3) float64 unit mean observation directions (landmark → cameras), or None.
    """

    points: np.ndarray
    weights: np.ndarray
    directions: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.points.shape[0])


def load_landmarks(path: str | Path) -> LandmarkCloud:
    """Load a landmark map, choosing the reader by extension (``.npy``, ``.txt``/``.csv``/``.xyz``)."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    suffix = path.suffix.lower()
    if suffix == ".npy":
        return _from_array(path, _read_npy(path))
    if suffix in TEXT_SUFFIXES:
        return _from_array(path, read_numeric_text(path, (3, 4), what="landmark"))
    raise InputError(f"{path}: unknown map format '{suffix or path.name}' (expected .npy, .txt, .csv, .xyz)")


def _read_npy(path: Path) -> np.ndarray:
    try:
        arr = np.load(path, allow_pickle=False)
    except (ValueError, OSError, EOFError) as exc:
        raise InputError(f"{path}: not a readable .npy array ({exc})") from None
    if arr.ndim != 2 or arr.shape[1] not in (3, 4) or not np.issubdtype(arr.dtype, np.number):
        raise InputError(f"{path}: expected a numeric (N,3) or (N,4) array, got {arr.dtype} {arr.shape}")
    arr = arr.astype(np.float64, copy=False)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        raise InputError(f"{path}: row {int(np.argmax(bad))} is not finite (NaN or inf)")
    return arr


_SPLIT = re.compile(r"[,\s]+")


def read_numeric_text(path: Path, columns: tuple[int, ...], what: str) -> np.ndarray:
    """Parse rows of numbers separated by spaces, tabs or commas; ``#`` starts a comment line.

    Every row must have one of ``columns`` fields (the first data row fixes the count) and be
    finite. Returns an (N, C) float64 array; errors name the file and 1-based line number.
    """
    rows: list[list[float]] = []
    ncols = None
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"{path}: cannot read ({exc})") from None
    for lineno, raw in enumerate(text.splitlines(), start=1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        fields = [f for f in _SPLIT.split(line) if f]
        if ncols is None:
            if len(fields) not in columns:
                raise InputError(
                    f"{path}:{lineno}: expected {' or '.join(map(str, columns))} columns in a {what} row, "
                    f"got {len(fields)}"
                )
            ncols = len(fields)
        elif len(fields) != ncols:
            raise InputError(f"{path}:{lineno}: expected {ncols} columns, got {len(fields)}")
        try:
            values = [float(f) for f in fields]
        except ValueError:
            raise InputError(f"{path}:{lineno}: not a number in {line!r}") from None
        if not all(np.isfinite(values)):
            raise InputError(f"{path}:{lineno}: value is not finite (NaN or inf)")
        rows.append(values)
    if ncols is None:
        return np.zeros((0, columns[0]))
    return np.asarray(rows, dtype=np.float64)


def _from_array(path: Path, arr: np.ndarray) -> LandmarkCloud:
    if arr.shape[0] == 0:
        raise InputError(f"{path}: map is empty (no landmark rows)")
    points = np.ascontiguousarray(arr[:, :3])
    if arr.shape[1] == 4:
        weights = np.ascontiguousarray(arr[:, 3])
        if (weights < 0).any():
            raise InputError(f"{path}: row {int(np.argmax(weights < 0))} has a negative weight")
    else:
        weights = np.ones(arr.shape[0])
    return LandmarkCloud(points=points, weights=weights)
