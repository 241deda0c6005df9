"""Synthetic scenes for tests, benchmarks and the demo (deterministic given a seed)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["HARD_FAMILIES", "MC_CLUSTERS", "MC_EXTENT", "MC_HEIGHT", "MC_LEVELS", "MC_PER_CLUSTER", "Scene",
           "competing_clusters_path", "hallway", "hard_path", "hard_scene", "monte_carlo_levels", "monte_carlo_map",
           "monte_carlo_poses", "two_clusters"]


@dataclass(frozen=True)
class Scene:
    """points: (M, 3) landmarks [m]; weights: (M,); path: (N, 3) sensor positions [m]."""

    points: np.ndarray
    weights: np.ndarray
    path: np.ndarray


def _hallway_centerline(length: float, step: float) -> tuple[np.ndarray, np.ndarray]:
    """S-shaped centerline: +x, a left turn to +y, a right turn back to +x. Returns xy (K,2), heading (K,)."""
    s = np.arange(0.0, length + 1e-9, step)

    def sig(u: np.ndarray) -> np.ndarray:
        return 1.0 / (1.0 + np.exp(-u))

    heading = 0.5 * np.pi * (sig((s - 0.3 * length) / 1.2) - sig((s - 0.7 * length) / 1.2))
    dx = np.cos(heading) * step
    dy = np.sin(heading) * step
    xy = np.stack([np.concatenate([[0.0], np.cumsum(dx[:-1])]), np.concatenate([[0.0], np.cumsum(dy[:-1])])], 1)
    return xy, heading


def hallway(
    length: float = 36.0,
    width: float = 3.0,
    spacing: float = 0.5,
    rich_side_points: int = 3000,
    poor_side_points: int = 150,
    sensor_height: float = 0.7,
    seed: int = 0,
) -> Scene:
    """S-shaped hallway like the paper's indoor route: landmarks concentrated on the left wall.

    The route follows the centerline at ``sensor_height`` with waypoints every ``spacing`` metres.
    Left wall (rich side) gets ``rich_side_points`` landmarks, the right wall ``poor_side_points``,
    at heights 0.2–2.6 m, on walls ``width`` apart.
    """
    rng = np.random.default_rng(seed)
    fine_xy, fine_heading = _hallway_centerline(length, 0.05)
    normal = np.stack([-np.sin(fine_heading), np.cos(fine_heading)], 1)  # points left

    def wall(count: int, side: float) -> np.ndarray:
        idx = rng.integers(0, fine_xy.shape[0], count)
        xy = fine_xy[idx] + side * 0.5 * width * normal[idx] + rng.normal(0, 0.03, (count, 2)) * normal[idx]
        z = rng.uniform(0.2, 2.6, count)
        return np.column_stack([xy, z])

    points = np.concatenate([wall(rich_side_points, +1.0), wall(poor_side_points, -1.0)])
    path_xy, _ = _hallway_centerline(length, spacing)
    path = np.column_stack([path_xy, np.full(path_xy.shape[0], sensor_height)])
    return Scene(points=points, weights=np.ones(points.shape[0]), path=path)


# --- the paper's Monte Carlo evaluation (§V-A.2) ---------------------------------------------------

MC_CLUSTERS = 9
MC_PER_CLUSTER = 2000
MC_LEVELS = 10
MC_EXTENT = 400.0
MC_HEIGHT = 20.0


def monte_carlo_levels() -> list[int]:
    """Feature counts of the ten nested sets: 2000, 3778, …, 18000."""
    return [round(x) for x in np.linspace(2000, MC_CLUSTERS * MC_PER_CLUSTER, MC_LEVELS)]


def monte_carlo_map(level: int | None = None, seed: int = 0) -> np.ndarray:
    """Landmarks (M, 3) [m]: nine truncated Gaussian clusters of 2000 features in [−400, 400]² × [0, 20].

    Cluster centres are uniform in the box, σ_xy uniform in 30–80 m, σ_z 5 m; samples outside the
    box are redrawn (truncation). ``level`` 0–9 returns the first ``monte_carlo_levels()[level]`` of a
    fixed random permutation, so the sets are nested; None returns all 18 000.
    """
    rng = np.random.default_rng(seed)
    lo = np.array([-MC_EXTENT, -MC_EXTENT, 0.0])
    hi = np.array([MC_EXTENT, MC_EXTENT, MC_HEIGHT])
    clusters = []
    for _ in range(MC_CLUSTERS):
        centre = rng.uniform(lo, hi)
        sigma = np.array([*([rng.uniform(30.0, 80.0)] * 2), 5.0])
        pts = np.empty((0, 3))
        while pts.shape[0] < MC_PER_CLUSTER:
            draw = rng.normal(centre, sigma, (MC_PER_CLUSTER, 3))
            draw = draw[np.all((draw >= lo) & (draw <= hi), axis=1)]
            pts = np.concatenate([pts, draw])
        clusters.append(pts[:MC_PER_CLUSTER])
    points = np.concatenate(clusters)[rng.permutation(MC_CLUSTERS * MC_PER_CLUSTER)]
    if level is None:
        return points
    if not 0 <= level < MC_LEVELS:
        raise ValueError(f"level must be in 0..{MC_LEVELS - 1}, got {level}")
    return points[: monte_carlo_levels()[level]]


def monte_carlo_poses() -> np.ndarray:
    """The 20 × 20 grid of sensor positions (400, 3) spanning x, y ∈ [−400, 400] at z = 20 m."""
    g = np.linspace(-MC_EXTENT, MC_EXTENT, 20)
    x, y = np.meshgrid(g, g, indexing="ij")
    return np.column_stack([x.ravel(), y.ravel(), np.full(400, MC_HEIGHT)])


def _cone_cluster(rng: np.random.Generator, axis: np.ndarray, spread: float, n: int, dist: float) -> np.ndarray:
    """``n`` points at about ``dist`` [m] whose bearings lie within ``spread`` [rad] of the unit ``axis``."""
    frame = np.linalg.qr(np.column_stack([axis, rng.normal(size=(3, 2))]))[0]
    frame[:, 0] = axis
    r = spread * np.sqrt(rng.uniform(0, 1, n))
    phi = rng.uniform(0, 2 * np.pi, n)
    local = np.column_stack([np.cos(r), np.sin(r) * np.cos(phi), np.sin(r) * np.sin(phi)])
    u = local @ frame.T
    return u * rng.uniform(0.8, 1.2, (n, 1)) * dist


def two_clusters(
    n_large: int = 100,
    n_small: int = 60,
    separation_deg: float = 140.0,
    large_spread_deg: float = 15.0,
    small_spread_deg: float = 15.0,
    seed: int = 0,
) -> Scene:
    """The paper's toy example: two clusters of features seen from one sensor at the origin.

    The larger cluster (``n_large`` features within ``large_spread_deg`` of azimuth +sep/2) and the
    smaller one (``n_small`` within ``small_spread_deg`` of −sep/2) lie in the horizontal plane. Without an
    FoV limit the best axis points between them; with α = 45° only one fits, and the larger one wins.
    path: (1, 3) the origin.
    """
    rng = np.random.default_rng(seed)
    half = np.radians(separation_deg) / 2
    a = np.array([np.cos(half), np.sin(half), 0.0])
    b = np.array([np.cos(half), -np.sin(half), 0.0])
    pts = np.concatenate(
        [
            _cone_cluster(rng, a, np.radians(large_spread_deg), n_large, 10.0),
            _cone_cluster(rng, b, np.radians(small_spread_deg), n_small, 10.0),
        ]
    )
    return Scene(points=pts, weights=np.ones(pts.shape[0]), path=np.zeros((1, 3)))


def competing_clusters_path(
    length: float = 40.0,
    spacing: float = 1.0,
    offset: float = 6.0,
    per_cluster: int = 300,
    seed: int = 0,
) -> Scene:
    """A straight path along +x with feature clusters on both sides whose dominance swaps half-way.

    Left (+y) cluster centred at x = 0.3·length, right (−y) cluster at x = 0.7·length, both at lateral
    distance ``offset`` [m] with 1.5 m spread; sensor at z = 1 m. Visibility alone (λ = 0) looks at
    the left cluster first and flips to the right one near the middle.
    """
    rng = np.random.default_rng(seed)
    left = rng.normal([0.3 * length, offset, 1.0], [1.5, 1.5, 0.8], (per_cluster, 3))
    right = rng.normal([0.7 * length, -offset, 1.0], [1.5, 1.5, 0.8], (per_cluster, 3))
    pts = np.concatenate([left, right])
    x = np.arange(0.0, length + 1e-9, spacing)
    path = np.column_stack([x, np.zeros_like(x), np.ones_like(x)])
    return Scene(points=pts, weights=np.ones(pts.shape[0]), path=path)


# --- hard single-pose scenes: families that defeat naive multi-start --------------------------------

#: the hard scene families, in report order
HARD_FAMILIES: tuple[str, ...] = ("clusters", "near_far", "twins", "rooms", "ring", "blob")


def _random_rotation(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random rotation (3, 3) (QR of a Gaussian matrix with the sign fixed)."""
    q, r = np.linalg.qr(rng.normal(size=(3, 3)))
    q *= np.sign(np.diag(r))
    return q if np.linalg.det(q) > 0 else -q


