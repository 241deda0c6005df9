"""Pan branch selection over a horizon (pivotd.gimbal.pan_unwrap)."""

from __future__ import annotations

import itertools
import math

import numpy as np
import pytest

from pivotd.geometry import pan_tilt_to_direction
from pivotd.gimbal.kinematics import JointLimits, world_directions_to_joints
from pivotd.gimbal.pan_unwrap import pan_branches, unwrap_pans

D = math.radians
WIDE = JointLimits(pan_min=D(-270), pan_max=D(270), tilt_min=D(-45), tilt_max=D(60))
DEMO = JointLimits(pan_min=D(-170), pan_max=D(170), tilt_min=D(-45), tilt_max=D(60))
SLIP = JointLimits(tilt_min=D(-45), tilt_max=D(60), continuous_pan=True)


def long_slews(start: float, pans: np.ndarray) -> np.ndarray:
    """Indices of the joint steps (from ``start`` into each waypoint) longer than π: the long way round."""
    p = np.concatenate([[float(start)], np.asarray(pans, float)])
    return np.flatnonzero(np.abs(np.diff(p)) > np.pi)


def _total_slew(start: float, pans: np.ndarray) -> float:
    return float(np.abs(np.diff(np.concatenate([[start], pans]))).sum())


def _brute(pans: np.ndarray, start: float, limits: JointLimits) -> float:
    """Least total slew over every in-range branch combination (exhaustive reference)."""
    layers = [pan_branches(float(p), limits) for p in pans]
    return min(_total_slew(start, np.array(c)) for c in itertools.product(*layers))


def test_branches_lie_inside_the_limits_and_are_equivalent():
    rng = np.random.default_rng(3)
    for p in rng.uniform(-3 * np.pi, 3 * np.pi, 200):
        for lim in (WIDE, DEMO):
            b = pan_branches(float(p), lim)
            assert np.all((b >= lim.pan_min - 1e-9) & (b <= lim.pan_max + 1e-9))
            assert np.allclose(np.remainder(b - p + np.pi, 2 * np.pi) - np.pi, 0.0, atol=1e-9)
        assert len(pan_branches(float(p), WIDE)) in (1, 2)
    assert pan_branches(D(180), DEMO).size == 0  # the sector behind a ±170° gimbal


@pytest.mark.parametrize("seed", range(6))
def test_unwrap_is_the_exact_least_slew_in_range(seed):
    rng = np.random.default_rng(seed)
    pans = np.cumsum(rng.normal(0.0, 0.8, 7))
    start = float(rng.uniform(WIDE.pan_min, WIDE.pan_max))
    out, clamped = unwrap_pans(pans, start, WIDE)
    assert not clamped.any()
    assert np.all((out >= WIDE.pan_min - 1e-9) & (out <= WIDE.pan_max + 1e-9))
    assert np.allclose(np.remainder(out - pans + np.pi, 2 * np.pi) - np.pi, 0.0, atol=1e-9)
    assert _total_slew(start, out) == pytest.approx(_brute(pans, start, WIDE), abs=1e-9)


def test_wide_range_picks_the_branch_with_room_for_the_turn_ahead():
    """A ±270° gimbal at pan 0 looking at a target at pan 190° (≡ −170°) whose pan will wind down by 400°:
    the greedy nearest branch (−170°) runs into −270° and must slew a full turn; the horizon-wide choice
    takes +190° and tracks the whole turn down to −210° without a long slew."""
    start = 0.0
    target = D(190) - np.linspace(0.0, D(400), 41)  # the world-fixed target's pan while the body turns
    out, _ = unwrap_pans(target, start, WIDE)
    assert out[0] == pytest.approx(D(190))  # 20° more than the nearest branch, once, at the start
    assert np.all(np.abs(np.diff(out)) <= D(10) + 1e-9)
    greedy, _, _ = world_directions_to_joints(
        pan_tilt_to_direction(target, np.zeros_like(target)), np.array([0.0, 0.0, 0.0, 1.0]),
        _identity_mount(), WIDE, start)
    assert long_slews(start, greedy).size == 1 and long_slews(start, greedy)[0] > 0  # a full circle mid-turn
    assert _total_slew(start, out) < _total_slew(start, greedy) - D(300)


def test_720_degree_turn_is_tracked_without_a_full_circle_slew_when_the_view_allows():
    """Two full body turns while the camera's world direction turns along (a view of the route ahead
    that sweeps 700° of world heading): the pan stays within ±270° without any long slew."""
    yaw = np.linspace(0.0, D(720), 145)
    view = yaw + D(40) * np.sin(np.linspace(0.0, 6 * np.pi, 145))  # world heading of the chosen view
    out, clamped = unwrap_pans(view - yaw, 0.0, WIDE)
    assert not clamped.any() and long_slews(0.0, out).size == 0
    assert np.abs(out).max() <= D(41)
    cont, _ = unwrap_pans(view - yaw, 0.0, SLIP)
    assert np.allclose(cont, out)


def test_bounded_range_never_exceeded_and_the_forced_unwind_is_found():
    """A world-fixed view while the body turns 360°: pan must wind 360° on a ±170° gimbal. Every joint
    value stays in range, and exactly one long slew is reported, where the view crosses the back sector."""
    yaw = np.linspace(0.0, D(360), 73)
    pans = np.remainder(-yaw + np.pi, 2 * np.pi) - np.pi
    out, clamped = unwrap_pans(pans, 0.0, DEMO)
    assert np.all((out >= DEMO.pan_min - 1e-12) & (out <= DEMO.pan_max + 1e-12))
    slews = long_slews(0.0, out)
    assert slews.size == 1
    i = int(slews[0])
    assert out[i - 1] <= D(-165) and out[i] >= D(165)
    assert np.all(np.abs(out[clamped]) == pytest.approx(D(170)))


def test_continuous_pan_is_the_nearest_unwrap():
    pans = np.remainder(np.linspace(0.0, D(900), 50) + np.pi, 2 * np.pi) - np.pi
    out, _ = unwrap_pans(pans, 0.0, SLIP)
    assert np.allclose(out, np.linspace(0.0, D(900), 50))
    assert long_slews(0.0, out).size == 0


def _identity_mount():
    from pivotd.gimbal.kinematics import Mount

    return Mount()


@pytest.mark.parametrize("limits", [DEMO, WIDE], ids=["one_branch", "two_branches"])
def test_every_waypoint_takes_one_of_its_own_branches_or_the_nearer_limit(limits):
    rng = np.random.default_rng(11)
    pans = rng.uniform(-3 * np.pi, 3 * np.pi, 60)  # any representation, some in the sector behind a ±170° gimbal
    out, clamped = unwrap_pans(pans, 0.3, limits)
    for p, o, c in zip(pans, out, clamped, strict=True):
        b = pan_branches(float(p), limits)
        assert c == (b.size == 0)
        if c:  # the limit nearer around the circle
            below, above = np.remainder(limits.pan_min - p, 2 * np.pi), np.remainder(p - limits.pan_max, 2 * np.pi)
            assert o == (limits.pan_min if below <= above else limits.pan_max)
        else:
            assert o in b  # exactly one of the branches pan_branches lists
    assert (limits is WIDE) or clamped.any()
    if limits is DEMO:  # one branch each: nothing to choose
        assert np.array_equal(out[~clamped], [pan_branches(float(p), DEMO)[0] for p in pans[~clamped]])
