"""Scene families the daemon is measured on end to end (``pivotd bench gap``): seeded landmark maps with a route.

Every family draws its geometry from ``numpy.random.default_rng(seed)``, so one seed gives one scene and another
seed another layout. Maps are sized for a 60° FoV at 0.3–10 m (a few hundred to a few thousand landmarks in view,
5k–60k in all; the FIF maps hold what their files hold, about 1000), routes run about 34–42 m (30–45 s at
0.8–1.2 m/s) through free space at the demo's body height:

* ``turn``: a corridor with an L- or U-turn; the walls around the corner are rich, the rest poor, so after the
  turn the rich wall is behind or beside the robot;
* ``aisles``: a serpentine through warehouse aisles whose shelf faces alternate rich and poor in bays, the left
  face rich where the right one is poor;
* ``clusters``: a loop through an open area with a few dense clusters at 2–9 m and a sparse background;
* ``fif``: the FIF maps of tests/data/fif (MIT licence, Zichao Zhang, RPG Zurich; see its LICENSE) with a loop
  around the walls' centre, or the y-corridor's own route shifted sideways;
* ``stop_turn``: a corridor with two corners where the robot stops and turns in place (a timed route with
  attitudes, rows t,x,y,z,qw,qx,qy,qz, played by ``tools/sim_pose --timed``).
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial import cKDTree

from pivotd.errors import InputError
from pivotd.geometry import matrix_to_quat, yaw_to_matrix
from pivotd.maps.formats import load_landmarks
from pivotd.robot_path import load_path

FIF_DIR = Path(__file__).resolve().parents[2] / "tests" / "data" / "fif"
ROUTE_STEP = 0.25  # [m] spacing of route rows
CLEARANCE = 0.3  # [m] no landmark this close to the route
WALL_Z = (0.2, 2.6)  # [m] heights of wall landmarks
_PIECE = 0.5  # [m] walls are sampled in pieces this long, each with its own density


@dataclass(frozen=True)
class FamilyScene:
    """One generated scene.

    landmarks (M, 3) [m]; route (K, 3) body positions [m]; quats (K, 4) body attitude (x, y, z, w) or None (heading
    along the route); stamps (K,) [s] or None: a timed route (played by its stamps, ``sim_pose --timed``).
    """

    name: str
    family: str
    seed: int
    landmarks: np.ndarray
    route: np.ndarray
    quats: np.ndarray | None = None
    stamps: np.ndarray | None = None

    @property
    def timed(self) -> bool:
        return self.stamps is not None

    @property
    def length(self) -> float:
        """Route length [m]."""
        return float(np.linalg.norm(np.diff(self.route, axis=0), axis=1).sum())


# --- geometry helpers ------------------------------------------------------------------------------------------


def densify(corners: np.ndarray, step: float = ROUTE_STEP) -> np.ndarray:
    """Points every ~``step`` [m] along the polyline through ``corners`` (P, D), corners kept."""
    corners = np.asarray(corners, float)
    out = [corners[:1]]
    for a, b in itertools.pairwise(corners):
        n = max(1, int(np.ceil(np.linalg.norm(b - a) / step)))
        u = np.arange(1, n + 1)[:, None] / n
        out.append(a + u * (b - a))
    return np.concatenate(out)


def _chaikin(xy: np.ndarray, rounds: int, closed: bool = False) -> np.ndarray:
    """Corner cutting (stays inside the hull of the corners); open polylines keep their ends."""
    for _ in range(rounds):
        a = np.vstack([xy, xy[:1]]) if closed else xy
        q = 0.75 * a[:-1] + 0.25 * a[1:]
        r = 0.25 * a[:-1] + 0.75 * a[1:]
        mid = np.stack([q, r], 1).reshape(-1, 2)
        xy = mid if closed else np.vstack([xy[:1], mid, xy[-1:]])
    return xy


def _wall(rng: np.random.Generator, a: np.ndarray, b: np.ndarray, density: Callable[[np.ndarray], float],
          z: tuple[float, float] = WALL_Z) -> np.ndarray:
    """Landmarks (N, 3) on the vertical wall from ``a`` to ``b`` (x, y) [m]; ``density(midpoint)`` gives landmarks
    per metre of wall for each piece of about 0.5 m; a few cm of scatter off the wall plane."""
    a, b = np.asarray(a, float), np.asarray(b, float)
    length = float(np.linalg.norm(b - a))
    if length < 1e-9:
        return np.empty((0, 3))
    along = (b - a) / length
    normal = np.array([-along[1], along[0]])
    n_pieces = max(1, int(np.ceil(length / _PIECE)))
    edges = np.linspace(0.0, length, n_pieces + 1)
    out = []
    for lo, hi in itertools.pairwise(edges):
        count = rng.poisson(density(a + along * 0.5 * (lo + hi)) * (hi - lo))
        s = rng.uniform(lo, hi, count)
        xy = a + s[:, None] * along + rng.normal(0.0, 0.02, (count, 1)) * normal
        out.append(np.column_stack([xy, rng.uniform(z[0], z[1], count)]))
    return np.concatenate(out)


def _offset(corners: np.ndarray, side: float, half_width: float) -> np.ndarray:
    """The polyline ``corners`` (P, 2) offset by ``side * half_width`` [m] to its left (side +1) or right (-1),
    with mitred joins."""
    seg = np.diff(corners, axis=0)
    seg /= np.linalg.norm(seg, axis=1, keepdims=True)
    nrm = np.column_stack([-seg[:, 1], seg[:, 0]])
    out = np.empty_like(corners)
    out[0] = corners[0] + side * half_width * nrm[0]
    out[-1] = corners[-1] + side * half_width * nrm[-1]
    for i in range(1, corners.shape[0] - 1):
        n1, n2 = nrm[i - 1], nrm[i]
        out[i] = corners[i] + side * half_width * (n1 + n2) / (1.0 + float(n1 @ n2))
    return out


def _corridor(rng: np.random.Generator, corners: np.ndarray, width: float,
              density: Callable[[np.ndarray, int, float], float], margin: float = 1.0) -> np.ndarray:
    """Walls (landmarks (N, 3)) of a corridor ``width`` [m] wide around the centreline ``corners`` (P, 2), each end
    closed by a wall ``margin`` [m] beyond it; ``density(point, leg, side)`` [landmarks/m] with leg the index of the
    segment (-1 for the end walls) and side +1 left, -1 right."""
    c = np.asarray(corners, float).copy()
    c[0] -= margin * (c[1] - c[0]) / np.linalg.norm(c[1] - c[0])
    c[-1] += margin * (c[-1] - c[-2]) / np.linalg.norm(c[-1] - c[-2])
    walls = []
    for side in (1.0, -1.0):
        line = _offset(c, side, 0.5 * width)
        for leg in range(c.shape[0] - 1):
            walls.append(_wall(rng, line[leg], line[leg + 1], lambda p, leg=leg, side=side: density(p, leg, side)))
    left, right = _offset(c, 1.0, 0.5 * width), _offset(c, -1.0, 0.5 * width)
    for i in (0, -1):
        walls.append(_wall(rng, left[i], right[i], lambda p: density(p, -1, 0.0)))
    return np.concatenate(walls)


def _with_height(xy: np.ndarray, z: float) -> np.ndarray:
    return np.column_stack([xy, np.full(xy.shape[0], z)])


def _yaw_quats(yaw: np.ndarray) -> np.ndarray:
    return matrix_to_quat(yaw_to_matrix(np.asarray(yaw, float)))


# --- families --------------------------------------------------------------------------------------------------


def turn(seed: int, speed: float = 1.0) -> FamilyScene:
    """L- or U-turn corridor, rich walls around the corner(s), poor elsewhere."""
    rng = np.random.default_rng(seed)
    width = rng.uniform(2.4, 3.4)
    total = rng.uniform(34.0, 42.0)
    sign = rng.choice([-1.0, 1.0])  # left or right turn
    u_turn = bool(rng.random() < 0.5)
    leg_a = rng.uniform(14.0, 20.0)
    if u_turn:
        gap = width + rng.uniform(0.3, 1.0)  # the legs' spacing: corridor plus a divider
        corners = np.array([[0.0, 0.0], [leg_a, 0.0], [leg_a, sign * gap], [leg_a - (total - leg_a - gap),
                                                                           sign * gap]])
    else:
        corners = np.array([[0.0, 0.0], [leg_a, 0.0], [leg_a, sign * (total - leg_a)]])
    outer = -sign  # the outer side of a turn to the left is the right wall
    rich, poor, medium = rng.uniform(200.0, 400.0), rng.uniform(4.0, 12.0), rng.uniform(15.0, 40.0)
    reach = rng.uniform(4.0, 8.0)  # [m] rich stretch of the outer walls on each side of a corner
    bends = corners[1:-1]

    def density(p: np.ndarray, leg: int, side: float) -> float:
        near = float(np.min(np.linalg.norm(bends - p, axis=1))) < reach + 0.5 * width
        if side == outer and near:
            return rich
        return medium if leg == 0 else poor

    pts = _corridor(rng, corners, width, density)
    z = rng.uniform(0.5, 0.9)
    route = _with_height(densify(corners), z)
    return FamilyScene(f"turn-{'U' if u_turn else 'L'}{'left' if sign > 0 else 'right'}", "turn", seed, pts, route)


def aisles(seed: int, speed: float = 1.0) -> FamilyScene:
    """Serpentine through 2–3 warehouse aisles; each aisle's two shelf faces alternate rich/poor in 1.5–2.5 m bays."""
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 4))
    aisle, depth, cross = rng.uniform(2.2, 3.0), rng.uniform(0.8, 1.2), 1.5
    total = rng.uniform(34.0, 42.0)
    pitch = aisle + depth
    shelf = (total - (n - 1) * pitch) / n - 1.0 - cross  # each aisle runs from x = -1 to shelf + cross
    rich, poor = rng.uniform(200.0, 350.0), rng.uniform(5.0, 15.0)
    top = rng.uniform(2.0, 3.0)
    pts = []
    for i in range(n):
        yc = i * pitch
        bays = np.cumsum(rng.uniform(1.5, 2.5, 40))
        phase = int(rng.integers(0, 2))

        def face(p: np.ndarray, left: bool, bays=bays, phase=phase) -> float:
            k = int(np.searchsorted(bays, p[0]))
            return rich if (k + phase + int(left)) % 2 == 0 else poor

        for side in (1.0, -1.0):
            y = yc + side * 0.5 * aisle
            pts.append(_wall(rng, np.array([0.0, y]), np.array([shelf, y]),
                             lambda p, left=side > 0: face(p, left), z=(0.1, top)))
    for j in range(n + 1):  # shelf ends, poor: row j spans the y between aisles j - 1 and j
        y_lo, y_hi = (j - 1) * pitch + 0.5 * aisle, j * pitch - 0.5 * aisle
        for x in (0.0, shelf):
            pts.append(_wall(rng, np.array([x, y_lo]), np.array([x, y_hi]), lambda p: poor, z=(0.1, top)))
    corners = []
    for i in range(n):
        xs = (-1.0, shelf + cross) if i % 2 == 0 else (shelf + cross, -1.0)
        corners += [[xs[0], i * pitch], [xs[1], i * pitch]]
    z = rng.uniform(0.5, 0.9)
    route = _with_height(densify(np.array(corners)), z)
    return FamilyScene(f"aisles-{n}", "aisles", seed, np.concatenate(pts), route)