def _anisotropic(rng: np.random.Generator, centre: np.ndarray, sigmas: np.ndarray, n: int) -> np.ndarray:
    """``n`` Gaussian points (n, 3) around ``centre`` with per-axis ``sigmas`` [m] in a random orientation."""
    return centre + (rng.normal(size=(n, 3)) * sigmas) @ _random_rotation(rng).T


def _clutter(rng: np.random.Generator, lo: np.ndarray, hi: np.ndarray, n: int) -> np.ndarray:
    """``n`` points uniform in the box [lo, hi] (n, 3)."""
    return rng.uniform(lo, hi, (n, 3))


def _count(n: float, scale: float) -> int:
    return max(1, round(n * scale))


def _clusters_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Seven anisotropic Gaussian clusters of very different sizes and densities (rods, sheets, blobs;
    σ per axis log-uniform in 0.5–20 m, counts log-uniform and scaled to 11 700 in all) plus 8 % uniform
    clutter in [−60, 60]² × [0, 15] m (≈ 12.7k landmarks at scale 1)."""
    lo, hi = np.array([-60.0, -60.0, 0.0]), np.array([60.0, 60.0, 15.0])
    counts = np.exp(rng.uniform(np.log(300), np.log(4000), 7))
    counts = np.maximum(1, np.round(counts * 11_700 * scale / counts.sum())).astype(int)
    inset = np.array([10.0, 10.0, 2.0])
    parts = [
        _anisotropic(rng, rng.uniform(lo + inset, hi - inset), np.exp(rng.uniform(np.log(0.5), np.log(20), 3)), k)
        for k in counts
    ]
    parts.append(_clutter(rng, lo, hi, _count(0.08 * 11_700 / 0.92, scale)))
    return np.concatenate(parts), lo + np.array([5.0, 5.0, 1.0]), hi - np.array([5.0, 5.0, 5.0])


def _near_far_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A large diffuse cluster near the sensor (≈ 9000 landmarks, σ 5 m at 12 m: far wider than a 30° cone)
    against a small dense one far away (1500–2200 landmarks, σ 1 m at 80 m: inside one cone), in random
    directions, plus 8 % clutter; which one wins depends on where in the ±3 m box the sensor stands."""
    d_near, d_far = _random_rotation(rng)[:, :2].T
    d_near[2], d_far[2] = 0.3 * d_near[2], 0.3 * d_far[2]
    d_near, d_far = d_near / np.linalg.norm(d_near), d_far / np.linalg.norm(d_far)
    near = _anisotropic(rng, 12.0 * d_near, np.array([5.0, 5.0, 3.0]), _count(9000, scale))
    far = _anisotropic(rng, 80.0 * d_far, np.array([1.0, 1.0, 0.6]), _count(rng.uniform(1500, 2200), scale))
    ext = np.array([90.0, 90.0, 20.0])
    clutter = _clutter(rng, -ext, ext, _count(0.08 * 10_850 / 0.92, scale))
    return np.concatenate([near, far, clutter]), np.array([-3.0, -3.0, -1.0]), np.array([3.0, 3.0, 1.0])


