"""`pivotd bench montecarlo --pareto`: plans judged against the exact step-limited grid plan, side by side."""

import pytest

from pivotd.bench.montecarlo import pareto_rows
from pivotd.errors import InputError


@pytest.mark.slow  # exact step-limited grid references (seconds of CPU), like the exhaustive tests in conftest
def test_pareto_compare_with_the_same_version_judges_the_same_plan(capsys):
    # the current package as the "other" version: identical plans, both timed in the same interleaved run
    (row,) = pareto_rows(families=False, compare_with="pivotd", only=("competing_clusters",))
    assert row["scene"] == "competing_clusters" and row["other"] == "pivotd"
    assert row["other_own_step_pct"] == row["own_step_pct"] >= 99.5
    assert row["other_max_step_deg"] == row["max_step_deg"]
    assert row["other_ms"] > 0 and row["speedup_vs_other"] > 0 and row["speedup_vs_grid"] > 0
    assert "this tree is" in capsys.readouterr().out


def test_pareto_compare_with_a_missing_package_is_a_clear_error():
    with pytest.raises(InputError, match="--compare-with no_such_pivotd_copy"):
        pareto_rows(families=False, compare_with="no_such_pivotd_copy", only=("competing_clusters",))
