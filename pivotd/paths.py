"""Translation path files (DESIGN.md §5): CSV rows ``x,y,z`` or ``timestamp,x,y,z,qw,qx,qy,qz``.

The 8-column form is the FIF trajectory format (quaternion stored w first, timestamp in ns);
in code quaternions are (x, y, z, w).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.maps.formats import read_numeric_text


@dataclass(frozen=True)
class PathData:
    """positions: (N, 3) [m]; quats: (N, 4) body attitude (x, y, z, w) or None; stamps: (N,) [s] or None."""

    positions: np.ndarray
    quats: np.ndarray | None = None
    stamps: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.positions.shape[0])


def load_path(path: str | Path) -> PathData:
    """Read a path CSV; raises :class:`InputError` naming the file and line on bad rows or an empty path."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    arr = read_numeric_text(path, (3, 8), what="path")
    if arr.shape[0] == 0:
        raise InputError(f"{path}: path is empty (no waypoint rows)")
    if arr.shape[1] == 3:
        return PathData(positions=np.ascontiguousarray(arr))
    quats = arr[:, [5, 6, 7, 4]]
    norms = np.linalg.norm(quats, axis=1)
    if np.any(norms < 1e-6):
        raise InputError(f"{path}: row {int(np.argmax(norms < 1e-6)) + 1} has a zero quaternion")
    stamps = arr[:, 0]
    # FIF stamps are integer nanoseconds; plain seconds pass through.
    if np.nanmax(np.abs(stamps)) > 1e12:
        stamps = (stamps - stamps[0]) * 1e-9
    return PathData(
        positions=np.ascontiguousarray(arr[:, 1:4]),
        quats=quats / norms[:, None],
        stamps=stamps,
    )
