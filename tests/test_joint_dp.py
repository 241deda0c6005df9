"""The joint-grid dynamic programme against exhaustive search on tiny grids, its limits and its determinism."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from pivotd.geometry import quat_to_matrix
from pivotd.gimbal.kinematics import Mount, base_from_world, joints_to_world_direction
from pivotd.pivot.joint_dp import JointGrid, best_joint_path, best_smooth_joint_path, cell_counts


def _pan_moves(grid: JointGrid) -> np.ndarray:
    """(P, P) pan move in cells between every pair (circular when continuous)."""
    i = np.arange(grid.shape[0])
    d = np.abs(i[:, None] - i[None, :])
    return np.minimum(d, grid.shape[0] - d) if grid.continuous_pan else d


def _exhaustive(scores, rp, rt, grid, allowed_first):
    """Best total over every feasible path (brute force)."""
    N, P, T = scores.shape
    pm = _pan_moves(grid)
    cells = [(i, j) for i in range(P) for j in range(T)]
    best, best_path = -np.inf, None
    for path in itertools.product(cells, repeat=N):
        if not allowed_first[path[0]]:
            continue
        ok = all(pm[path[k][0], path[k + 1][0]] <= rp[k] and abs(path[k][1] - path[k + 1][1]) <= rt[k]
                 for k in range(N - 1))
        if ok:
            total = sum(scores[k, c[0], c[1]] for k, c in enumerate(path))
            if total > best:
                best, best_path = total, path
    return best, np.array(best_path)


def _check_limits(path, rp, rt, grid):
    pm = _pan_moves(grid)
    for k in range(len(path) - 1):
        assert pm[path[k, 0], path[k + 1, 0]] <= rp[k]
        assert abs(path[k, 1] - path[k + 1, 1]) <= rt[k]


@pytest.mark.parametrize("wrap", [False, True])
@pytest.mark.parametrize("with_start", [False, True])
@pytest.mark.parametrize("seed", range(6))
def test_matches_exhaustive_search(seed, with_start, wrap):
    rng = np.random.default_rng(seed + 100 * with_start + 1000 * wrap)
    step = math.radians(10)
    if wrap:
        grid = JointGrid(-math.pi + 2 * math.pi * np.arange(5) / 5, np.radians([0.0, 10.0, 20.0]), continuous_pan=True)
    else:
        grid = JointGrid.inside(0.0, math.radians(30), 0.0, math.radians(20), step=step)
    P, T = grid.shape
    assert ((5, 3) if wrap else (4, 3)) == (P, T)
    N = 4
    scores = rng.normal(size=(N, P, T))
    max_dpan = rng.integers(0, 3, N - 1) * grid.pan_step + rng.uniform(0, 0.5, N - 1) * grid.pan_step
    max_dtilt = rng.integers(0, 2, N - 1) * grid.tilt_step + rng.uniform(0, 0.5, N - 1) * grid.tilt_step
    rp = [grid.pan_cells(v) for v in max_dpan]
    rt = [grid.tilt_cells(v) for v in max_dtilt]
    allowed = np.ones((P, T), bool)
    start = reach = None
    if with_start:
        start, reach = (float(grid.pans[1]), float(grid.tilts[2])), (grid.pan_step * 1.0, 0.0)
        allowed[:] = False
        allowed[[0, 1, 2], 2] = True
    res = best_joint_path(scores, max_dpan, max_dtilt, grid, start=start, start_reach=reach)
    best, best_path = _exhaustive(scores, rp, rt, grid, allowed)
    assert res.total == pytest.approx(best, abs=1e-12)
    assert sum(scores[k, i, j] for k, (i, j) in enumerate(res.cells)) == pytest.approx(res.total, abs=1e-12)
    np.testing.assert_array_equal(res.cells, best_path)  # random scores: the optimum is unique
    _check_limits(res.cells, rp, rt, grid)
    assert allowed[tuple(res.cells[0])]


def test_limits_respected_on_a_larger_grid():
    rng = np.random.default_rng(7)
    grid = JointGrid.inside(math.radians(-170), math.radians(170), math.radians(-30), math.radians(60))
    N = 40
    scores = rng.uniform(size=(N, *grid.shape))
    max_dpan = rng.uniform(0, math.radians(12), N - 1)
    max_dtilt = rng.uniform(0, math.radians(6), N - 1)
    res = best_joint_path(scores, max_dpan, max_dtilt, grid)
    rp = [grid.pan_cells(v) for v in max_dpan]
    rt = [grid.tilt_cells(v) for v in max_dtilt]
    _check_limits(res.cells, rp, rt, grid)
    joints = res.joints(grid)
    assert np.all(np.abs(np.diff(joints[:, 0])) <= max_dpan + 1e-9)
    assert np.all(np.abs(np.diff(joints[:, 1])) <= max_dtilt + 1e-9)
    # the unconstrained per-frame maximum bounds the optimum from above; the path beats standing still anywhere
    assert res.total <= scores.reshape(N, -1).max(axis=1).sum() + 1e-9
    assert res.total >= scores.sum(axis=0).max() - 1e-9


def test_deterministic_and_ties_prefer_no_move():
    grid = JointGrid.inside(0.0, math.radians(20), 0.0, math.radians(10), step=math.radians(5))
    flat = np.ones((6, *grid.shape))
    res = best_joint_path(flat, math.radians(10), math.radians(10), grid)
    assert np.all(res.cells == res.cells[0])  # equal scores everywhere: never move
    np.testing.assert_array_equal(res.cells[0], [0, 0])  # ... at the lowest index
    rng = np.random.default_rng(3)
    scores = rng.integers(0, 3, size=(12, *grid.shape)).astype(float)  # many ties
    a = best_joint_path(scores, math.radians(5), math.radians(5), grid)
    b = best_joint_path(scores.copy(), math.radians(5), math.radians(5), grid)
    np.testing.assert_array_equal(a.cells, b.cells)
    assert a.total == b.total


def test_start_pose_and_wrap_across_the_seam():
    grid = JointGrid.inside(-math.pi, math.pi, 0.0, 0.0, step=math.radians(30), continuous_pan=True)
    P, T = grid.shape
    assert (P, T) == (12, 1)
    assert grid.pan_step == pytest.approx(math.radians(30))
    scores = np.zeros((3, P, T))
    scores[2, P - 1, 0] = 10.0  # one cell left of the first pan, across the seam
    res = best_joint_path(scores, math.radians(30), 0.0, grid, start=(float(grid.pans[1]), 0.0))
    np.testing.assert_array_equal(res.cells[:, 0], [1, 0, P - 1])
    assert res.total == 10.0
    with pytest.raises(ValueError, match="start_reach"):
        best_joint_path(scores, 0.1, 0.1, grid, start_reach=(0.1, 0.1))


def test_forbidden_cells_and_bad_input():
    grid = JointGrid.inside(0.0, 1.0, 0.0, 1.0, step=0.5)
    scores = np.zeros((2, *grid.shape))
    scores[1, :, :] = -np.inf
    with pytest.raises(ValueError, match="no feasible"):
        best_joint_path(scores, 1.0, 1.0, grid)
    with pytest.raises(ValueError, match="shape"):
        best_joint_path(np.zeros((2, 2, 2)), 1.0, 1.0, grid)
    with pytest.raises(ValueError, match="max_dpan"):
        best_joint_path(np.zeros((3, *grid.shape)), [-1.0, 0.0], 1.0, grid)


def test_grid_spacing_and_ends():
    g = JointGrid.inside(math.radians(-170), math.radians(170), math.radians(-90), math.radians(90))
    assert g.pans[0] == pytest.approx(math.radians(-170)) and g.pans[-1] == pytest.approx(math.radians(170))
    assert g.tilts[0] == pytest.approx(math.radians(-90)) and g.tilts[-1] == pytest.approx(math.radians(90))
    assert g.pan_step <= math.radians(2) + 1e-12 and g.tilt_step <= math.radians(2) + 1e-12
    assert g.shape == (171, 91)
    assert g.pan_cells(math.radians(4)) == 2 and g.pan_cells(math.radians(3.99)) == 1
    c = JointGrid.inside(0.0, 0.0, 0.0, 0.0, step=math.radians(7), continuous_pan=True)
    assert c.shape == (52, 1) and c.pans[-1] < 2 * math.pi - 1e-6
    np.testing.assert_allclose(np.diff(c.pans), 2 * math.pi / 52)


def test_directions_follow_the_kinematics():
    rng = np.random.default_rng(5)
    q = rng.normal(size=4)
    q /= np.linalg.norm(q)
    mount = Mount.from_xyz_rpy(np.zeros(3), np.array([0.1, -0.2, 0.3]))
    grid = JointGrid.inside(-1.0, 1.0, -0.5, 0.5, step=0.25)
    dirs = grid.directions(base_from_world(q, mount))
    T = grid.shape[1]
    for i, j in [(0, 0), (3, 2), (8, 4)]:
        expect = joints_to_world_direction(grid.pans[i], grid.tilts[j], q, mount)
        np.testing.assert_allclose(dirs[i * T + j], expect, atol=1e-12)
    assert quat_to_matrix(q).shape == (3, 3)


GRIDS = {  # pan min, pan max, tilt min, tilt max, step [deg], continuous pan
    "bounded": (-170, 170, -45, 60, 7, False),
    "poles": (-90, 120, -90, 90, 5, False),
    "over_the_top": (-30, 30, -120, 135, 6, False),
    "multi_turn": (-400, 380, -20, 20, 9, False),
    "continuous": (-180, 180, -60, 80, 8, True),
    "single_pan": (17, 17, -60, 80, 8, False),
}


@pytest.mark.parametrize("name", sorted(GRIDS))
@pytest.mark.parametrize("alpha_deg", [3.0, 30.0, 100.0])
def test_cell_counts_match_a_direct_cone_test(name, alpha_deg):
    rng = np.random.default_rng(len(name) + int(alpha_deg))
    *limits, step, continuous = GRIDS[name]
    grid = JointGrid.inside(*np.radians(limits), step=math.radians(step), continuous_pan=continuous)
    q = rng.normal(size=4)
    R = base_from_world(q / np.linalg.norm(q), Mount.from_xyz_rpy(np.zeros(3), np.array([0.2, 0.1, -0.4])))
    rel = rng.normal(size=(400, 3)) * 5
    rel[:3] = np.array([[0.0, 0.0, 1.0], [0.0, 0.0, -2.0], [-1.0, 1e-3, 0.0]]) @ R  # base poles, the ±π seam
    w = rng.uniform(0.5, 2.0, 400)
    alpha = math.radians(alpha_deg)
    counts = cell_counts(rel, None, grid, R, alpha)
    weighted = cell_counts(rel, w, grid, R, alpha)
    u = rel / np.linalg.norm(rel, axis=1, keepdims=True)
    cos = grid.directions(R) @ u.T
    inside = cos >= math.cos(alpha)
    sure = np.abs(cos - math.cos(alpha)) > 1e-7  # away from the cone's edge both tests must agree exactly
    got_in = counts.ravel()
    assert got_in.sum() > 0
    lo = (inside & sure).sum(axis=1)
    hi = (inside | ~sure).sum(axis=1)
    assert np.all((got_in >= lo) & (got_in <= hi))
    assert np.abs(weighted.ravel() - (inside * w).sum(axis=1)).max() <= 2.0 * (~sure).sum(axis=1).max() + 1e-9
    if (~sure).sum() == 0:
        np.testing.assert_array_equal(got_in, inside.sum(axis=1))


def test_cell_counts_ignore_a_landmark_at_the_camera():
    grid = JointGrid.inside(-1.0, 1.0, -0.5, 0.5, step=0.25)
    assert cell_counts(np.zeros((1, 3)), None, grid, np.eye(3), 0.3).sum() == 0
    assert cell_counts(np.zeros((0, 3)), None, grid, np.eye(3), 0.3).shape == grid.shape


def _pan_move(grid: JointGrid, a: int, b: int) -> int:
    """Signed pan move b − a [cells] (the shorter way round when continuous)."""
    P = grid.shape[0]
    return (b - a + P // 2) % P - P // 2 if grid.continuous_pan else b - a


def _smooth_exhaustive(scores, vp, vt, ap, at, grid, centre, radius):
    """Best total over every path from centre[0] within the move, change-of-move (from rest) and corridor limits
    (brute force; −inf when none)."""
    N, P, T = scores.shape
    cells = [(i, j) for i in range(P) for j in range(T)]
    best = -np.inf
    for tail in itertools.product(cells, repeat=N - 1):
        path = (tuple(centre[0]), *tail)
        prev, ok = (0, 0), True
        for k in range(N):
            if abs(_pan_move(grid, centre[k][0], path[k][0])) > radius[0] or abs(path[k][1] - centre[k][1]) > radius[1]:
                ok = False
                break
            if k < N - 1:
                m = (_pan_move(grid, path[k][0], path[k + 1][0]), path[k + 1][1] - path[k][1])
                if (abs(m[0]) > vp[k] or abs(m[1]) > vt[k] or abs(m[0] - prev[0]) > ap[k]
                        or abs(m[1] - prev[1]) > at[k]):
                    ok = False
                    break
                prev = m
        if ok:
            best = max(best, sum(scores[k, c[0], c[1]] for k, c in enumerate(path)))
    return best


@pytest.mark.parametrize("wrap", [False, True])
@pytest.mark.parametrize("seed", range(8))
def test_smooth_path_matches_exhaustive_search(seed, wrap):
    rng = np.random.default_rng(seed + 50 * wrap)
    if wrap:
        grid = JointGrid(-math.pi + 2 * math.pi * np.arange(6) / 6, np.radians([0.0, 10.0, 20.0]), continuous_pan=True)
    else:
        grid = JointGrid.inside(0.0, math.radians(40), 0.0, math.radians(20), step=math.radians(10))
    P, T = grid.shape
    N = 4
    scores = rng.normal(size=(N, P, T))
    vp, vt = rng.integers(1, 3, N - 1), rng.integers(0, 2, N - 1)
    ap, at = rng.integers(0, 3, N - 1), rng.integers(0, 2, N - 1)
    # a centre walking at most one cell per step and a corridor of 1–2 cells (every third case: the whole grid)
    walk = np.cumsum(np.vstack([[rng.integers(0, P), rng.integers(0, T)], rng.integers(-1, 2, (N - 1, 2))]), axis=0)
    centre = np.column_stack([np.remainder(walk[:, 0], P) if wrap else np.clip(walk[:, 0], 0, P - 1),
                              np.clip(walk[:, 1], 0, T - 1)])
    radius = (P, T) if seed % 3 == 0 else (int(rng.integers(1, 3)), int(rng.integers(0, 2)))
    slack = rng.uniform(0, 0.5, (4, N - 1))  # limits between whole cells round down
    args = ((vp + slack[0]) * grid.pan_step, (vt + slack[1]) * grid.tilt_step, (ap + slack[2]) * grid.pan_step,
            (at + slack[3]) * grid.tilt_step)
    best = _smooth_exhaustive(scores, vp, vt, ap, at, grid, centre, radius)
    if not np.isfinite(best):
        with pytest.raises(ValueError, match="no feasible"):
            best_smooth_joint_path(scores, *args, grid, centre, radius)
        return
    res = best_smooth_joint_path(scores, *args, grid, centre, radius)
    assert res.total == pytest.approx(best, abs=1e-12)
    c = res.cells
    assert sum(scores[k, i, j] for k, (i, j) in enumerate(c)) == pytest.approx(res.total, abs=1e-12)
    np.testing.assert_array_equal(c[0], centre[0])
    moves = np.array([[_pan_move(grid, c[k, 0], c[k + 1, 0]), c[k + 1, 1] - c[k, 1]] for k in range(N - 1)])
    assert np.all(np.abs(moves[:, 0]) <= vp) and np.all(np.abs(moves[:, 1]) <= vt)
    change = np.diff(np.vstack([[0, 0], moves]), axis=0)
    assert np.all(np.abs(change[:, 0]) <= ap) and np.all(np.abs(change[:, 1]) <= at)


def test_counted_cases_of_the_smooth_search_are_feasible():
    """The exhaustive comparison above is not vacuous: most of its cases have a feasible path."""
    feasible = 0
    for seed in range(8):
        rng = np.random.default_rng(seed)
        grid = JointGrid.inside(0.0, math.radians(40), 0.0, math.radians(20), step=math.radians(10))
        P, T = grid.shape
        scores = rng.normal(size=(4, P, T))
        centre = np.tile([2, 1], (4, 1))
        feasible += np.isfinite(_smooth_exhaustive(scores, [1] * 3, [1] * 3, [1] * 3, [1] * 3, grid, centre, (1, 1)))
    assert feasible == 8


def test_smooth_path_without_a_change_limit_is_the_velocity_optimum():
    rng = np.random.default_rng(11)
    grid = JointGrid.inside(math.radians(-60), math.radians(60), math.radians(-20), math.radians(20),
                            step=math.radians(5))
    P, T = grid.shape
    N = 25
    scores = rng.uniform(size=(N, P, T))
    start = (float(grid.pans[12]), float(grid.tilts[4]))
    ref = best_joint_path(scores, math.radians(10), math.radians(5), grid, start=start)
    centre = np.tile(grid.nearest(*start), (N, 1))
    free = best_smooth_joint_path(scores, math.radians(10), math.radians(5), np.inf, np.inf, grid, centre, (P, T))
    assert free.total == pytest.approx(ref.total, abs=1e-9)
    # a change limit of one cell per step costs score and is kept
    smooth = best_smooth_joint_path(scores, math.radians(10), math.radians(5), math.radians(5), math.radians(5),
                                    grid, centre, (P, T))
    assert smooth.total < ref.total
    moves = np.diff(smooth.cells, axis=0)
    assert np.abs(np.diff(np.vstack([[0, 0], moves]), axis=0)).max() <= 1
    assert np.abs(moves[:, 0]).max() <= 2 and np.abs(moves[:, 1]).max() <= 1


def test_smooth_path_bad_input():
    grid = JointGrid.inside(0.0, 1.0, 0.0, 1.0, step=0.5)
    scores = np.zeros((3, *grid.shape))
    with pytest.raises(ValueError, match="centre"):
        best_smooth_joint_path(scores, 1.0, 1.0, 1.0, 1.0, grid, np.zeros((2, 2), int), (1, 1))
    with pytest.raises(ValueError, match="centre"):
        best_smooth_joint_path(scores, 1.0, 1.0, 1.0, 1.0, grid, np.full((3, 2), 5), (1, 1))
    with pytest.raises(ValueError, match="radius"):
        best_smooth_joint_path(scores, 1.0, 1.0, 1.0, 1.0, grid, np.zeros((3, 2), int), (-1, 0))
    with pytest.raises(ValueError, match="max_ddpan"):
        best_smooth_joint_path(scores, 1.0, 1.0, -1.0, 1.0, grid, np.zeros((3, 2), int), (1, 1))