def clusters(seed: int, speed: float = 1.0) -> FamilyScene:
    """A smooth loop through an open area with 4–7 dense clusters at 2–9 m from it and a sparse background."""
    rng = np.random.default_rng(seed)
    k = int(rng.integers(5, 8))
    ang = (np.arange(k) + rng.uniform(-0.3, 0.3, k)) * 2 * np.pi / k
    radius = rng.uniform(5.0, 8.0, k)
    xy = _chaikin(np.column_stack([radius * np.cos(ang), radius * np.sin(ang)]), 4, closed=True)
    xy = np.vstack([xy, xy[:1]])
    scale = rng.uniform(34.0, 42.0) / float(np.linalg.norm(np.diff(xy, axis=0), axis=1).sum())
    route_xy = densify(xy * scale)
    z = rng.uniform(0.5, 0.9)
    route = _with_height(route_xy, z)
    tree = cKDTree(route)
    pts = []
    n_clusters = int(rng.integers(4, 8))
    for _ in range(n_clusters):
        sigma = rng.uniform(0.2, 0.8)
        for _attempt in range(50):
            anchor = route[rng.integers(0, route.shape[0])]
            phi = rng.uniform(0, 2 * np.pi)
            centre = anchor + rng.uniform(2.0, 9.0) * np.array([np.cos(phi), np.sin(phi), 0.0])
            centre[2] = rng.uniform(0.3, 3.0)
            if tree.query(centre)[0] > 1.0 + 2 * sigma:
                break
        blob = rng.normal(centre, sigma * rng.uniform(0.6, 1.4, 3), (int(rng.integers(800, 3000)), 3))
        pts.append(blob)
    lo, hi = route.min(axis=0) - 10.0, route.max(axis=0) + 10.0
    back = rng.uniform([lo[0], lo[1], 0.0], [hi[0], hi[1], 4.0], (int(rng.integers(1500, 3000)), 3))
    pts = np.concatenate([*pts, back])
    pts = pts[tree.query(pts)[0] > 2 * CLEARANCE]
    return FamilyScene(f"clusters-{n_clusters}", "clusters", seed, pts, route)


