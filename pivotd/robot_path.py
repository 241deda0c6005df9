"""The robot's translation path: path files (docs/FORMATS.md) and :class:`Polyline` (arc length, projection).

Files are CSV rows ``x,y,z`` or ``timestamp,x,y,z,qw,qx,qy,qz``.

The 8-column form is the FIF trajectory format (quaternion stored w first, timestamp in ns);
in code quaternions are (x, y, z, w).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.geometry import MAX_COORDINATE, matrix_to_quat, normalize, safe_unit_quats, yaw_to_matrix
from pivotd.maps.formats import read_numeric_text, xyz_columns


@dataclass(frozen=True)
class PathData:
    """positions: (N, 3) [m]; quats: (N, 4) body attitude (x, y, z, w) or None; stamps: (N,) [s] or None."""

    positions: np.ndarray
    quats: np.ndarray | None = None
    stamps: np.ndarray | None = None

    def __len__(self) -> int:
        return int(self.positions.shape[0])


_STAMP_NAMES = ("timestamp", "time", "t", "stamp", "time_s", "t_s", "__time")


def path_columns(names: list[str]) -> list[int]:
    """Columns of a path CSV with a header row: timestamp, x, y, z, qw, qx, qy, qz when it names a timestamp
    and the four quaternion components, else x, y, z (other columns are ignored)."""
    index, xyz, _ = xyz_columns(names, "header row")
    stamp = next((index[n] for n in _STAMP_NAMES if n in index), None)
    quat = [index.get(n) for n in ("qw", "qx", "qy", "qz")]
    if stamp is not None and None not in quat:
        return [stamp, *xyz, *quat]
    return xyz


def load_path(path: str | Path) -> PathData:
    """Read a path CSV; raises :class:`InputError` naming the file and line on bad rows or an empty path."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file")
    arr = read_numeric_text(path, (3, 8), what="path", select=path_columns)
    if arr.shape[0] == 0:
        raise InputError(f"{path}: path is empty (no waypoint rows)")
    xyz = arr[:, :3] if arr.shape[1] == 3 else arr[:, 1:4]
    far = np.max(np.abs(xyz), axis=1) > MAX_COORDINATE
    if far.any():
        raise InputError(f"{path}: row {int(np.argmax(far)) + 1} has a position beyond ±{MAX_COORDINATE:g} m")
    if arr.shape[1] == 3:
        return PathData(positions=np.ascontiguousarray(arr))
    quats, usable = safe_unit_quats(arr[:, [5, 6, 7, 4]])
    if not usable.all():
        raise InputError(f"{path}: row {int(np.argmax(~usable)) + 1} has a zero quaternion")
    stamps = arr[:, 0]
    # FIF stamps are integer nanoseconds; plain seconds pass through.
    if np.nanmax(np.abs(stamps)) > 1e12:
        with np.errstate(over="ignore"):
            stamps = (stamps - stamps[0]) * 1e-9
        if not np.isfinite(stamps).all():
            raise InputError(f"{path}: row {int(np.argmax(~np.isfinite(stamps))) + 1} has a timestamp out of range")
    return PathData(positions=np.ascontiguousarray(arr[:, 1:4]), quats=quats, stamps=stamps)


def project_onto_polyline(positions: np.ndarray, arc: np.ndarray, point: np.ndarray,
                          window: tuple[float, float] | None = None) -> tuple[float, float]:
    """Nearest point to ``point`` (3,) [m] on the polyline through ``positions`` (P, 3) [m], P ≥ 1.

    ``arc`` (P,) is a non-decreasing coordinate of the vertices (arc length [m], or any progress measure);
    returns that coordinate interpolated linearly at the foot point, and the distance [m]. Repeated
    vertices (zero-length segments) are fine. With ``window`` = (lo, hi) only segments whose coordinate
    range overlaps [lo, hi] are searched (all of them when none does).
    """
    p = np.asarray(point, float)
    if positions.shape[0] == 1:
        return float(arc[0]), float(np.linalg.norm(p - positions[0]))
    a = positions[:-1]
    seg = np.diff(positions, axis=0)
    len2 = np.maximum(np.sum(seg * seg, axis=1), 1e-18)
    t = np.clip(np.einsum("ij,ij->i", p - a, seg) / len2, 0.0, 1.0)
    d = np.linalg.norm(a + t[:, None] * seg - p, axis=1)
    if window is not None:
        inside = (arc[1:] >= window[0]) & (arc[:-1] <= window[1])
        if inside.any():
            d = np.where(inside, d, np.inf)
    i = int(np.argmin(d))
    return float(arc[i] + t[i] * (arc[i + 1] - arc[i])), float(d[i])