def _twins_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Two clusters of near-equal size (5000 and 5000·(1 ± 3 %) landmarks) of different shapes, 100–180°
    apart as seen from the origin at 20–40 m, plus 8 % clutter; the sensor stands within ±4 m of the origin."""
    az = rng.uniform(0, 2 * np.pi)
    sep = rng.uniform(np.radians(100), np.pi)
    dirs = [np.array([np.cos(a), np.sin(a), rng.uniform(-0.2, 0.2)]) for a in (az, az + sep)]
    n0 = 5000
    n1 = round(n0 * (1 + rng.uniform(-0.03, 0.03)))
    parts = [
        _anisotropic(rng, rng.uniform(20, 40) * d / np.linalg.norm(d), np.exp(rng.uniform(np.log(1.0), np.log(6.0), 3)),
                     _count(n, scale))
        for d, n in zip(dirs, (n0, n1), strict=True)
    ]
    ext = np.array([50.0, 50.0, 10.0])
    parts.append(_clutter(rng, -ext, ext, _count(0.08 * (n0 + n1) / 0.92, scale)))
    return np.concatenate(parts), np.array([-4.0, -4.0, -1.0]), np.array([4.0, 4.0, 1.0])


def _wall_points(rng: np.random.Generator, a: np.ndarray, b: np.ndarray, height: float, n: int) -> np.ndarray:
    """``n`` points (n, 3) on the vertical wall over the floor segment a → b (2,), 0–``height`` m, with
    half of them in a few dense patches (posters, shelves) and the rest uniform."""
    n_patch = n // 2
    u = rng.uniform(0, 1, n - n_patch)
    z = rng.uniform(0, height, n - n_patch)
    k = rng.integers(1, 4)
    pu, pz = rng.uniform(0.1, 0.9, k), rng.uniform(0.3, height - 0.3, k)
    which = rng.integers(0, k, n_patch)
    length = max(float(np.linalg.norm(b - a)), 1e-9)
    u = np.concatenate([u, np.clip(pu[which] + rng.normal(0, 0.4 / length, n_patch), 0, 1)])
    z = np.concatenate([z, np.clip(pz[which] + rng.normal(0, 0.3, n_patch), 0, height)])
    xy = a + u[:, None] * (b - a)
    return np.column_stack([xy, z])


def _rooms_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A floor: a 3-m-wide corridor along +x with three rooms on each side (6–10 m wide, 7 m deep, 3 m
    high); landmarks on every wall (uniform and in dense patches, per-wall density varying ×8) and
    sparsely on the floors (≈ 12k). No occlusion is modelled: walls of other rooms stay visible."""
    height = 3.0
    widths = rng.uniform(6.0, 10.0, 3)
    xs = np.concatenate([[0.0], np.cumsum(widths)])
    depth, half = 7.0, 1.5
    walls = [(np.array([0.0, -half]), np.array([xs[-1], -half])), (np.array([0.0, half]), np.array([xs[-1], half]))]
    for side in (-1.0, 1.0):
        y0, y1 = side * half, side * (half + depth)
        for i in range(3):
            walls.append((np.array([xs[i], y1]), np.array([xs[i + 1], y1])))  # back wall
        for x in xs:
            walls.append((np.array([x, y0]), np.array([x, y1])))  # side walls
    dens = np.exp(rng.uniform(0, np.log(8.0), len(walls)))
    lengths = np.array([np.linalg.norm(b - a) for a, b in walls])
    share = dens * lengths / np.sum(dens * lengths)
    parts = [_wall_points(rng, a, b, height, _count(s * 10_800, scale)) for (a, b), s in zip(walls, share, strict=True)]
    floor = rng.uniform([0.0, -half - depth, 0.0], [xs[-1], half + depth, 0.0], (_count(1200, scale), 3))
    parts.append(floor)
    sensor_lo = np.array([0.5, -half - depth + 0.5, 0.5])
    sensor_hi = np.array([xs[-1] - 0.5, half + depth - 0.5, 1.8])
    return np.concatenate(parts), sensor_lo, sensor_hi


