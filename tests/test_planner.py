"""Receding-horizon planner: path progress, resampling, warm start, anchoring, reachability."""

import math

import numpy as np
import pytest

from pivotd.daemon.planner import Plan, PlannerSettings, RecedingHorizonPlanner
from pivotd.geometry import angle_between, direction_to_pan_tilt, normalize, pan_tilt_to_direction, slerp
from pivotd.gimbal.kinematics import JointLimits, Mount, base_from_world, world_directions_to_joints
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import MapStore
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import Polyline

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])


def s_path():
    """Out along +x, back along -x one metre to the side: the two legs pass close to each other."""
    out = np.column_stack([np.linspace(0, 10, 21), np.zeros(21), np.zeros(21)])
    turn = np.array([[10.5, 0.5, 0.0]])
    back = np.column_stack([np.linspace(10, 0, 21), np.ones(21), np.zeros(21)])
    return np.vstack([out, turn, back])


def test_progress_is_monotone_and_cannot_jump_to_a_nearby_leg():
    tr = Polyline(s_path())
    s, d = tr.locate(np.array([2.0, 0.1, 0]))
    assert s == pytest.approx(2.0, abs=1e-9) and d == pytest.approx(0.1)
    # Standing between the legs, nearer the return leg: with progress known, we stay on the first leg.
    s2, _ = tr.locate(np.array([2.2, 0.7, 0]), previous=s)
    assert s2 == pytest.approx(2.2, abs=1e-9)
    # Without history the nearest point wins (the return leg).
    s_free, _ = tr.locate(np.array([2.2, 0.7, 0]))
    assert s_free > 15
    # Walking backwards never reduces progress.
    s3, _ = tr.locate(np.array([1.0, 0.0, 0]), previous=s2)
    assert s3 == pytest.approx(s2)


def test_progress_is_robust_to_the_robot_being_off_the_path():
    tr = Polyline(s_path())
    s, d = tr.locate(np.array([4.0, -3.0, 0.0]), previous=3.5)
    assert s == pytest.approx(4.0, abs=1e-9) and d == pytest.approx(3.0)


def test_sampling_positions_and_heading_attitude():
    tr = Polyline(s_path())
    pos, q = tr.sample(np.array([0.0, 5.0, 25.0, 1e9]))
    np.testing.assert_allclose(pos[:2], [[0, 0, 0], [5, 0, 0]], atol=1e-12)
    np.testing.assert_allclose(pos[3], s_path()[-1])
    # Heading along +x on the first leg, along -x on the way back (yaw = pi).
    np.testing.assert_allclose(q[1], IDENTITY, atol=1e-12)
    assert abs(abs(q[2, 2]) - 1.0) < 1e-9


def test_path_quaternions_are_used_when_informative():
    pos = np.column_stack([np.arange(5.0), np.zeros(5), np.zeros(5)])
    yaw = np.linspace(0, np.pi / 2, 5)
    quats = np.column_stack([np.zeros(5), np.zeros(5), np.sin(yaw / 2), np.cos(yaw / 2)])
    _, q = Polyline(pos, quats).sample(np.array([2.0]))
    np.testing.assert_allclose(q[0], quats[2], atol=1e-12)
    # All-identical orientations (a planner that leaves them unset) fall back to the heading.
    _, q2 = Polyline(pos, np.tile(quats[4], (5, 1)), ignore_constant_quats=True).sample(np.array([2.0]))
    np.testing.assert_allclose(q2[0], IDENTITY, atol=1e-12)


def test_slerp_and_plan_interpolation():
    a, b = np.array([1.0, 0, 0]), np.array([0.0, 1.0, 0])
    mid = slerp(a, b, 0.5)
    np.testing.assert_allclose(mid, normalize(np.array([1.0, 1.0, 0])), atol=1e-12)
    plan = Plan(created=0.0, positions=np.array([[0.0, 0, 0], [1.0, 0, 0]]), directions=np.stack([a, b]),
                body_quats=np.tile(IDENTITY, (2, 1)), visible=np.zeros(2, int), s=np.array([3.0, 4.0]),
                map_version=0, path_version=0, solve_s=0.0)
    np.testing.assert_allclose(plan.direction_at_s(3.5), mid, atol=1e-12)
    np.testing.assert_allclose(plan.direction_at_s(-10), a)
    assert plan.locate(np.array([0.25, 0.3, 0]))[0] == pytest.approx(3.25)


