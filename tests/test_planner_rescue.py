"""Rescue of blind warm starts in the receding-horizon planner (pivotd.pivot.rescue, planner.rescue_blind)."""

import math
from dataclasses import replace

import numpy as np
import pytest

from pivotd.config import load_config
from pivotd.daemon.planner import PathMode, Plan, PlannerSettings, RecedingHorizonPlanner, Rescue
from pivotd.errors import PivotdError
from pivotd.geometry import angle_between
from pivotd.gimbal.kinematics import JointLimits, Mount
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import MapStore
from pivotd.pivot.rescue import blind_waypoints, rescue_init
from pivotd.pivot.trajectory import TrajectoryOptions

IDENTITY = np.array([0.0, 0.0, 0.0, 1.0])
N = 41  # waypoints of the path (0.5 m apart along +x) and of the horizon
LIMITS = JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60), False)


def yaw(deg: float) -> np.ndarray:
    a = math.radians(deg)
    return np.array([math.cos(a), math.sin(a), 0.0])


BLANK = yaw(-50.0)  # 140° from the wall's normal direction (+y)


def snapshot():
    """A dense textured wall 4 m to the left of a 20 m straight path, one landmark far on the right."""
    rng = np.random.default_rng(1)
    wall = np.c_[rng.uniform(0, 22, 1500), np.full(1500, 4.0), rng.uniform(-1, 1.5, 1500)]
    pts = np.vstack([wall, [[6.0, -6.0, 0.0]]]).astype(np.float32)
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=pts, weights=np.ones(pts.shape[0], np.float32)))
    return store.snapshot()


def planner(snap, warm: np.ndarray, rescue: float | None, max_step: float | None = None) -> RecedingHorizonPlanner:
    """A planner on the path whose previous plan looked at ``warm`` (3,) everywhere."""
    st = PlannerSettings(fov=math.radians(60), lam=0.6, spacing=0.5, horizon=N, max_step=max_step, axis_speeds=None,
                         retained_filter=RetainedFilter(min_range=0.3, max_range=10.0), rescue_fraction=rescue)
    pl = RecedingHorizonPlanner(st, Mount(), LIMITS)
    path = np.c_[np.linspace(0, 20, N), np.zeros(N), np.zeros(N)]
    pl.set_path(path, None, 1)
    pl.last_plan = Plan(created=0.0, positions=path, directions=np.repeat(warm[None], N, 0),
                        body_quats=np.tile(IDENTITY, (N, 1)), visible=np.zeros(N, int), s=np.arange(N) * 0.5,
                        map_version=snap.version, path_version=1, solve_s=0.0, path_mode=PathMode.ON_PATH)
    return pl


