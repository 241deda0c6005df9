"""``planner.max_step_deg``: validated in the config file, and every replan keeps its steps within it."""

import math

import numpy as np
import pytest

from pivotd.config import load_config
from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner
from pivotd.daemon.wiring import build_planner
from pivotd.errors import ConfigError
from pivotd.gimbal.kinematics import JointLimits, Mount
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import MapStore
from pivotd.pivot.scenes import hallway
from pivotd.pivot.steps import step_angles

MINIMAL = "name: test-node\nmap:\n  allow_empty: true\n"


@pytest.mark.parametrize(
    ("value", "pattern"),
    [("0", r":5: planner\.max_step_deg: must be ≥ 0\.01"), ("-3", r":5: planner\.max_step_deg: must be ≥ 0\.01"),
     ("181", r":5: planner\.max_step_deg: must be ≤ 180"), (".inf", r":5: planner\.max_step_deg: must be finite"),
     ("fast", r":5: planner\.max_step_deg: must be a number")],
)
def test_bad_step_limits_name_the_file_line_and_key(tmp_path, value, pattern):
    path = tmp_path / "pivotd.yaml"
    path.write_text(MINIMAL + f"planner:\n  max_step_deg: {value}\n")
    with pytest.raises(ConfigError, match=pattern) as err:
        load_config(path)
    assert str(path) in str(err.value) and "\n" not in str(err.value)


def test_the_setting_reaches_the_planner(tmp_path):
    path = tmp_path / "pivotd.yaml"
    path.write_text(MINIMAL + "planner:\n  max_step_deg: 4\n")
    assert build_planner(load_config(path)).settings.max_step == pytest.approx(math.radians(4))
    path.write_text(MINIMAL)
    assert build_planner(load_config(path)).settings.max_step is None


def test_replans_never_exceed_the_step_limit():
    sc = hallway()
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    snap = store.snapshot()
    limit = math.radians(2.0)
    limits = JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60), False)
    settings = PlannerSettings(fov=math.radians(60), lam=0.6, spacing=0.5, horizon=20, max_step=limit,
                               retained_filter=RetainedFilter(min_range=0.3, max_range=10.0))
    pl = RecedingHorizonPlanner(settings, Mount(), limits)
    pl.set_path(sc.path, None, 1)
    commanded = None
    for k in range(12):
        pos = sc.path[0] + (sc.path[1] - sc.path[0]) * (k / 2)
        plan = pl.replan(snap, pos, np.array([0.0, 0, 0, 1]), commanded)
        assert step_angles(plan.directions, commanded).max() <= limit + 1e-9
        commanded = plan.directions[0]