def _plan_through(positions, s):
    n = len(s)
    return Plan(created=0.0, positions=np.asarray(positions, float), directions=np.tile([1.0, 0, 0], (n, 1)),
                body_quats=np.tile(IDENTITY, (n, 1)), visible=np.zeros(n, int), s=np.asarray(s, float),
                map_version=0, path_version=0, solve_s=0.0)


def test_plan_locate_keeps_the_index_mapping_at_repeated_positions():
    # The camera stood still between waypoints 1 and 2 (e.g. the horizon clamped at the path's end, or
    # the mount offset cancelling the motion): the zero-length segment keeps its own arc interval.
    plan = _plan_through([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [1.0, 1.0, 0]], [3.0, 4.0, 4.5, 5.5])
    assert plan.locate(np.array([1.2, 0.6, 0.0]))[0] == pytest.approx(5.1)  # on the last segment
    assert plan.locate(np.array([0.5, -0.2, 0.0]))[0] == pytest.approx(3.5)  # on the first
    assert plan.locate(np.array([1.5, -0.5, 0.0]))[0] == pytest.approx(4.0)  # nearest to the repeated vertex
    clamped = _plan_through([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0]], [0.0, 1.0, 1.0, 1.0])
    assert clamped.locate(np.array([3.0, 0.0, 0.0]))[0] == pytest.approx(1.0)
    assert clamped.locate(np.array([0.25, 1.0, 0.0]))[0] == pytest.approx(0.25)


def _brute_force_locate(positions, s, point):
    """Closest point by bounded 1-D minimisation on every segment (no shared code with the planner)."""
    from scipy.optimize import minimize_scalar

    if len(positions) == 1:
        return s[0], float(np.linalg.norm(point - positions[0]))
    best = (math.inf, 0.0)
    for i in range(len(positions) - 1):
        a, b = positions[i], positions[i + 1]
        res = minimize_scalar(lambda u, a=a, b=b: float(np.sum((a + u * (b - a) - point) ** 2)), bounds=(0.0, 1.0),
                              method="bounded", options={"xatol": 1e-12})
        for u in (0.0, 1.0, float(res.x)):
            d = float(np.linalg.norm(a + u * (b - a) - point))
            if d < best[0]:
                best = (d, s[i] + u * (s[i + 1] - s[i]))
    return best[1], best[0]


def test_plan_and_path_locate_match_a_brute_force_projection():
    rng = np.random.default_rng(7)
    for _ in range(60):
        n = int(rng.integers(1, 9))
        positions = rng.normal(size=(n, 3)) * 2.0
        if n > 2:
            k = int(rng.integers(1, n))
            positions[k] = positions[k - 1]  # one repeated point
        s = 10.0 + np.cumsum(rng.uniform(0.1, 1.0, n))
        point = rng.normal(size=3) * 3.0
        s_ref, d_ref = _brute_force_locate(positions, s, point)
        # Generic random data: the nearest point is unique, so the arc coordinates agree, not only distances.
        assert _plan_through(positions, s).locate(point)[0] == pytest.approx(s_ref, abs=1e-6)
        path = Polyline(positions)
        arc_ref, dist_ref = _brute_force_locate(path.positions, path.arc, point)
        arc, dist = path.locate(point)
        assert dist == pytest.approx(dist_ref, abs=1e-9) and dist == pytest.approx(d_ref, abs=1e-9)
        assert arc == pytest.approx(arc_ref, abs=1e-6)


def _planner(limits=None, horizon=20, lam=0.6):
    limits = limits or JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60), False)
    settings = PlannerSettings(fov=math.radians(60), lam=lam, spacing=0.5, horizon=horizon,
                               retained_filter=RetainedFilter(min_range=0.3, max_range=10.0))
    return RecedingHorizonPlanner(settings, Mount(), limits)