def test_blind_warm_start_turns_to_the_wall_with_a_higher_objective():
    snap = snapshot()
    off, on = planner(snap, BLANK, None), planner(snap, BLANK, 0.25)
    p_off = off.replan(snap, np.zeros(3), IDENTITY, BLANK)
    p_on = on.replan(snap, np.zeros(3), IDENTITY, BLANK)
    # without the rescue the warm plan stays on the blank view: no gradient leads 140° away
    assert off.solves == 1 and p_off.visible.max() <= 1
    assert all(angle_between(d, BLANK) < math.radians(10) for d in p_off.directions)
    # with it, a second solve from the wall's axis wins by the objective and the plan looks at the wall
    assert on.solves == 2 and on.rescues == 1
    assert p_on.rescue == Rescue.KEPT and p_off.rescue == Rescue.NOT_TRIED  # what the daemon's status counts
    assert on.last_objective > off.last_objective
    assert np.median(p_on.visible) > 300
    assert angle_between(p_on.directions[N // 2], yaw(90.0)) < math.radians(50)


def test_rescue_keeps_the_step_limit():
    snap = snapshot()
    step = math.radians(10)
    pl = planner(snap, BLANK, 0.25, max_step=step)
    plan = pl.replan(snap, np.zeros(3), IDENTITY, BLANK)
    assert pl.solves == 2
    turns = [angle_between(a, b) for a, b in zip(plan.directions[:-1], plan.directions[1:], strict=True)]
    assert angle_between(BLANK, plan.directions[0]) <= step + 1e-6 and max(turns) <= step + 1e-6
    assert plan.visible.sum() > 1000  # it still turns to the wall, within the limit


def test_no_second_solve_when_nothing_is_blind_and_the_plan_is_unchanged():
    snap = snapshot()
    wall = yaw(90.0)
    off, on = planner(snap, wall, None), planner(snap, wall, 0.25)
    anchor = wall
    for k in range(4):  # a few replans as the robot moves: the grid waypoints' estimates come from the cache
        pos = np.array([0.3 * k, 0.0, 0.0])
        p_off = off.replan(snap, pos, IDENTITY, anchor)
        p_on = on.replan(snap, pos, IDENTITY, anchor)
        np.testing.assert_array_equal(p_on.directions, p_off.directions)
        np.testing.assert_array_equal(p_on.visible, p_off.visible)
        anchor = p_on.directions[0]
    assert on.solves == off.solves == 4 and on.rescues == 0


def test_blind_waypoints_share_of_attainable():
    got = blind_waypoints(np.array([0, 10, 2, 0, 5]), np.array([20, 20, 20, 0, 10]), 0.25)
    np.testing.assert_array_equal(got, [0, 2])  # 0/20 and 2/20 < 25 %; nothing attainable is never blind


def test_rescue_init_points_runs_at_their_axes_and_slerps_the_neighbourhood():
    d = np.repeat(yaw(0.0)[None], 9, 0)
    axes = np.array([yaw(90.0), yaw(90.0)])
    init = rescue_init(d, np.array([4, 5]), axes, reach=2)
    ang = np.degrees(np.arctan2(init[:, 1], init[:, 0]))
    np.testing.assert_allclose(ang, [0, 0, 30, 60, 90, 90, 60, 30, 0], atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(init, axis=1), 1.0)
    # opposite directions still give a unit start
    opp = rescue_init(np.repeat(yaw(0.0)[None], 3, 0), np.array([1]), np.array([yaw(180.0)]), reach=1)
    np.testing.assert_allclose(np.linalg.norm(opp, axis=1), 1.0)
    assert angle_between(opp[0], yaw(0.0)) == pytest.approx(math.pi / 2)


def test_config_rescue_settings(tmp_path):
    p = tmp_path / "c.yaml"
    p.write_text("map:\n  allow_empty: true\nplanner:\n  rescue_blind: true\n  rescue_fraction: 0.3\n")
    cfg = load_config(p)
    assert cfg.planner.rescue_blind is True and cfg.planner.rescue_fraction == pytest.approx(0.3)
    p.write_text("map:\n  allow_empty: true\nplanner:\n  rescue_fraction: 1.5\n")
    with pytest.raises(PivotdError, match="rescue_fraction"):
        load_config(p)


def test_a_rescue_that_lost_is_not_retried_until_the_problem_changes():
    snap = snapshot()
    pl = planner(snap, BLANK, 0.25)
    # too short to pay for the turn under the paper's smoothness (1 − cos per step, no knee: a turn costs more)
    pl.settings = replace(pl.settings, horizon=10, options=TrajectoryOptions.paper())
    first = pl.replan(snap, np.zeros(3), IDENTITY, BLANK)
    assert pl.solves == 2 and pl.rescues == 0 and first.visible.max() <= 1  # tried, lost on the objective
    assert first.rescue == Rescue.LOST
    second = pl.replan(snap, np.array([0.1, 0.0, 0.0]), IDENTITY, first.directions[0])
    assert pl.solves == 3 and second.rescue == Rescue.NOT_TRIED  # the same blind waypoints: not tried again
    pl.replan(snap, np.array([0.6, 0.0, 0.0]), IDENTITY, first.directions[0])
    assert pl.solves == 5  # a new blind waypoint entered the horizon: tried again


def test_the_rescue_builds_its_cone_kernel_once_and_searches_as_without_it():
    from pivotd.pivot.view import optimize_view

    snap = snapshot()
    pl = planner(snap, BLANK, 0.25)
    assert pl.replan(snap, np.zeros(3), IDENTITY, BLANK).rescue == Rescue.KEPT
    kernel = pl._view_kernel()
    assert kernel is pl._view_kernel() and kernel.alpha == pl.settings.alpha  # one kernel per FoV, kept
    rel = snap.points[:1500].astype(float) - np.array([5.0, 0.0, 0.0])
    alpha = pl.settings.alpha
    own, shared = optimize_view(rel, None, alpha), optimize_view(rel, None, alpha, kernel=kernel)
    assert np.array_equal(own.direction, shared.direction) and own.visible == shared.visible > 300
    pl.settings = replace(pl.settings, fov=math.radians(40))
    assert pl._view_kernel().alpha == pytest.approx(math.radians(20))  # a new FoV builds its own
