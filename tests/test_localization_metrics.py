"""Localization metrics (pivotd.localization.metrics): per run, and frames in a slew."""

import math

import numpy as np
import pytest

from pivotd.localization.metrics import aggregate, longest_streak, run_metrics, turning_frames


def _axes(yaw_deg):
    a = np.radians(np.asarray(yaw_deg, float))
    return np.c_[np.cos(a), np.sin(a), np.zeros_like(a)]


def test_turning_frames_mark_both_ends_of_a_fast_step():
    times = np.arange(6) * 0.1
    yaw = [0, 1, 2, 12, 13, 13]  # 10°/s, 10°/s, 100°/s, 10°/s, 0
    assert turning_frames(times, _axes(yaw), 45.0).tolist() == [False, False, True, True, False, False]
    assert not turning_frames(times[:1], _axes([0])).any()


def test_run_metrics_share_of_failures_while_turning_and_the_longest_streak():
    t = np.array([0.01, 0.01, 0.5, math.inf, 0.01, 0.3, 0.3, 0.01])  # [m]
    r = np.full(8, 0.5)  # [deg]
    turning = np.array([0, 0, 1, 1, 0, 0, 1, 0], bool)
    m = run_metrics(t, r, 0.1, compute_s=0.08, decisions=4, turning=turning)
    assert m.success[1] == pytest.approx(4 / 8) and m.failure == pytest.approx(4 / 8)
    assert m.failure_turning == pytest.approx(3 / 8)  # frames 2, 3, 6 failed in a slew; 5 failed at rest
    assert m.no_pose == pytest.approx(1 / 8)
    assert m.longest_failure == pytest.approx(0.2)
    assert m.compute_ms == pytest.approx(10.0) and m.compute_ms_decision == pytest.approx(20.0)
    assert math.isnan(run_metrics(t, r, 0.1, 0.0).failure_turning)  # not known without the slews
    assert longest_streak(np.array([1, 1, 0, 1, 1, 1, 0], bool)) == 3


def test_aggregate_reports_the_turning_failures_over_runs():
    runs = [run_metrics(np.array([0.01, 1.0]), np.zeros(2), 0.1, 0.0, turning=np.array([False, k == 0]))
            for k in range(2)]
    out = aggregate(runs)
    assert out["failure_turning"].mean == pytest.approx(0.25) and out["failure"].mean == pytest.approx(0.5)