@pytest.fixture(scope="module")
def scene_store():
    sc = hallway()
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    return sc, store


def test_plan_beats_forward_looking_and_respects_joint_limits(scene_store):
    sc, store = scene_store
    pl = _planner()
    pl.set_path(sc.path, None, 1)
    plan = pl.replan(store.snapshot(), sc.path[0], IDENTITY, None)
    assert plan.directions.shape == (20, 3)
    np.testing.assert_allclose(plan.s, 0.5 * np.arange(20), atol=1e-9)
    # Reachable: every direction maps to joint angles inside the limits for its predicted attitude.
    pan, _tilt, clamped = world_directions_to_joints(plan.directions, plan.body_quats, Mount(), pl.limits)
    assert not clamped.any()
    # The rich wall is on the left: the plan looks left, and sees more than looking ahead.
    assert np.mean(pan) > math.radians(20)
    snap = store.snapshot()
    fwd = []
    for i in range(plan.positions.shape[0]):
        tangent = normalize(np.diff(sc.path, axis=0)[min(i, sc.path.shape[0] - 2)])
        rel = normalize(snap.points - plan.positions[i])
        dist = np.linalg.norm(snap.points - plan.positions[i], axis=1)
        ok = (dist >= 0.3) & (dist <= 10)
        fwd.append(int(((rel @ tangent) >= math.cos(math.radians(30)))[ok].sum()))
    assert plan.visible.mean() > 1.3 * np.mean(fwd)


def test_tight_limits_are_built_into_the_optimisation(scene_store):
    sc, store = scene_store
    tight = JointLimits(math.radians(-20), math.radians(20), math.radians(-10), math.radians(10), False)
    pl = _planner(limits=tight)
    pl.set_path(sc.path, None, 1)
    plan = pl.replan(store.snapshot(), sc.path[0], IDENTITY, None)
    pan, _tilt, clamped = world_directions_to_joints(plan.directions, plan.body_quats, Mount(), tight)
    assert not clamped.any()
    assert np.all(pan <= math.radians(20) + 1e-6) and np.all(pan >= math.radians(-20) - 1e-6)
    # The best reachable view is pressed against the left pan limit, not somewhere arbitrary.
    assert np.median(pan) > math.radians(15)


def test_replans_are_warm_started_and_anchored(scene_store):
    sc, store = scene_store
    pl = _planner()
    pl.set_path(sc.path, None, 1)
    snap = store.snapshot()
    first = pl.replan(snap, sc.path[0], IDENTITY, None)
    commanded = first.directions[0]
    worst = 0.0
    for k in range(1, 30):
        pos = sc.path[0] + (sc.path[1] - sc.path[0]) * (k / 10)  # 5 cm per replan
        plan = pl.replan(snap, pos, IDENTITY, commanded)
        worst = max(worst, float(np.degrees(angle_between(plan.direction_at_s(plan.s[0]), commanded))))
        commanded = plan.directions[0]
    assert worst < 3.0, f"a replan moved the current direction by {worst:.1f} degrees"
    assert pl.progress == pytest.approx(0.5 * 29 / 10 * 1.0, abs=0.05)


def test_without_a_path_the_current_pose_is_optimised(scene_store):
    sc, store = scene_store
    pl = _planner()
    plan = pl.replan(store.snapshot(), sc.path[3], IDENTITY, None)
    assert plan.directions.shape == (1, 3) and plan.visible[0] > 50


def test_empty_map_gives_a_plan_without_error():
    pl = _planner()
    plan = pl.replan(MapStore().snapshot(), np.zeros(3), IDENTITY, np.array([1.0, 0, 0]))
    assert plan.directions.shape == (1, 3) and plan.visible[0] == 0
    assert np.isfinite(plan.directions).all()


