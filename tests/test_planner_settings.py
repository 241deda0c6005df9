"""One set of defaults: the daemon plans with every planner value of its config, never with a default of
PlannerSettings or TrajectoryOptions (pivotd.daemon.wiring.planner_settings)."""

from __future__ import annotations

import math
from dataclasses import fields, replace

import pytest

from pivotd.config import Config, PivotConfig, PlannerConfig
from pivotd.daemon.wiring import build_planner, planner_settings
from pivotd.pivot.normalise import Normalisation

#: config field -> the value the planner settings carry for it (SI, as the config holds it)
PIVOT = {
    "fov": lambda st: st.fov,
    "lam": lambda st: st.lam,
    "transition_width": lambda st: math.radians(st.options.width_deg),
    "iterations": lambda st: st.options.max_iterations,
    "distance_weights": lambda st: st.options.distance_weights,
    "smooth_knee": lambda st: math.radians(st.options.smooth_knee_deg),
}
PLANNER = {
    "waypoint_spacing": lambda st: st.spacing,
    "horizon": lambda st: st.horizon,
    "max_landmarks_per_waypoint": lambda st: st.max_landmarks_per_waypoint,
    "max_step": lambda st: st.max_step,
    "max_path_offset": lambda st: st.max_path_offset,
    "normalise": lambda st: st.options.normalise,
    "rescue_blind": lambda st: st.rescue_fraction is not None,
    "rescue_fraction": lambda st: st.rescue_fraction,
    "replan_budget": lambda st: st.replan_budget,
}
#: planner keys that set when to replan and how long to wait, not how (the daemon, the trigger, the worker)
NOT_PLANNING = {"replan_hz", "replan_on_waypoint", "replan_max_interval", "replan_deadline"}

#: a value other than the default for every mapped field
CHANGED_PIVOT = dict(fov=math.radians(44.0), lam=0.35, transition_width=math.radians(2.5), iterations=33,
                     distance_weights=True, smooth_knee=math.radians(2.0))
CHANGED_PLANNER = dict(waypoint_spacing=0.4, horizon=17, max_landmarks_per_waypoint=1234, max_step=math.radians(5.0),
                       max_path_offset=2.5, normalise=Normalisation.ATTAINABLE, rescue_fraction=0.3,
                       replan_budget=1.5)


def test_every_pivot_and_planner_key_is_mapped_or_named_as_not_planning():
    assert set(PIVOT) == {f.name for f in fields(PivotConfig)}
    assert set(PLANNER) | NOT_PLANNING == {f.name for f in fields(PlannerConfig)}
    assert set(CHANGED_PIVOT) == set(PIVOT)
    assert set(CHANGED_PLANNER) == set(PLANNER) - {"rescue_blind"}


@pytest.mark.parametrize("changed", [False, True], ids=["defaults", "changed"])
def test_planner_settings_carry_every_pivot_and_planner_value(changed):
    cfg = Config()
    if changed:
        cfg = replace(cfg, pivot=replace(cfg.pivot, **CHANGED_PIVOT), planner=replace(cfg.planner, **CHANGED_PLANNER))
        assert cfg.pivot != PivotConfig() and all(getattr(cfg.pivot, k) != getattr(PivotConfig(), k)
                                                  for k in CHANGED_PIVOT)
        assert all(getattr(cfg.planner, k) != getattr(PlannerConfig(), k) for k in CHANGED_PLANNER)
    st = planner_settings(cfg)
    for section, table in ((cfg.pivot, PIVOT), (cfg.planner, PLANNER)):
        for name, carried in table.items():
            expected = getattr(section, name)
            if isinstance(expected, float):
                assert carried(st) == pytest.approx(expected, rel=1e-12), name  # through degrees and back
            else:
                assert carried(st) == expected, name
    assert st.options.warm_iterations <= cfg.pivot.iterations
    f = cfg.map.filters
    assert (st.retained_filter.min_range, st.retained_filter.max_range) == (f.min_range, f.max_range)
    assert build_planner(cfg).settings == st


def test_the_daemons_defaults_are_the_configs():
    """The values the three layers once disagreed on are the config's: knee 1°, width 4°, 50 iterations, horizon
    20, 2000 landmarks per waypoint, rescue on, FoV 60°."""
    st = planner_settings(Config())
    assert st.options.smooth_knee_deg == pytest.approx(1.0) and st.options.width_deg == pytest.approx(4.0)
    assert st.options.max_iterations == 50 and st.horizon == 20 and st.max_landmarks_per_waypoint == 2000
    assert st.rescue_fraction == pytest.approx(0.25) and st.fov == pytest.approx(math.radians(60.0))


def test_rescue_off_in_the_config_is_off_in_the_planner():
    cfg = Config()
    assert planner_settings(replace(cfg, planner=replace(cfg.planner, rescue_blind=False))).rescue_fraction is None
