"""Scene families of ``pivotd bench gap``: deterministic per seed, different across seeds, routes in free space with
landmarks in range, map sizes for a cheap run, and files the daemon and sim_pose read back."""

from __future__ import annotations

import numpy as np
import pytest

from pivotd.errors import InputError
from pivotd.geometry import quat_to_matrix
from pivotd.maps.formats import load_landmarks
from pivotd.sim.routes import TimedRoute, load_route
from pivotd.sim.scene_families import FAMILIES, clearance, generate, in_range_counts, write_scene

SEEDS = (1, 2, 3, 4)


@pytest.mark.parametrize("family", FAMILIES)
def test_same_seed_same_scene_other_seed_other_scene(family):
    a, b, c = generate(family, 1), generate(family, 1), generate(family, 2)
    np.testing.assert_array_equal(a.landmarks, b.landmarks)
    np.testing.assert_array_equal(a.route, b.route)
    differs = a.route.shape != c.route.shape or not np.allclose(a.route, c.route)
    assert differs, "seed 2 gives the route of seed 1"
    if family != "fif":  # the FIF maps are files: seeds pick among them and move the route
        assert a.landmarks.shape != c.landmarks.shape or not np.allclose(a.landmarks, c.landmarks)


@pytest.mark.parametrize("family", FAMILIES)
@pytest.mark.parametrize("seed", SEEDS)
def test_route_in_free_space_with_landmarks_in_range_everywhere(family, seed):
    scene = generate(family, seed)
    assert clearance(scene) >= 0.3
    counts = in_range_counts(scene, 0.3, 10.0)
    assert counts.shape == (scene.route.shape[0],)
    assert counts.min() >= 100, f"a route point with {counts.min()} landmarks in 0.3-10 m"
    lo, hi = (900, 1100) if family == "fif" else (5_000, 60_000)
    assert lo <= scene.landmarks.shape[0] <= hi
    assert 32.0 <= scene.length <= 43.0  # 30-45 s at 0.8-1.2 m/s
    steps = np.linalg.norm(np.diff(scene.route, axis=0), axis=1)
    assert steps.max() <= 0.3  # rows close enough that the clearance check covers the route


def _heading(scene, i):
    d = scene.route[min(i + 1, len(scene.route) - 1)] - scene.route[max(i - 1, 0)]
    return d / np.linalg.norm(d)


@pytest.mark.parametrize("seed", SEEDS)
def test_turn_the_rich_wall_is_behind_after_the_turn(seed):
    """Over the last quarter of the route more landmarks in range lie outside a forward 30° cone than in it,
    and more behind (> 90° off the heading) than in that cone."""
    scene = generate("turn", seed)
    n = len(scene.route)
    ahead = behind = 0
    for i in range(3 * n // 4, n, 4):
        rel = scene.landmarks - scene.route[i]
        dist = np.linalg.norm(rel, axis=1)
        cos = rel @ _heading(scene, i) / np.maximum(dist, 1e-9)
        near = (dist > 0.3) & (dist < 10.0)
        ahead += int(np.sum(near & (cos > np.cos(np.radians(30)))))
        behind += int(np.sum(near & (cos < 0)))
    assert behind > 2 * ahead


@pytest.mark.parametrize("seed", SEEDS)
def test_aisles_the_rich_side_alternates(seed):
    """Along the first aisle the face with more landmarks (within 1.8 m of the route: the aisle's own faces, not
    the next aisle's behind a shelf) switches sides at least twice."""
    scene = generate("aisles", seed)
    y0 = scene.route[0, 1]
    rich_left = []
    for x in np.arange(0.5, scene.route[:, 0].max() - 2.0, 0.5):
        near = np.abs(scene.landmarks[:, 0] - x) < 0.5
        left = np.sum(near & (scene.landmarks[:, 1] > y0) & (scene.landmarks[:, 1] < y0 + 1.8))
        right = np.sum(near & (scene.landmarks[:, 1] < y0) & (scene.landmarks[:, 1] > y0 - 1.8))
        if max(left, right) > 3 * min(left, right) + 10:
            rich_left.append(left > right)
    assert np.count_nonzero(np.diff(rich_left)) >= 2


@pytest.mark.parametrize("seed", SEEDS)
def test_stop_turn_stops_and_turns_in_place_twice(seed):
    scene = generate("stop_turn", seed, speed=1.2)
    assert scene.timed and scene.quats is not None
    r = TimedRoute(scene.route, scene.quats, scene.stamps)
    assert 30.0 <= r.duration <= 45.0
    t = np.arange(0.0, r.duration, 0.05)
    poses = [r.at_time(x) for x in t]
    pos = np.array([p.position for p in poses])
    fwd = np.array([quat_to_matrix(p.quat)[:, 0] for p in poses])
    yaw = np.unwrap(np.arctan2(fwd[:, 1], fwd[:, 0]))
    still = np.all(np.abs(np.diff(pos, axis=0)) < 1e-12, axis=1)
    runs = np.flatnonzero(np.diff(np.concatenate([[0], still.astype(int), [0]])))
    spins = [abs(yaw[b] - yaw[a]) for a, b in zip(runs[::2], runs[1::2], strict=True)]
    assert len(spins) == 2
    np.testing.assert_allclose(spins, np.pi / 2, atol=1e-6)  # each stop turns by the corner's 90°
    speed = np.linalg.norm(np.diff(pos, axis=0), axis=1) / 0.05
    assert np.max(speed) == pytest.approx(1.2, rel=1e-6)
    # while driving the body faces along the route
    moving = ~still
    step = np.diff(pos, axis=0)[moving]
    np.testing.assert_allclose(np.einsum("ij,ij->i", step / np.linalg.norm(step, axis=1, keepdims=True),
                                         fwd[:-1][moving]), 1.0, atol=1e-6)


@pytest.mark.parametrize("family", ["turn", "stop_turn"])
def test_written_scene_reads_back(family, tmp_path):
    scene = generate(family, 2)
    map_path, spec = write_scene(scene, tmp_path)
    np.testing.assert_allclose(load_landmarks(map_path).points, scene.landmarks)
    data = load_route(spec)
    np.testing.assert_allclose(data.positions, scene.route, atol=1e-6)
    if scene.timed:
        np.testing.assert_allclose(data.stamps, scene.stamps, atol=1e-6)
        np.testing.assert_allclose(np.abs(np.sum(data.quats * scene.quats, axis=1)), 1.0, atol=1e-6)
    else:
        assert data.stamps is None and data.quats is None


def test_unknown_family_is_an_input_error():
    with pytest.raises(InputError, match="unknown scene family 'atrium'"):
        generate("atrium", 1)