def test_horizon_waypoints_sit_on_a_fixed_grid_and_the_cache_follows_the_map(scene_store):
    sc, _ = scene_store
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    pl = _planner()
    pl.set_path(sc.path, None, 1)
    p1 = pl.replan(store.snapshot(), sc.path[0] + np.array([0.12, 0, 0]), IDENTITY, None)
    p2 = pl.replan(store.snapshot(), sc.path[0] + np.array([0.31, 0, 0]), IDENTITY, p1.directions[0])
    assert p1.s[0] == pytest.approx(0.12, abs=1e-6) and p2.s[0] == pytest.approx(0.31, abs=1e-6)
    np.testing.assert_allclose(p1.s[1:], 0.5 * np.arange(1, p1.s.shape[0]))
    np.testing.assert_allclose(p2.s[1:], p1.s[1:])  # same grid: cached retained sets, exact warm start
    np.testing.assert_allclose(p2.positions[1:], p1.positions[1:])
    # A map update invalidates the cache: with the rich wall removed the plan sees far fewer landmarks.
    store.set_layer("base", LandmarkCloud(points=sc.points[3000:], weights=sc.weights[3000:]))
    p3 = pl.replan(store.snapshot(), sc.path[0] + np.array([0.35, 0, 0]), IDENTITY, p2.directions[0])
    assert p3.landmarks < 0.2 * p2.landmarks


def test_late_replans_halve_the_horizon_and_cap_and_fast_ones_restore_them(scene_store):
    from dataclasses import replace

    sc, store = scene_store
    pl = _planner()
    pl.settings = replace(pl.settings, max_landmarks_per_waypoint=400, replan_budget=1e-9)  # every replan is late
    pl.set_path(sc.path, None, 1)
    snap = store.snapshot()
    shapes = []
    for _ in range(5):
        plan = pl.replan(snap, sc.path[0], IDENTITY, None)
        shapes.append((plan.degrade, plan.directions.shape[0], plan.landmarks))
    assert [d for d, _, _ in shapes] == [0, 1, 2, 3, 3]  # at most PlannerSettings.MAX_DEGRADE halvings
    assert [n for _, n, _ in shapes] == [20, 10, 5, 2, 2]
    assert shapes[3][2] <= 2 * 50  # two waypoints of at most 400 / 8 landmarks
    pl.settings = replace(pl.settings, replan_budget=1e9)  # every replan fits: one halving undone per replan
    assert [pl.replan(snap, sc.path[0], IDENTITY, None).degrade for _ in range(4)] == [3, 2, 1, 0]
    assert pl.replan(snap, sc.path[0], IDENTITY, None).directions.shape[0] == 20


def _sideways(path: np.ndarray, offset: float) -> np.ndarray:
    """``path`` (N, 3) moved ``offset`` [m] to the left of its direction of travel at every vertex."""
    t = np.gradient(path[:, :2], axis=0)
    t /= np.linalg.norm(t, axis=1, keepdims=True)
    out = path.copy()
    out[:, :2] += offset * np.column_stack([-t[:, 1], t[:, 0]])
    return out


def test_a_path_beyond_the_offset_is_left_for_the_pose_and_resumed_when_back(scene_store):
    from pivotd.daemon.planner import PathMode
    from pivotd.gimbal.kinematics import camera_position

    sc, store = scene_store
    snap = store.snapshot()
    robot = sc.path[6]
    alone = _planner().replan(snap, robot, IDENTITY, None)  # no path: the pose alone
    assert alone.path_mode is PathMode.NO_PATH and alone.path_offset is None
    pl = _planner()
    pl.set_path(_sideways(sc.path, 5.0), None, 1)  # the route's path, 5 m to the side (max_path_offset 3 m)
    plan = pl.replan(snap, robot, IDENTITY, None)
    assert plan.path_mode is PathMode.OFF_PATH and plan.path_offset == pytest.approx(5.0, abs=0.3)
    assert plan.directions.shape == (1, 3)  # for where the robot is, not for waypoints it is not at
    np.testing.assert_allclose(plan.positions[0], camera_position(robot, IDENTITY, Mount()), atol=1e-9)
    assert plan.visible[0] >= 0.8 * alone.visible[0] and plan.visible[0] > 50
    # the true path: the horizon along it again
    pl.set_path(sc.path, None, 2)
    on = pl.replan(snap, robot, IDENTITY, plan.directions[0])
    assert on.path_mode is PathMode.ON_PATH and on.path_offset < 1e-6 and on.directions.shape == (20, 3)
    # the robot leaves the path sideways and comes back to it further along: it resumes there
    progress = pl.progress
    for k in range(7, 16):
        off = pl.replan(snap, _sideways(sc.path, 5.0)[k], IDENTITY, None)
        assert off.path_mode is PathMode.OFF_PATH and off.directions.shape == (1, 3)
        assert pl.progress == progress  # frozen while off the path
    back = pl.replan(snap, sc.path[16], IDENTITY, None)
    arc16 = float(np.sum(np.linalg.norm(np.diff(sc.path[:17], axis=0), axis=1)))
    assert back.path_mode is PathMode.ON_PATH and back.s[0] == pytest.approx(arc16, abs=1e-6)


