"""End to end: a storm of SIGHUPs to a real tracking daemon (pivotd.bench.soak's ``reload_storm``): the reloads
coalesce and are counted, replanning goes on, and the control loop keeps tracking the running plan throughout."""

from __future__ import annotations

import time

import pytest

from pivotd.bench.soak import RELOAD_STORM, SoakStack, check_device_log, count_tracebacks

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

RECOVER_S = 60.0  # generous: a shared machine


def test_a_reload_storm_keeps_replanning_and_tracking(tmp_path):
    with SoakStack(tmp_path, seed=5) as stack:
        assert stack.wait_healthy(RECOVER_S) is not None, (tmp_path / "pivotd.log").read_text()[-3000:]
        t0 = time.time()
        event = stack.inject("reload_storm")
        plans = stack.status["planner"]["plans"]

        def replanned(st: dict) -> bool:  # every SIGHUP it received answered, and plans made after the storm
            answered = st.get("reloads", 0) + st.get("reload_errors", 0) + st.get("reloads_coalesced", 0)
            return 0 < st.get("reload_requests", 0) == answered and st["planner"]["plans"] >= plans + 5

        assert stack.wait(replanned, RECOVER_S) is not None, (event, stack.status)
        st = stack.status
        # The kernel merges SIGHUPs still pending (a standard signal is pending at most once): the daemon counts
        # the ones it received, and a storm of them is a few reloads, the rest coalesced.
        assert st["reload_errors"] == 0 and 1 <= st["reloads"] < st["reload_requests"] <= RELOAD_STORM, st
        # No reload dropped the plan: the daemon tracked during the storm and after it (a reload that changes
        # nothing leaves the plan alone; one that stopped replanning would let it go stale and hold).
        during = [s["state"] for s in list(stack.probe.statuses) if s.get("time", 0) > t0]
        assert during and set(during) == {"tracking"}, during
        log = (tmp_path / "pivotd.log").read_text()
        assert "no setting changed; planner and map kept" in log
        assert "map read again" not in log
        assert stack.stop_daemon() == 0
    assert check_device_log(stack.cfg, tmp_path / "gimbal.csv").beyond_limits == 0
    assert count_tracebacks(tmp_path / "pivotd.log")[0] == 0