class Polyline:
    """A translation path (P, 3) [m] with arc length, monotone progress and resampling.

    ``quats`` (P, 4) (x, y, z, w) give the body attitude along the path (interpolated linearly and
    renormalised, consecutive ones kept in the same hemisphere). Without them the attitude follows the
    path heading with zero roll and pitch; the heading at each vertex is that of its neighbours' chord,
    interpolated along the arc, so it turns smoothly. ``ignore_constant_quats`` treats quaternions that
    are all equal as absent (path planners that leave orientations unset). Repeated points are dropped.
    """

    def __init__(self, positions: np.ndarray, quats: np.ndarray | None = None,
                 ignore_constant_quats: bool = False) -> None:
        positions = np.asarray(positions, dtype=float).reshape(-1, 3)
        if positions.shape[0] == 0:
            raise InputError("path has no waypoints")
        keep = np.ones(positions.shape[0], dtype=bool)
        keep[1:] = np.linalg.norm(np.diff(positions, axis=0), axis=1) > 1e-9
        self.positions = positions[keep]
        self.quats = None
        if quats is not None:
            q = np.asarray(quats, dtype=float).reshape(-1, 4)[keep].copy()
            q /= np.linalg.norm(q, axis=1, keepdims=True)
            if not (ignore_constant_quats and self.positions.shape[0] > 1 and np.allclose(q, q[:1], atol=1e-9)):
                flip = np.cumprod(np.where(np.sum(q[1:] * q[:-1], axis=1) < 0, -1.0, 1.0))
                q[1:] *= flip[:, None]
                self.quats = q
        self._seg = np.diff(self.positions, axis=0)
        self._seg_len2 = np.maximum(np.sum(self._seg * self._seg, axis=1), 1e-18)
        self.arc = np.concatenate([[0.0], np.cumsum(np.sqrt(np.sum(self._seg * self._seg, axis=1)))])
        self.length = float(self.arc[-1])
        self.yaw = self._vertex_yaw()

    def _vertex_yaw(self) -> np.ndarray:
        p = self.positions
        if p.shape[0] < 2:
            return np.zeros(p.shape[0])
        tangent = np.empty_like(p)
        tangent[0] = p[1] - p[0]
        tangent[-1] = p[-1] - p[-2]
        tangent[1:-1] = p[2:] - p[:-2]
        return np.unwrap(np.arctan2(tangent[:, 1], tangent[:, 0]))

    def locate(self, position: np.ndarray, previous: float | None = None, back: float = 1.0,
               ahead: float = 5.0) -> tuple[float, float]:
        """Arc length [m] of the point on the path nearest to ``position``, and its distance [m].

        With ``previous`` progress only the stretch [previous − back, previous + ahead] is searched (so a
        path that passes near itself cannot make progress jump) and the result never decreases.
        """
        window = None if previous is None else (previous - back, previous + ahead)
        s_foot, d = project_onto_polyline(self.positions, self.arc, position, window)
        s_new = s_foot if previous is None else max(s_foot, float(previous))
        return min(s_new, self.length), d

    def sample(self, s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Positions (K, 3) and body quaternions (K, 4) at arc lengths ``s`` (K,), clamped to the path."""
        s = np.clip(np.atleast_1d(np.asarray(s, float)), 0.0, self.length)
        if self.positions.shape[0] == 1:
            q = self.quats[0] if self.quats is not None else np.array([0.0, 0.0, 0.0, 1.0])
            return np.repeat(self.positions, s.shape[0], axis=0), np.tile(q, (s.shape[0], 1))
        i = np.clip(np.searchsorted(self.arc, s, side="right") - 1, 0, self.positions.shape[0] - 2)
        u = ((s - self.arc[i]) / np.maximum(self.arc[i + 1] - self.arc[i], 1e-12))[:, None]
        pos = self.positions[i] + u * self._seg[i]
        if self.quats is not None:
            quats = normalize((1 - u) * self.quats[i] + u * self.quats[i + 1])
        else:
            quats = matrix_to_quat(yaw_to_matrix((1 - u[:, 0]) * self.yaw[i] + u[:, 0] * self.yaw[i + 1]))
        return pos, quats

    def direction(self, s: float) -> np.ndarray:
        """Unit direction of travel (3,) at arc length ``s``."""
        if self.positions.shape[0] == 1:
            return np.zeros(3)
        i = int(np.clip(np.searchsorted(self.arc, s, side="right") - 1, 0, self.positions.shape[0] - 2))
        return self._seg[i] / np.sqrt(self._seg_len2[i])