FIF_MAPS = ("four_walls", "two_walls", "ycorridor_6x20")


def fif(seed: int, speed: float = 1.0) -> FamilyScene:
    """FIF map ``FIF_MAPS[seed % 3]``: the box maps with a loop (circle or ellipse, 0.9–1.5 m) around the
    walls' centre, camera near mid-height; the y-corridor with its own route shifted sideways."""
    rng = np.random.default_rng(seed)
    which = FIF_MAPS[seed % len(FIF_MAPS)]
    pts = np.asarray(load_landmarks(FIF_DIR / f"{which}_points_w.txt").points, float)
    mid = 0.5 * (pts.min(axis=0) + pts.max(axis=0))
    mount_z = 0.2  # config/demo.yaml gimbal.mount.xyz[2]: the camera sits this far above the body
    z = mid[2] - mount_z + rng.uniform(-0.2, 0.2)
    if which == "ycorridor_6x20":
        xy = load_path(FIF_DIR / "ycorridor_6x20.csv").positions[:, :2] + [rng.uniform(-0.3, 0.3), 0.0]
        if rng.random() < 0.5:
            xy = xy[::-1]
        route_xy = densify(xy)
    else:
        a, b = rng.uniform(0.9, 1.5, 2)
        centre = mid[:2] + rng.uniform(-0.2, 0.2, 2)
        turns = rng.uniform(34.0, 42.0) / (np.pi * (a + b))  # laps, from the ellipse's approximate perimeter
        th = rng.uniform(0, 2 * np.pi) + rng.choice([-1.0, 1.0]) * np.linspace(0, 2 * np.pi * turns,
                                                                               int(turns * 64) + 1)
        route_xy = densify(centre + np.column_stack([a * np.cos(th), b * np.sin(th)]))
    return FamilyScene(f"fif-{which}", "fif", seed, pts, _with_height(route_xy, z))


