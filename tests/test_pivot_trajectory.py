"""Trajectory PIVOT: smoothness on competing clusters, warm start, anchor, retained sets, edge cases."""

import numpy as np
import pytest

from pivotd.geometry import angle_between, normalize
from pivotd.pivot.constraints import PanTiltConstraint
from pivotd.pivot.scenes import competing_clusters_path, hallway
from pivotd.pivot.trajectory import (
    TrajectoryOptions,
    optimize_trajectory,
    path_directions,
    spatial_order,
    trajectory_problem,
)
from pivotd.pivot.visibility import hard_count


def _steps_deg(C):
    return np.degrees(angle_between(C[1:], C[:-1]))


@pytest.fixture(scope="module")
def competing():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    free = optimize_trajectory(scene.points, scene.path, alpha, 0.0)
    smooth = optimize_trajectory(scene.points, scene.path, alpha, 0.6)
    return scene, free, smooth


def test_lambda_zero_jumps_between_competing_clusters(competing):
    _, free, _ = competing
    assert _steps_deg(free.directions).max() > 90.0


def test_lambda_smooths_the_jump_and_keeps_most_visibility(competing):
    _, free, smooth = competing
    steps = _steps_deg(smooth.directions)
    # a view that kept the left cluster centred would turn by up to atan(1/6) = 9.5° where the path passes
    # it (x = 12 m, 6 m aside, 1 m per waypoint); the step-limited polish may use the largest step elsewhere
    # too, but never exceeds it (measured 10.2°: the plan's own largest step depends on which 256 landmarks
    # per waypoint the ascent samples: 7.7° in the map's order, 10.2–12.1° along space-filling curves)
    assert steps.max() < 11.0
    assert np.median(steps) < 8.0  # measured 7.4°: the polish uses the largest step wherever Φ_hard gains
    # λ = 0 solves every waypoint with optimize_view (single-pose quality), and the default objective weights
    # landmarks by distance (eq. 15), which the polish follows rather than the count: measured 86.3 %
    assert smooth.visible.mean() >= 0.85 * free.visible.mean()


def test_result_is_consistent(competing):
    scene, _, smooth = competing
    alpha = np.radians(30)
    C = smooth.directions
    assert np.allclose(np.linalg.norm(C, axis=1), 1.0)
    assert np.allclose(np.einsum("nij,j->ni", smooth.rotations, [0, 0, 1]), C, atol=1e-12)
    for i in (0, 10, 25, 40):
        assert smooth.visible[i] == hard_count(C[i], normalize(scene.points - scene.path[i]), alpha)


def test_lambda_zero_matches_independent_waypoints(competing):
    scene, free, _ = competing
    alpha = np.radians(30)
    part = optimize_trajectory(scene.points, scene.path[10:14], alpha, 0.0)
    assert np.all(np.abs(part.visible - free.visible[10:14]) <= 0.03 * free.visible[10:14] + 2)


def test_warm_start_keeps_a_converged_plan_and_is_cheap(competing):
    scene, _, _ = competing
    alpha = np.radians(30)
    # converged for the smooth objective: without the hard-count polish, which leaves its optimum on purpose
    smooth = optimize_trajectory(scene.points, scene.path, alpha, 0.6,
                                 options=TrajectoryOptions.paper(step_polish_deg=0))
    again = optimize_trajectory(scene.points, scene.path, alpha, 0.6, init_directions=smooth.directions)
    assert np.degrees(angle_between(again.directions, smooth.directions)).max() < 3.0
    assert again.iterations <= TrajectoryOptions.paper().warm_iterations


def test_anchor_pulls_the_first_waypoint_toward_it():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    init = np.tile([0.0, 1.0, 0.0], (len(scene.path), 1))
    anchor = np.array([1.0, 0.0, 0.0])
    free = optimize_trajectory(scene.points, scene.path, alpha, 0.6, init_directions=init)
    pulled = optimize_trajectory(scene.points, scene.path, alpha, 0.6, init_directions=init, anchor=anchor)
    assert angle_between(pulled.directions[0], anchor) < angle_between(free.directions[0], anchor) - np.radians(1)