def test_a_dense_cluster_outweighs_a_sparse_one_that_the_cell_cap_reads_more_of():
    """Left: 3000 landmarks packed in one 1 m cell; right: 600 spread over six cells (100 each). With a cell cap of
    256 the queries read 256 on the left and all 600 on the right; the plan still looks at the left, where five
    times as many landmarks are."""
    rng = np.random.default_rng(5)
    left = rng.uniform([0.05, 3.05, 0.05], [0.95, 3.95, 0.95], (3000, 3))
    right = np.concatenate([rng.uniform([x, -4.0, 0.0], [x + 1.0, -3.0, 1.0], (100, 3)) for x in range(-3, 3)])
    store = MapStore(cell_cap=256)
    store.set_layer("base", LandmarkCloud(np.concatenate([left, right]).astype(np.float32),
                                          np.ones(3600, np.float32)))
    snap = store.snapshot()
    assert snap.queried_landmarks == 256 + 600
    pl = _planner(horizon=1)
    plan = pl.replan(snap, np.array([0.5, 0.0, 0.5]), IDENTITY, None)
    assert plan.directions[0, 1] > 0.5, plan.directions[0]  # towards +y: the dense cluster


def test_between_far_apart_waypoints_a_plan_follows_the_gimbal_sweep_not_the_great_circle():
    """Waypoints 200° apart in pan at the same tilt (a view handed from a cluster behind to one ahead): between
    them the plan's direction is the joints' interpolation at that tilt, not the great circle, which dives 30° below
    it (towards the floor, to a −45° tilt limit); the body turning between the waypoints is carried along."""
    pans, tilts = np.radians([-140.0, 60.0]), np.radians([-15.0, -15.0])
    yaw = math.radians(10.0)
    quats = np.array([IDENTITY, [0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)]])
    mount = Mount()
    frames = base_from_world(quats, mount)
    dirs = np.einsum("nji,nj->ni", frames, pan_tilt_to_direction(pans, tilts))
    common = dict(created=0.0, positions=np.array([[0.0, 0, 0], [1.0, 0, 0]]), directions=dirs, body_quats=quats,
                  visible=np.zeros(2), s=np.array([0.0, 1.0]), map_version=0, path_version=0, solve_s=0.0, pans=pans)
    plan = Plan(**common, tilts=tilts, base_frames=frames)
    np.testing.assert_allclose(plan.direction_at_s(np.array([0.0, 1.0])), dirs, atol=1e-12)
    for f in np.linspace(0.0, 1.0, 11):
        d = plan.direction_at_s(f)
        # in the interpolated body frame the joints are the linear interpolation of the waypoints' joints
        q = np.array([0.0, 0.0, math.sin(f * yaw / 2), math.cos(f * yaw / 2)])
        pan, tilt = direction_to_pan_tilt(base_from_world(q, mount) @ d)
        assert math.degrees(tilt) == pytest.approx(-15.0, abs=0.5)
        assert math.degrees(pan) == pytest.approx((-140.0 + 200.0 * f + 180.0) % 360.0 - 180.0, abs=1.0)
    great_circle = Plan(**common).direction_at_s(0.5)
    assert math.degrees(direction_to_pan_tilt(frames[0] @ great_circle)[1]) < -40.0