def stop_turn(seed: int, speed: float = 1.0) -> FamilyScene:
    """A corridor with two corners; at each the robot stops, turns in place by the corner's angle at 30–60°/s and
    drives on. Walls in 3 m bays, rich with probability 0.4. Timed route at ``speed`` [m/s]."""
    rng = np.random.default_rng(seed)
    width = rng.uniform(3.0, 4.0)
    legs = rng.uniform(10.0, 14.0, 3)
    legs *= rng.uniform(32.0, 38.0) / legs.sum()
    yaw, corners = 0.0, [np.zeros(2)]
    turns = rng.choice([-1.0, 1.0], 2) * np.pi / 2
    for i, leg in enumerate(legs):
        corners.append(corners[-1] + leg * np.array([np.cos(yaw), np.sin(yaw)]))
        if i < 2:
            yaw += turns[i]
    corners = np.array(corners)
    rich, poor = rng.uniform(200.0, 350.0), rng.uniform(4.0, 12.0)
    bay_rich: dict[tuple, bool] = {}

    def density(p: np.ndarray, leg: int, side: float) -> float:
        key = (leg, side, *np.floor(p / 3.0).astype(int).tolist())  # 3 m bays
        if key not in bay_rich:
            bay_rich[key] = bool(rng.random() < 0.4)
        return rich if bay_rich[key] else poor

    pts = _corridor(rng, corners, width, density)
    z = rng.uniform(0.5, 0.9)
    yaw_rate = np.radians(rng.uniform(30.0, 60.0))
    pause = rng.uniform(0.5, 1.0)
    rows_t, rows_xy, rows_yaw = [], [], []
    t, heading = 0.0, 0.0
    for i in range(3):
        seg = densify(corners[i:i + 2])
        steps = np.linalg.norm(np.diff(seg, axis=0), axis=1)
        times = t + np.concatenate([[0.0], np.cumsum(steps)]) / speed
        start = 0 if i == 0 else 1  # the corner row is already there
        rows_t += list(times[start:])
        rows_xy += list(seg[start:])
        rows_yaw += [heading] * (seg.shape[0] - start)
        t = float(times[-1])
        if i < 2:
            n = max(2, int(np.ceil(abs(turns[i]) / np.radians(10.0))))
            spin = np.linspace(0.0, turns[i], n + 1)[1:]
            rows_t += [t + pause, *(t + pause + (abs(spin) / yaw_rate))]
            rows_xy += [corners[i + 1]] * (n + 1)
            rows_yaw += [heading, *(heading + spin)]
            heading += float(turns[i])
            t = rows_t[-1] + pause
            rows_t.append(t)
            rows_xy.append(corners[i + 1])
            rows_yaw.append(heading)
    route = _with_height(np.array(rows_xy), z)
    return FamilyScene("stop_turn", "stop_turn", seed, pts, route, _yaw_quats(np.array(rows_yaw)),
                       np.array(rows_t))