def _ring_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Landmarks in an annulus 15–25 m around the origin, heights −1–3 m, with an azimuthal density
    1 + Σ low-frequency cosines (random phases) and a few blobs: many near-equal maxima all around
    the sensor, whose landmark centroid is near zero (≈ 12k). The sensor stands within ±2 m of the centre."""
    n = _count(12_000, scale)
    freqs = np.arange(1, 6)
    amp, phase = rng.uniform(0.0, 0.25, freqs.size), rng.uniform(0, 2 * np.pi, freqs.size)
    # rejection sampling of the azimuth density
    az = np.empty(0)
    while az.size < n:
        a = rng.uniform(0, 2 * np.pi, 2 * n)
        dens = 1.0 + np.cos(np.outer(a, freqs) + phase) @ amp
        az = np.concatenate([az, a[rng.uniform(0, 1 + amp.sum(), a.size) < dens]])
    n_blob = n // 10
    az = az[: n - n_blob]
    blob_az = rng.uniform(0, 2 * np.pi, 4)[rng.integers(0, 4, n_blob)] + rng.normal(0, 0.05, n_blob)
    az = np.concatenate([az, blob_az])
    r = rng.uniform(15.0, 25.0, n)
    z = rng.uniform(-1.0, 3.0, n)
    pts = np.column_stack([r * np.cos(az), r * np.sin(az), z])
    return pts, np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 1.5])


def _blob_family(rng: np.random.Generator, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The sensor inside a dense Gaussian cloud (the neighbourhood of a real map): 12k landmarks around the
    origin, σ = s · f per axis with s log-uniform in 6–14 m and f uniform in 1–1.5 (near-isotropic to mildly
    anisotropic, randomly oriented), of which 0–3 density lumps (σ 0.5–2 m, 0.5–3 % of the landmarks each)
    centred at points of the cloud. Every direction sees a similar count: a flat landscape whose maxima are
    shallow and many. The sensor stands within ±2 m (±1 m vertically) of the centre."""
    n = _count(12_000, scale)
    n_lumps = int(rng.integers(0, 4))
    sizes = [_count(s * 12_000, scale) for s in rng.uniform(0.005, 0.03, n_lumps)]
    sigmas = np.exp(rng.uniform(np.log(6.0), np.log(14.0))) * rng.uniform(1.0, 1.5, 3)
    cloud = _anisotropic(rng, np.zeros(3), sigmas, max(1, n - sum(sizes)))
    parts = [cloud]
    for k in sizes:
        parts.append(_anisotropic(rng, cloud[rng.integers(0, cloud.shape[0])], rng.uniform(0.5, 2.0, 3), k))
    return np.concatenate(parts), np.array([-2.0, -2.0, -1.0]), np.array([2.0, 2.0, 1.0])


