"""`pivotd bench horizon`: the side-by-side comparison with another version's planner."""

import argparse
import json

import pytest

from pivotd.bench import horizon
from pivotd.errors import InputError


def _args(tmp_path, **kw):
    parser = argparse.ArgumentParser()
    horizon.configure(parser)
    argv = ["--landmarks", "3000", "--horizon", "8", "--replans", "6", "--json", str(tmp_path / "h.json")]
    for k, v in kw.items():
        argv += [f"--{k.replace('_', '-')}", str(v)]
    return parser.parse_args(argv)


def test_compare_with_the_same_version_plans_the_same(tmp_path):
    # the current package as the "other" version: interleaved replans of identical code see the same landmarks
    assert horizon.run(_args(tmp_path, compare_with="pivotd")) == 0
    out = json.loads((tmp_path / "h.json").read_text())
    assert out["compare_with"] == "pivotd"
    assert out["visible_vs_other"] == pytest.approx(1.0)
    assert out["other_replan_cpu_ms_p50"] > 0 and out["cpu_p50_ratio_vs_other"] > 0


def test_compare_with_a_missing_package_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="--compare-with no_such_pivotd_copy"):
        horizon.run(_args(tmp_path, compare_with="no_such_pivotd_copy"))


def test_the_daemons_planner_is_timed_warm_and_on_new_paths(tmp_path):
    from pivotd.config import load_config
    from pivotd.sim.launch import REPO

    assert horizon.run(_args(tmp_path, replans=40, step=2.0)) == 0  # 80 m: more than one pass
    out = json.loads((tmp_path / "h.json").read_text())
    assert out["new_paths"] >= 1 and out["new_path_cpu_ms_max"] > 0  # the hallway wrapped at least once
    assert out["replan_cpu_ms_p50"] > 0 and out["cold_start_ms"] > 0
    cfg = load_config(REPO / "config" / "demo.yaml")
    assert cfg.planner.rescue_blind  # the daemon's defaults: what is timed is what runs


def test_a_bad_speed_is_a_clear_error(tmp_path):
    with pytest.raises(InputError, match="--speed"):
        horizon.run(_args(tmp_path, speed=0))
