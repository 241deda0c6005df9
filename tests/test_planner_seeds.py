"""The planner's seeds: a plan without a previous one (first plan, new path, reload, worker restart) gets the cold
seeds beside the commanded direction; the joint-grid seed keeps the plan executable within the limits."""

import math

import numpy as np
import pytest
from test_planner_rescue import BLANK, IDENTITY, snapshot, yaw

from pivotd.daemon.planner import PathMode, Plan, PlannerSettings, RecedingHorizonPlanner
from pivotd.geometry import angle_between
from pivotd.gimbal.kinematics import JointLimits, Mount
from pivotd.maps.filters import RetainedFilter

N = 21
LIMITS = JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60), False)


def planner(axis_speeds: tuple[float, float] | None = None) -> RecedingHorizonPlanner:
    """Rescue off; the joint-grid seed only with ``axis_speeds`` [rad/s]; the replan period of the config (0.2 s)."""
    st = PlannerSettings(fov=math.radians(60), lam=0.6, spacing=0.5, horizon=N, rescue_fraction=None,
                         axis_speeds=axis_speeds, replan_period=0.2,
                         retained_filter=RetainedFilter(min_range=0.3, max_range=10.0))
    return RecedingHorizonPlanner(st, Mount(), LIMITS)


def path(offset: float = 0.0) -> np.ndarray:
    return np.c_[np.linspace(0, 10, N), np.full(N, offset), np.zeros(N)]


def blank_plan(snap) -> Plan:
    """A previous plan on path version 1 that looked at the blank side everywhere."""
    return Plan(created=0.0, positions=path(), directions=np.repeat(BLANK[None], N, 0),
                body_quats=np.tile(IDENTITY, (N, 1)), visible=np.zeros(N, int), s=np.arange(N) * 0.5,
                map_version=snap.version, path_version=1, solve_s=0.0, path_mode=PathMode.ON_PATH)


