"""Event-driven replanning (pivotd.daemon.replan_trigger) and its wiring from the config."""

from pathlib import Path

import numpy as np

from pivotd.config import load_config
from pivotd.daemon.replan_trigger import ReplanReason, ReplanTrigger
from pivotd.daemon.wiring import build_control_settings, build_replan_trigger

REPO = Path(__file__).resolve().parent.parent


def test_replans_when_moved_a_waypoint_on_new_inputs_and_at_the_longest_interval():
    trig = ReplanTrigger(distance=0.5, max_interval=1.0)
    p0 = np.zeros(3)
    assert trig.due(0.0, p0, (1, 0)) == ReplanReason.FIRST
    trig.planned(0.0, p0, (1, 0))
    # 0.49 m later and 0.9 s later, same inputs: the plan stands
    assert trig.due(0.9, np.array([0.49, 0.0, 0.0]), (1, 0)) is None
    assert trig.due(0.2, np.array([0.3, 0.4, 0.0]), (1, 0)) == ReplanReason.MOVED  # 0.5 m in any direction
    assert trig.due(0.2, p0, (2, 0)) == ReplanReason.INPUT  # a new path
    assert trig.due(0.2, p0, (1, 1)) == ReplanReason.INPUT  # a new map
    assert trig.due(1.0, p0, (1, 0)) == ReplanReason.INTERVAL  # standing still: still replans every second
    trig.planned(1.0, np.array([0.3, 0.4, 0.0]), (1, 1))
    assert trig.due(1.5, np.array([0.3, 0.4, 0.0]), (1, 1)) is None  # measured from the last replan
    trig.reset()
    assert trig.due(1.5, p0, (1, 1)) == ReplanReason.FIRST


def test_without_a_distance_every_tick_replans():
    trig = ReplanTrigger(distance=None, max_interval=1.0)
    trig.planned(0.0, np.zeros(3), ())
    assert trig.due(0.01, np.zeros(3), ()) == ReplanReason.EVERY_TICK


def test_config_wiring_and_the_stale_plan_timeout(tmp_path):
    base = (REPO / "config" / "demo.yaml").read_text().replace("demo_hallway_map.txt",
                                                               str(REPO / "config" / "demo_hallway_map.txt"))
    on = tmp_path / "on.yaml"
    on.write_text(base.replace("  replan_hz: 5\n", "  replan_hz: 5\n  replan_on_waypoint: true\n"
                                                   "  replan_max_interval_s: 3\n"))
    off = tmp_path / "off.yaml"
    off.write_text(base.replace("  replan_hz: 5\n", "  replan_hz: 5\n  replan_on_waypoint: false\n"))
    cfg_on, cfg_off = load_config(on), load_config(off)
    t_on, t_off = build_replan_trigger(cfg_on), build_replan_trigger(cfg_off)
    assert t_on.distance == cfg_on.planner.waypoint_spacing and t_on.max_interval == 3.0
    assert t_off.distance is None
    # a plan may be kept up to max_interval: the control loop must not call it stale before that
    assert build_control_settings(cfg_on).plan_timeout >= 2 * 3.0
    assert build_control_settings(cfg_off).plan_timeout == max(1.0, 10.0 / cfg_off.planner.replan_hz)
