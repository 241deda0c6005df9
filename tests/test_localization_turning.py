"""PIVOT on a turning route with a bounded pan range: the daemon's planner and control loop unwind where
the view loses least instead of winding into the limit and sweeping the whole circle."""

import math
from pathlib import Path

import numpy as np
import pytest

from pivotd.localization.camera import CameraModel
from pivotd.localization.policies import PolicyName, make_policy
from pivotd.localization.scenes import build_scene
from pivotd.localization.simulate import localize, run_policy
from pivotd.localization.stack import load_config
from pivotd.localization.world import World

pytestmark = pytest.mark.slow

REPO = Path(__file__).resolve().parent.parent


def test_full_turn_past_a_corner_of_walls_keeps_the_camera_on_landmarks():
    """FIF two walls: a 2 m circle in 5 s (the body turns 360°) next to two walls meeting in a corner; the
    walls cover 120–270° of the surroundings depending on the position. A world-fixed view must unwind
    once on a ±170° gimbal; unwound at the limit it sweeps ≥ 170° of empty surroundings (about 1 s, ≥ 9
    frames at 10 Hz); unwound where the empty sector is narrowest it loses at most a few frames."""
    world = World(load_config(REPO / "config" / "demo.yaml"), build_scene("fif_two_walls", 0, REPO / "tests" / "data"
                                                                          / "fif"), CameraModel())
    lim = world.limits
    assert not lim.continuous_pan and math.degrees(lim.pan_max) == pytest.approx(170.0)
    traj = run_policy(world, make_policy(PolicyName.PIVOT, world, 0))
    pan = traj.setpoints[:, 0]
    assert pan.min() >= lim.pan_min - 1e-9 and pan.max() <= lim.pan_max + 1e-9
    err = localize(world, traj, 0)
    blind = int(np.count_nonzero(err.in_view < 8))
    assert blind <= 6, f"{blind} of {err.in_view.size} frames see fewer than 8 landmarks"
    ok = (err.translation <= 0.25) & (err.rotation <= 2.0)
    assert ok.mean() >= 0.85
