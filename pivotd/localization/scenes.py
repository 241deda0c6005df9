"""Scenes for the localization benchmark: landmark maps with occluding walls and a timed route.

Two sources:

* the FIF maps shipped in ``tests/data/fif`` with their trajectories (walls made of landmarks; the
  occupancy grid is built from the landmarks themselves, no surface normals);
* seeded procedural scenes built from vertical walls and boxes: ``rooms`` (three rooms joined by
  doorways, some walls textureless), ``corridor`` (one textureless wall, the other textured in patches)
  and ``warehouse`` (an aisle out and the next one back between racks stocked in clusters, some bays
  empty). Walls occlude (their surfaces are sampled into the occupancy grid); landmarks sit on
  textured faces with the face normal, so they are seen only from the front.

Routes are polylines at the demo robot's walking speed (FIF routes keep their own time stamps); the
body heading follows the route (FIF: the file's attitudes).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.localization.stack import load_landmarks, load_path

WALL_HEIGHT = 2.5  # [m]
BODY_HEIGHT = 0.3  # [m] route height above the floor (the gimbal sits above it, see the mount)
OCCUPANCY_VOXEL = 0.2  # [m] procedural scenes
FIF_VOXEL = 0.5  # [m] FIF walls are sparse landmark planes
SPEED = 0.8  # [m/s] config/demo.yaml sim.speed
_SURFACE_STEP = 0.1  # [m] occupancy sampling of wall surfaces


@dataclass(frozen=True)
class LocScene:
    """A map and a route.

    landmarks (M, 3) [m]; normals (M, 3) unit outward face normals or None (unknown); occupancy (K, 3)
    points whose voxels block sight; voxel [m]; route (P, 3) body positions [m] with route_quats (P, 4)
    (x, y, z, w) or None (heading along the route); stamps (P,) [s] the time at each route vertex.
    """

    name: str
    landmarks: np.ndarray
    normals: np.ndarray | None
    occupancy: np.ndarray
    voxel: float
    route: np.ndarray
    route_quats: np.ndarray | None
    stamps: np.ndarray

    @property
    def duration(self) -> float:
        """Route duration [s]."""
        return float(self.stamps[-1] - self.stamps[0])

    @property
    def arc(self) -> np.ndarray:
        """(P,) arc length [m] at each route vertex."""
        return np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(self.route, axis=0), axis=1))])


class _Builder:
    """Collects wall surfaces (occupancy samples) and landmarks with normals."""

    def __init__(self, rng: np.random.Generator) -> None:
        self.rng = rng
        self.occ: list[np.ndarray] = []
        self.pts: list[np.ndarray] = []
        self.nrm: list[np.ndarray] = []

    def wall(self, a: tuple[float, float], b: tuple[float, float], z0: float = 0.0, z1: float = WALL_HEIGHT,
             gaps: tuple[tuple[float, float], ...] = ()) -> None:
        """Occluding vertical wall from ``a`` to ``b`` (x, y) [m], heights [z0, z1], with open ``gaps``
        (intervals of distance from ``a``) such as doorways."""
        a_, b_ = np.asarray(a, float), np.asarray(b, float)
        length = float(np.linalg.norm(b_ - a_))
        s = np.arange(0.0, length + 1e-9, _SURFACE_STEP)
        for g0, g1 in gaps:
            s = s[(s < g0) | (s > g1)]
        z = np.arange(z0, z1 + 1e-9, _SURFACE_STEP)
        ss, zz = np.meshgrid(s, z, indexing="ij")
        xy = a_ + np.outer(ss.ravel(), (b_ - a_) / max(length, 1e-12))
        self.occ.append(np.column_stack([xy, zz.ravel()]))

    def texture(self, a: tuple[float, float], b: tuple[float, float], side: float, density: float,
                z0: float = 0.0, z1: float = WALL_HEIGHT, span: tuple[float, float] | None = None) -> None:
        """Landmarks on the face of wall a→b on the ``side`` (+1 left of a→b, −1 right), ``density`` per m²,
        uniformly over distances ``span`` (default the whole wall) and heights [z0, z1]."""
        a_, b_ = np.asarray(a, float), np.asarray(b, float)
        length = float(np.linalg.norm(b_ - a_))
        u = (b_ - a_) / max(length, 1e-12)
        normal = side * np.array([-u[1], u[0]])
        lo, hi = span or (0.0, length)
        n = self.rng.poisson(density * (hi - lo) * (z1 - z0))
        s = self.rng.uniform(lo, hi, n)
        z = self.rng.uniform(z0, z1, n)
        xy = a_ + np.outer(s, u) + 0.02 * normal
        self.pts.append(np.column_stack([xy, z]))
        self.nrm.append(np.tile([normal[0], normal[1], 0.0], (n, 1)))

    def box(self, lo: tuple[float, float], hi: tuple[float, float], z1: float) -> None:
        """Occluding box [lo, hi] (x, y) [m] from the floor to ``z1``."""
        (x0, y0), (x1, y1) = lo, hi
        for a, b in (((x0, y0), (x1, y0)), ((x1, y0), (x1, y1)), ((x1, y1), (x0, y1)), ((x0, y1), (x0, y0))):
            self.wall(a, b, 0.0, z1)

    def scene(self, name: str, route: np.ndarray) -> LocScene:
        route = np.column_stack([route, np.full(route.shape[0], BODY_HEIGHT)])
        arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(route, axis=0), axis=1))])
        return LocScene(name, np.concatenate(self.pts), np.concatenate(self.nrm), np.concatenate(self.occ),
                        OCCUPANCY_VOXEL, route, None, arc / SPEED)


def _densify(corners: list[tuple[float, float]], step: float = 0.25) -> np.ndarray:
    """Polyline through ``corners`` resampled every ``step`` [m] with rounded corners (radius ≈ 0.5 m)."""
    c = np.asarray(corners, float)
    pts = [c[0]]
    for i in range(1, len(c) - 1):
        a, b, d = c[i - 1], c[i], c[i + 1]
        r = min(0.5, 0.45 * np.linalg.norm(b - a), 0.45 * np.linalg.norm(d - b))
        p0 = b + r * (a - b) / np.linalg.norm(a - b)
        p1 = b + r * (d - b) / np.linalg.norm(d - b)
        t = np.linspace(0, 1, 7)[:, None]
        pts.extend((1 - t) ** 2 * p0 + 2 * (1 - t) * t * b + t**2 * p1)
    pts.append(c[-1])
    p = np.asarray(pts)
    seg = np.linalg.norm(np.diff(p, axis=0), axis=1)
    keep = np.concatenate([[True], seg > 1e-9])
    p = p[keep]
    arc = np.concatenate([[0.0], np.cumsum(np.linalg.norm(np.diff(p, axis=0), axis=1))])
    s = np.arange(0.0, arc[-1], step)
    s = np.append(s, arc[-1]) if arc[-1] - s[-1] > 1e-6 else s
    return np.column_stack([np.interp(s, arc, p[:, 0]), np.interp(s, arc, p[:, 1])])


def rooms(seed: int) -> LocScene:
    """Three 6 × 5 m rooms in a row joined by 1.2 m doorways; each wall face is textured (4 /m²) with
    probability ½ (at least one per room); the route crosses every room through the doorways."""
    rng = np.random.default_rng([seed, 1])
    b = _Builder(rng)
    w, h, door = 6.0, 5.0, 1.2
    doors = rng.uniform(1.0, h - 1.0 - door, 2)
    b.wall((0, 0), (3 * w, 0))
    b.wall((3 * w, 0), (3 * w, h))
    b.wall((3 * w, h), (0, h))
    b.wall((0, h), (0, 0))
    for k, y in enumerate(doors):
        x = (k + 1) * w
        b.wall((x, 0), (x, h), gaps=((y, y + door),))
    for room in range(3):
        x0, x1 = room * w, (room + 1) * w
        faces = [((x0, 0), (x1, 0), 1.0), ((x1, 0), (x1, h), 1.0), ((x1, h), (x0, h), 1.0), ((x0, h), (x0, 0), 1.0)]
        chosen = rng.random(4) < 0.5
        chosen[rng.integers(4)] = True
        for (a, c, side), on in zip(faces, chosen, strict=True):
            if on:
                b.texture(a, c, side, 4.0)
    corners = [(1.0, rng.uniform(1.0, h - 1.0))]
    for k, y in enumerate(doors):
        x = (k + 1) * w
        corners.append((x - rng.uniform(2.0, 4.0), rng.uniform(1.0, h - 1.0)))
        corners += [(x - 0.8, y + door / 2), (x + 0.8, y + door / 2)]
    corners.append((3 * w - 1.0, rng.uniform(1.0, h - 1.0)))
    return b.scene("rooms", _densify(corners))


def corridor(seed: int) -> LocScene:
    """A 30 × 2.4 m corridor: left wall textureless, right wall textured (10 /m²) in 1–3 m patches with
    1–4 m gaps, textured end walls; the route walks the centre line."""
    rng = np.random.default_rng([seed, 2])
    b = _Builder(rng)
    length, half = 30.0, 1.2
    b.wall((0, -half), (length, -half))
    b.wall((length, half), (0, half))
    b.wall((0, half), (0, -half))
    b.wall((length, -half), (length, half))
    s = rng.uniform(0.0, 2.0)
    while s < length:
        e = min(length, s + rng.uniform(1.0, 3.0))
        b.texture((0, -half), (length, -half), 1.0, 10.0, span=(s, e))
        s = e + rng.uniform(1.0, 4.0)
    b.texture((0, half), (0, -half), 1.0, 6.0)
    b.texture((length, -half), (length, half), 1.0, 6.0)
    y = rng.uniform(-0.3, 0.3)
    return b.scene("corridor", _densify([(1.0, y), (length - 1.0, -y)]))


def warehouse(seed: int) -> LocScene:
    """Three 14 × 1 × 3 m racks with 3 m aisles; each 1.5 m bay face holds a cluster of 15 labels with
    probability 0.6, else nothing; sparse outer walls (1 /m²). The route goes out along one aisle and
    back along the next."""
    rng = np.random.default_rng([seed, 3])
    b = _Builder(rng)
    x0, x1 = 0.0, 14.0
    rack_y = (0.0, 4.0, 8.0)
    for y in rack_y:
        b.box((x0, y), (x1, y + 1.0), 3.0)
        for face_y, side in ((y, -1.0), (y + 1.0, 1.0)):
            for bay in np.arange(x0, x1 - 1e-9, 1.5):
                if rng.random() < 0.6:
                    c = bay + rng.uniform(0.3, 1.2)
                    zc = rng.uniform(0.3, 2.5)
                    n = 15
                    pts = np.column_stack([rng.uniform(c - 0.3, c + 0.3, n), np.full(n, face_y + 0.02 * side),
                                           np.clip(rng.uniform(zc - 0.3, zc + 0.3, n), 0.05, 2.95)])
                    b.pts.append(pts)
                    b.nrm.append(np.tile([0.0, side, 0.0], (n, 1)))
    lo, hi = (-4.0, -3.0), (18.0, 12.0)
    walls = [((lo[0], lo[1]), (hi[0], lo[1])), ((hi[0], lo[1]), (hi[0], hi[1])),
             ((hi[0], hi[1]), (lo[0], hi[1])), ((lo[0], hi[1]), (lo[0], lo[1]))]
    for a, c in walls:
        b.wall(a, c, 0.0, 4.0)
        b.texture(a, c, 1.0, 1.0, 0.0, 4.0)
    corners = [(-2.0, 2.5), (16.0, 2.5), (16.0, 6.5), (-2.0, 6.5)]
    return b.scene("warehouse", _densify(corners))


PROCEDURAL: dict[str, Callable[[int], LocScene]] = {"rooms": rooms, "corridor": corridor, "warehouse": warehouse}

FIF_SCENES: dict[str, tuple[str, str]] = {
    "fif_two_walls": ("two_walls_points_w.txt", "test_traj.csv"),
    "fif_four_walls": ("four_walls_points_w.txt", "test_traj.csv"),
    "fif_ycorridor": ("ycorridor_6x20_points_w.txt", "ycorridor_6x20.csv"),
}


def fif_scene(name: str, data_dir: Path) -> LocScene:
    """FIF map ``name`` (a key of FIF_SCENES) with its trajectory from ``data_dir``."""
    map_file, traj_file = FIF_SCENES[name]
    cloud = load_landmarks(data_dir / map_file)
    path = load_path(data_dir / traj_file)
    if path.stamps is None or path.quats is None:
        raise InputError(f"{data_dir / traj_file}: expected a timed FIF trajectory "
                         "(timestamp, x, y, z, qw, qx, qy, qz)")
    pts = np.asarray(cloud.points, float)
    return LocScene(name, pts, None, pts, FIF_VOXEL, path.positions, path.quats, path.stamps - path.stamps[0])


def scene_names() -> list[str]:
    """All scene names: the FIF maps first, then the procedural scenes."""
    return [*FIF_SCENES, *PROCEDURAL]


def build_scene(name: str, seed: int, fif_dir: Path) -> LocScene:
    """Scene ``name``; procedural scenes are generated from ``seed``, FIF scenes do not depend on it."""
    if name in FIF_SCENES:
        return fif_scene(name, fif_dir)
    if name in PROCEDURAL:
        return PROCEDURAL[name](seed)
    raise InputError(f"unknown scene '{name}' (known: {', '.join(scene_names())})")