def test_retained_lists_equal_the_dense_path_when_everything_is_retained():
    scene = competing_clusters_path(length=10.0)
    alpha = np.radians(30)
    # in spatial order, as the dense path orders the whole map (its strided subsamples see the same landmarks)
    everything = spatial_order(scene.points, [np.arange(len(scene.points))] * len(scene.path))
    dense = optimize_trajectory(scene.points, scene.path, alpha, 0.6)
    ragged = optimize_trajectory(scene.points, scene.path, alpha, 0.6, retained=everything)
    assert np.degrees(angle_between(dense.directions, ragged.directions)).max() < 0.5
    assert np.all(np.abs(dense.visible - ragged.visible) <= 2)


def test_retained_subsets_restrict_what_counts():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    left_only = [np.arange(300)] * len(scene.path)  # the first 300 points are the left (+y) cluster
    r = optimize_trajectory(scene.points, scene.path, alpha, 0.0, retained=left_only)
    assert np.all(r.directions[:, 1] > 0)
    assert r.visible.max() <= 300


def test_constraint_is_never_violated():
    scene = competing_clusters_path()
    N = len(scene.path)
    yaw = np.linspace(0, 0.5, N)  # the base turns slowly left along the path
    c, s = np.cos(yaw), np.sin(yaw)
    world_from_base = np.zeros((N, 3, 3))
    world_from_base[:, 0, 0], world_from_base[:, 0, 1] = c, -s
    world_from_base[:, 1, 0], world_from_base[:, 1, 1] = s, c
    world_from_base[:, 2, 2] = 1
    con = PanTiltConstraint(np.transpose(world_from_base, (0, 2, 1)), -np.radians(60), np.radians(60),
                            -np.radians(20), np.radians(30))
    for lam in (0.0, 0.6):
        r = optimize_trajectory(scene.points, scene.path, np.radians(30), lam, constraint=con)
        assert con.reachable(r.directions).all()
        assert r.visible.sum() > 0
    warm = optimize_trajectory(scene.points, scene.path, np.radians(30), 0.6, constraint=con,
                               init_directions=np.tile([-1.0, 0, 0], (N, 1)))
    assert con.reachable(warm.directions).all()


def test_landmark_at_a_waypoint_is_ignored():
    scene = competing_clusters_path(length=10.0)
    pts = np.vstack([scene.points, scene.path[3]])
    r = optimize_trajectory(pts, scene.path, np.radians(30), 0.6)
    ref = optimize_trajectory(scene.points, scene.path, np.radians(30), 0.6)
    assert np.isfinite(r.directions).all()
    assert abs(int(r.visible[3]) - int(ref.visible[3])) <= 2


def test_landmark_at_a_waypoint_is_ignored_with_retained_lists():
    scene = competing_clusters_path(length=10.0)
    pts = np.vstack([scene.points, scene.path[3]])
    everything = [np.arange(len(pts))] * len(scene.path)
    r = optimize_trajectory(pts, scene.path, np.radians(30), 0.6, retained=everything)
    ref = optimize_trajectory(scene.points, scene.path, np.radians(30), 0.6)
    assert np.isfinite(r.directions).all()
    assert abs(int(r.visible[3]) - int(ref.visible[3])) <= 2
    assert r.visible.max() <= len(scene.points)


def test_zero_landmarks_and_a_single_waypoint():
    path = np.array([[0.0, 0, 0], [1, 0, 0], [2, 0, 0]])
    r = optimize_trajectory(np.zeros((0, 3)), path, 0.3, 0.6)
    assert np.allclose(r.directions, [1, 0, 0]) and r.visible.sum() == 0
    one = optimize_trajectory(np.array([[0.0, 5.0, 0.0]]), path[:1], np.radians(10), 0.6)
    assert one.visible[0] == 1 and one.directions[0, 1] > 0.98


def test_bad_input_raises_value_error():
    path = np.array([[0.0, 0, 0], [1, 0, 0]])
    pts = np.array([[0.0, 5.0, 0.0], [np.nan, 0, 0]])
    with pytest.raises(ValueError, match="points row 1"):
        optimize_trajectory(pts, path, 0.3, 0.6)
    with pytest.raises(ValueError, match="lambda"):
        optimize_trajectory(pts[:1], path, 0.3, -1.0)
    with pytest.raises(ValueError, match="waypoints"):
        optimize_trajectory(pts[:1], np.zeros((0, 3)), 0.3, 0.6)
    with pytest.raises(ValueError, match="init_directions"):
        optimize_trajectory(pts[:1], path, 0.3, 0.6, init_directions=np.zeros((3, 3)))