FAMILIES: dict[str, Callable[..., FamilyScene]] = {
    "turn": turn, "aisles": aisles, "clusters": clusters, "fif": fif, "stop_turn": stop_turn,
}


def generate(family: str, seed: int, speed: float = 1.0) -> FamilyScene:
    """Scene of ``family`` for ``seed``; ``speed`` [m/s] times timed routes. Raises InputError on an unknown name."""
    if family not in FAMILIES:
        raise InputError(f"unknown scene family {family!r} (known: {', '.join(FAMILIES)})")
    return FAMILIES[family](seed, speed)


# --- checks and files ------------------------------------------------------------------------------------------


def clearance(scene: FamilyScene) -> float:
    """Smallest distance [m] from a route row to a landmark."""
    return float(cKDTree(scene.landmarks).query(scene.route)[0].min())


def in_range_counts(scene: FamilyScene, min_range: float = 0.3, max_range: float = 10.0) -> np.ndarray:
    """Landmarks (K,) at a distance in [min_range, max_range] [m] of each route row (any direction)."""
    tree = cKDTree(scene.landmarks)
    far = np.array([len(x) for x in tree.query_ball_point(scene.route, max_range)])
    near = np.array([len(x) for x in tree.query_ball_point(scene.route, min_range)])
    return far - near


def write_scene(scene: FamilyScene, out_dir: Path) -> tuple[Path, str]:
    """Write the map (``map.npy``, (M, 3)) and the route CSV (``route.csv``: rows x,y,z, or t,x,y,z,qw,qx,qy,qz for
    a timed route) into ``out_dir``; returns the map path and the route spec (``csv:FILE``) for ``sim_pose``."""
    out_dir.mkdir(parents=True, exist_ok=True)
    map_path, route_path = out_dir / "map.npy", out_dir / "route.csv"
    np.save(map_path, np.ascontiguousarray(scene.landmarks, dtype=float))
    if scene.timed:
        q = scene.quats if scene.quats is not None else np.tile([0.0, 0.0, 0.0, 1.0], (scene.route.shape[0], 1))
        rows = np.column_stack([scene.stamps, scene.route, q[:, 3], q[:, :3]])
        np.savetxt(route_path, rows, fmt="%.6f", delimiter=",", header="t,x,y,z,qw,qx,qy,qz", comments="")
    else:
        np.savetxt(route_path, scene.route, fmt="%.6f", delimiter=",", header="x,y,z", comments="")
    return map_path, f"csv:{route_path}"