def test_a_new_path_with_the_camera_pointing_away_gets_the_cold_seeds():
    snap = snapshot()
    pl = planner()
    pl.set_path(path(), None, 1)
    pl.last_plan = blank_plan(snap)
    warm = pl.replan(snap, np.zeros(3), IDENTITY, BLANK)
    assert warm.seed == "warm" and warm.visible.max() <= 1  # the warm start has no gradient to follow
    pl.set_path(path(0.2), None, 2)  # a new path: no previous plan for it
    plan = pl.replan(snap, np.array([0.0, 0.2, 0.0]), IDENTITY, BLANK)
    assert plan.seed not in ("warm", "anchor")
    assert np.median(plan.visible) > 300
    assert angle_between(plan.directions[N // 2], np.array([0.0, 1.0, 0.0])) < math.radians(50)


def test_the_first_plan_gets_the_cold_seeds_beside_the_commanded_direction():
    snap = snapshot()
    pl = planner()
    pl.set_path(path(), None, 1)
    plan = pl.replan(snap, np.zeros(3), IDENTITY, BLANK)
    assert pl.solves >= 2 and plan.seed != "anchor"
    assert np.median(plan.visible) > 300


def test_the_joint_grid_seed_leaves_a_blank_warm_plan_within_the_axis_speeds():
    snap = snapshot()
    speeds = (math.radians(120), math.radians(90))
    pl = planner(speeds)
    pl.set_path(path(), None, 1)
    pl.last_plan = blank_plan(snap)
    # the replan that queries the map for the horizon leaves the joint-grid seed to the next one
    first = pl.replan(snap, np.zeros(3), IDENTITY, BLANK, now=0.0)
    assert first.seed == "warm" and pl.joint_solves == 0
    # the next one finds it in another basin after its own (warm) solve; one solve per replan: the one after
    # solves it, against the warm plan kept as it is
    second = pl.replan(snap, np.array([0.05, 0.0, 0.0]), IDENTITY, BLANK, now=0.05)
    assert second.seed == "warm" and pl.joint_solves == 0
    solves = pl.solves
    plan = pl.replan(snap, np.array([0.1, 0.0, 0.0]), IDENTITY, BLANK, now=0.1)
    assert plan.seed == "joint_grid" and pl.joint_solves == 1 and pl.solves == solves + 1
    assert np.median(plan.visible) > 300
    # the commanded direction is where the plan starts from: its first move fits the pan speed at 1 m/s
    first = angle_between(plan.directions[0], BLANK)
    assert first <= speeds[0] * (0.5 / pl.settings.nominal_speed) + math.radians(5)


def test_a_plan_as_executed_slews_at_the_axis_speeds_and_is_computed_once_per_replan():
    from pivotd.daemon.planner import _Execution

    speeds = (math.radians(120), math.radians(90))
    pl = planner(speeds)
    pl.set_path(path(), None, 1)
    quats = np.tile(IDENTITY, (N, 1))
    executed = _Execution(pl, np.arange(N) * 0.5, quats, BLANK)  # from the commanded -50°, 60° of pan per step
    plan = np.repeat(BLANK[None], N, 0)
    plan[5:] = yaw(100.0)  # a 150° swing at waypoint 5, then a hold
    out = executed.directions(plan)
    assert executed.directions(plan.copy()) is out  # the same plan is followed once
    for k, want in [(0, -50.0), (4, -50.0), (5, 10.0), (6, 70.0), (7, 100.0), (N - 1, 100.0)]:
        assert angle_between(out[k], yaw(want)) < 1e-9, k
    other = plan.copy()
    other[5:] = yaw(-80.0)  # another plan: its own path (30° within one step)
    assert angle_between(executed.directions(other)[5], yaw(-80.0)) < 1e-9


def test_a_plan_past_the_end_of_the_pan_range_is_also_judged_held_there():
    from pivotd.daemon.planner import _Execution

    pl = planner((math.radians(120), math.radians(90)))
    pl.set_path(path(), None, 1)
    quats = np.tile(IDENTITY, (N, 1))
    start = yaw(-160.0)
    executed = _Execution(pl, np.arange(N) * 0.5, quats, start)
    # a view that moves on past −170°: −165°, then −190° (+170°) and −200° (+160°), which the joints would reach
    # the long way round; held, it stays at −170°
    plan = np.repeat(yaw(-165.0)[None], N, 0)
    plan[5:10] = yaw(-190.0)
    plan[10:] = yaw(-200.0)
    held = executed.held_at_limits(plan)
    assert held is not None
    for k, want in [(0, -165.0), (4, -165.0), (5, -170.0), (9, -170.0), (N - 1, -170.0)]:
        assert angle_between(held[k], yaw(want)) < 1e-9, k
    # as executed, the held plan stays at the limit; the plan itself slews away from it towards +160°
    assert angle_between(executed.directions(held)[N - 1], yaw(-170.0)) < 1e-9
    assert angle_between(executed.directions(plan)[N - 1], yaw(160.0)) < 1e-9
    # a plan inside the range, or one crossing the front (0°) within it, is left alone
    inside = np.repeat(yaw(-100.0)[None], N, 0)
    inside[8:] = yaw(40.0)
    assert executed.held_at_limits(inside) is None


def test_a_plan_as_executed_turns_at_most_one_replan_period_towards_its_first_waypoint():
    from pivotd.daemon.planner import _Execution

    pl = planner((math.radians(120), math.radians(90)))
    pl.set_path(path(), None, 1)
    executed = _Execution(pl, np.arange(N) * 0.5, np.tile(IDENTITY, (N, 1)), BLANK)  # commanded -50°
    plan = np.repeat(yaw(40.0)[None], N, 0)  # 90° away from the first waypoint on
    out = executed.directions(plan)
    # 0.2 s at 120 °/s before the next plan: 24°, then 60° a step
    for k, want in [(0, -26.0), (1, 34.0), (2, 40.0)]:
        assert angle_between(out[k], yaw(want)) < 1e-9, k


def test_a_jump_the_axes_cannot_make_between_two_waypoints_is_started_early_enough_to_arrive_on_time():
    from pivotd.daemon.planner import _Execution

    pl = planner((math.radians(120), math.radians(90)))
    pl.set_path(path(), None, 1)
    executed = _Execution(pl, np.arange(N) * 0.5, np.tile(IDENTITY, (N, 1)), BLANK)  # commanded -50°, 60° a step
    plan = np.repeat(BLANK[None], N, 0)
    plan[8:] = yaw(100.0)  # 150° between waypoints 7 and 8
    early = executed.anticipated(plan)
    assert early is not None
    pans = [math.degrees(math.atan2(d[1], d[0])) for d in early]
    assert np.allclose(pans[:6], -50.0) and np.allclose(pans[6:9], [-20.0, 40.0, 100.0])
    assert np.allclose(pans[9:], 100.0)
    # followed late, the plan reaches 100° one step after waypoint 8; started early it is there at waypoint 8
    late, on_time = executed.directions(plan), executed.directions(early)
    assert angle_between(late[8], yaw(100.0)) > math.radians(80) and angle_between(on_time[8], yaw(100.0)) < 1e-9
    # a plan whose every step fits is left alone
    assert executed.anticipated(on_time) is None


def test_a_turn_in_place_between_two_waypoints_gives_the_axes_the_time_of_the_turn():
    pl = planner((math.radians(120), math.radians(90)))
    half = math.sin(math.radians(45.0))  # a 90° turn about z
    quats = np.array([IDENTITY, IDENTITY, [0.0, 0.0, -half, half], [0.0, 0.0, -half, half]])
    s = np.array([0.0, 0.5, 0.5 + 1e-6, 1.0])  # the turn takes no arc length
    dpan, _ = pl._step_limits(s, quats)
    # 90° at the nominal 90 °/s: one second, 120° of pan; the steps of travel 0.5 s, 60°
    assert np.allclose(np.degrees(dpan), [60.0, 120.0, 60.0])
    # once the robot has been seen turning, at its own rate: 45 °/s
    pl.replan(snapshot(), np.zeros(3), IDENTITY, None, now=0.0)
    q1 = np.array([0.0, 0.0, math.sin(math.radians(-11.25)), math.cos(math.radians(-11.25))])  # 22.5° in 0.5 s
    pl.replan(snapshot(), np.zeros(3), q1, None, now=0.5)
    assert math.degrees(pl.turn_rate) == pytest.approx(45.0)
    assert math.degrees(pl._step_limits(s, quats)[0][1]) == pytest.approx(240.0)


def test_a_turn_in_place_on_the_path_gets_a_waypoint_per_waypoint_period_of_the_turn():
    """East to a corner, a 90° turn in place (the path's repeated corner dropped: the attitude turns over its first
    0.25 m north), north on. The robot stands at the corner before the turn, seen turning at 45 °/s: the turn takes
    2 s where the travel to the next waypoint takes 0.5 s, so 3 waypoints split it into 22.5° steps of 0.5 s each
    (without them those 2 s lie between two waypoints and no direction is planned inside them)."""
    q_east, q_north = np.array([0.0, 0.0, 0.0, 1.0]), np.array([0.0, 0.0, math.sin(math.pi / 4), math.cos(math.pi / 4)])
    east = np.c_[np.arange(0.0, 5.01, 0.25), np.zeros(21), np.zeros(21)]
    north = np.c_[np.full(60, 5.0), np.arange(0.25, 15.01, 0.25), np.zeros(60)]
    quats = np.vstack([np.tile(q_east, (21, 1)), np.tile(q_north, (60, 1))])
    pl = planner((math.radians(120), math.radians(90)))
    pl.set_path(np.vstack([east, north]), quats, 1)
    pl.replan(snapshot(), np.array([4.8, 0.0, 0.0]), q_east, None)  # progress reaches the corner's grid cell
    pl.turn_rate = math.radians(45.0)
    plan = pl.replan(snapshot(), np.array([5.0, 0.0, 0.0]), q_east, None)
    assert np.all(np.diff(plan.s) > 0)
    assert plan.s.shape[0] == N + 3
    yaws = np.degrees(np.unwrap([2 * math.atan2(q[2], q[3]) for q in plan.body_quats]))
    np.testing.assert_allclose(yaws[:5], [0.0, 22.5, 45.0, 67.5, 90.0], atol=1e-6)
    assert np.all((plan.s[1:4] > 5.0) & (plan.s[1:4] < 5.25))  # where the path turns
    dpan, _ = pl._step_limits(plan.s, plan.body_quats)
    np.testing.assert_allclose(np.degrees(dpan[:3]), 60.0, rtol=1e-3)  # 0.5 s each at 120 °/s
    # a path without a turn is sampled in arc length only
    straight = planner((math.radians(120), math.radians(90)))
    straight.set_path(path(), None, 1)
    assert straight.replan(snapshot(), np.zeros(3), IDENTITY, None).s.shape[0] == N


def test_a_plan_started_early_is_published_and_the_next_replan_starts_from_the_plan_as_solved():
    from pivotd.maps.formats import LandmarkCloud
    from pivotd.maps.store import MapStore

    rng = np.random.default_rng(3)  # a sparse wall on the right for the first 3 m, a dense one on the left after
    right = np.c_[rng.uniform(-1, 3.2, 600), np.full(600, -1.5), rng.uniform(-0.5, 0.5, 600)]
    left = np.c_[rng.uniform(3.8, 12, 3000), np.full(3000, 1.5), rng.uniform(-0.5, 0.5, 3000)]
    pts = np.vstack([right, left]).astype(np.float32)
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=pts, weights=np.ones(pts.shape[0], np.float32)))
    snap = store.snapshot()
    pl = planner((math.radians(120), math.radians(90)))
    pl.set_path(path(), None, 1)
    plan = pl.replan(snap, np.zeros(3), IDENTITY, yaw(-90.0), now=0.0)
    assert pl._warm_from is not None and pl._warm_from[0] is plan
    solved = pl._warm_from[1]
    dpan, _ = pl._step_limits(plan.s, plan.body_quats)
    # the published plan keeps every step within the axis speeds; the plan as solved does not
    assert np.all(np.abs(np.diff(plan.pans)) <= dpan + 1e-9)
    assert np.any(np.abs(np.diff(solved.pans)) > dpan + 1e-9)
    # the next warm start is the plan as solved, read at the new arc lengths
    s = plan.s[:1] + 0.05
    np.testing.assert_allclose(pl._warm_start(np.r_[s, plan.s[1:]], plan.s.shape[0], PathMode.ON_PATH)[1:],
                               solved.direction_at_s(plan.s[1:]), atol=1e-12)