def test_path_directions_follow_the_path_and_survive_stalls():
    path = np.array([[0.0, 0, 0], [0, 0, 0], [1, 0, 0], [1, 1, 0], [1, 1, 0]])
    d = path_directions(path)
    assert np.allclose(np.linalg.norm(d, axis=1), 1)
    assert d[0, 0] > 0.99 and d[-1, 1] > 0.99


def test_distance_weights_prefer_near_landmarks():
    near = np.array([[0.0, 2.0, 0.0]]) + 0.05 * np.random.default_rng(0).normal(size=(40, 3))
    far = np.array([[0.0, -30.0, 0.0]]) + 0.5 * np.random.default_rng(1).normal(size=(60, 3))
    pts = np.vstack([near, far])
    path = np.zeros((1, 3))
    weighted = optimize_trajectory(pts, path, np.radians(10), 0.0)
    plain = optimize_trajectory(pts, path, np.radians(10), 0.0, options=TrajectoryOptions.paper(distance_weights=False))
    assert weighted.directions[0, 1] > 0.9  # 40 near features outweigh 60 far ones
    assert plain.directions[0, 1] < -0.9


def test_hallway_plan_is_smooth_and_sees_the_rich_wall():
    scene = hallway()
    r = optimize_trajectory(scene.points, scene.path, np.radians(30), 0.6)
    assert _steps_deg(r.directions).max() < 20.0
    assert r.visible.mean() > 100


def test_ragged_bearings_match_float64_including_close_pairs():
    from pivotd.pivot.pairs import gather_pairs, ragged_geometry

    rng = np.random.default_rng(2)
    path = np.column_stack([np.linspace(1000.0, 1010.0, 6), np.full(6, -500.0), np.ones(6)])  # far from the origin
    pts = np.vstack([path[2] + [0.003, 0.0, 0.0], path[0] + rng.normal(scale=8.0, size=(200, 3))])
    retained = [np.arange(len(pts))[: 50 + 20 * i] for i in range(len(path))]
    geom, norm = ragged_geometry(gather_pairs(pts, None, retained, len(path)), path, False)
    for i, r in enumerate(retained):
        ref = normalize(pts[r] - path[i])
        assert np.abs(geom.points[i, : r.size] - ref).max() < 2e-6
        assert not geom.valid[i, r.size :].any()
        assert norm[i] == r.size


def test_single_waypoint_without_anchor_has_single_pose_quality():
    # one waypoint, no anchor: the smoothness term has no pair, so λ changes nothing and the answer is the
    # single-pose optimum (optimize_view), not a trajectory ascent on a subsample
    from pivotd.pivot.scenes import hard_scene
    from pivotd.pivot.view import optimize_view

    sc = hard_scene("clusters", 1, poses=6, scale=0.3)
    alpha = np.radians(15)
    for t in sc.path:
        ref = optimize_view(normalize(sc.points - t), None, alpha)
        plan = optimize_trajectory(sc.points, t[None], alpha, 0.6,
                                   options=TrajectoryOptions.paper(distance_weights=False))
        # the same solver; only its strided candidate sample sees the landmarks in spatial order
        assert abs(int(plan.visible[0]) - ref.visible) <= 0.005 * ref.visible + 1
        anchored = optimize_trajectory(sc.points, t[None], alpha, 0.6, anchor=ref.direction,
                                       options=TrajectoryOptions.paper(distance_weights=False))
        assert anchored.visible[0] >= 0.9 * ref.visible  # with an anchor the smoothness term applies


def test_judge_weight_totals_are_the_per_waypoint_norms():
    sc = hallway(rich_side_points=600, poor_side_points=60, spacing=1.0)
    rng = np.random.default_rng(4)
    retained = [np.sort(rng.choice(sc.points.shape[0], int(k), replace=False)) for k in rng.integers(50, 400, 6)]
    problem = trajectory_problem(sc.points, sc.path[:6], np.radians(30), 0.6, weights=sc.weights, retained=retained)
    assert np.array_equal(problem.geom.row_totals, problem.norm)  # Σ_j s_ij of each waypoint, float64
    assert problem.geom.row_totals is problem.geom.row_totals  # computed once
    C = normalize(np.c_[np.ones(6), rng.normal(0, 0.3, (6, 2))])
    visible, obj = problem.judge(C)
    assert list(visible) == [hard_count(C[i], normalize(sc.points[r] - sc.path[i]), np.radians(30))
                             for i, r in enumerate(retained)]
    assert obj > 0
