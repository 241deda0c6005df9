"""Synthetic scenes for tests, benchmarks and the demo (deterministic given a seed)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np


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