_FAMILIES = {
    "clusters": _clusters_family,
    "near_far": _near_far_family,
    "twins": _twins_family,
    "rooms": _rooms_family,
    "ring": _ring_family,
    "blob": _blob_family,
}


def _family_points(family: str, seed: int, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    if family not in _FAMILIES:
        raise ValueError(f"unknown scene family {family!r}; expected one of {', '.join(HARD_FAMILIES)}")
    if not (np.isfinite(scale) and scale > 0):
        raise ValueError(f"scale must be > 0, got {scale}")
    return _FAMILIES[family](np.random.default_rng([seed, HARD_FAMILIES.index(family)]), scale)


def hard_scene(family: str, seed: int = 0, poses: int = 60, scale: float = 1.0) -> Scene:
    """One seeded instance of a hard scene family (see :data:`HARD_FAMILIES`) with ``poses`` random
    sensor positions for single-pose evaluation (``path`` (poses, 3), uniform in the family's sensor box).

    ``scale`` multiplies every landmark count (small instances for tests); the geometry stays the same.
    Families: ``clusters`` (mixed anisotropic clusters + 8 % clutter, random sensor positions),
    ``near_far`` (small dense distant cluster vs large diffuse near one), ``twins`` (two near-equal
    clusters far apart), ``rooms`` (walls and floors of rooms along a corridor), ``ring`` (an annulus of
    landmarks around the sensor), ``blob`` (the sensor inside a dense Gaussian cloud with density lumps).
    """
    points, lo, hi = _family_points(family, seed, scale)
    rng = np.random.default_rng([seed, HARD_FAMILIES.index(family), 1])
    sensors = rng.uniform(lo, hi, (poses, 3))
    return Scene(points=points, weights=np.ones(points.shape[0]), path=sensors)


def hard_path(family: str, seed: int = 0, waypoints: int = 40, scale: float = 1.0) -> Scene:
    """The landmarks of ``hard_scene(family, seed, scale=scale)`` with a smooth path through the family's
    sensor box (``path`` (waypoints, 3), evenly spaced along its arc length): a seeded closed-form curve —
    a sine-perturbed diagonal (clusters, near_far, twins), the corridor then into a room (rooms), a loop
    around the centre (ring, blob)."""
    points, lo, hi = _family_points(family, seed, scale)
    if waypoints < 2:
        raise ValueError(f"waypoints must be ≥ 2, got {waypoints}")
    rng = np.random.default_rng([seed, HARD_FAMILIES.index(family), 2])
    mid, span = 0.5 * (lo + hi), 0.5 * (hi - lo)
    if family in ("ring", "blob"):
        rad = 0.8 * float(min(span[0], span[1]))
        knots = [mid + np.array([rad * np.cos(t), rad * np.sin(t), 0.0]) for t in np.linspace(0, 2 * np.pi, 65)]
    elif family == "rooms":
        y_room = rng.choice([-1.0, 1.0]) * 0.7 * span[1]
        x_door = rng.uniform(lo[0] + 0.3 * 2 * span[0], hi[0] - 0.2 * 2 * span[0])
        z = 1.2
        knots = [np.array([lo[0], 0.0, z]), np.array([x_door, 0.0, z]), np.array([x_door, y_room, z])]
    else:
        a, b = rng.uniform(-1, 1, 2)
        u = np.linspace(-1.0, 1.0, 65)
        knots = mid + span * np.column_stack([0.9 * u, 0.9 * u * a + 0.3 * np.sin(3 * u + b), 0.5 * np.sin(2 * u)])
    knots = np.asarray(knots, dtype=float)
    seg = np.linalg.norm(np.diff(knots, axis=0), axis=1)
    arc = np.concatenate([[0.0], np.cumsum(seg)])
    s = np.linspace(0.0, arc[-1], waypoints)
    path = np.column_stack([np.interp(s, arc, knots[:, k]) for k in range(3)])
    return Scene(points=points, weights=np.ones(points.shape[0]), path=path)
