"""The planner thread's schedule and SIGHUP reloads: absolute deadlines that early wakes do not move, coalesced
reloads, and reloads that keep the running plan (docs/design/daemon.md, pivotd.daemon.reload).

The daemon here is a real :class:`~pivotd.daemon.daemon.Daemon` with its real planner process, driven without a
bus or a gimbal: the planner loop runs in a thread and the tests do what the SIGHUP handler does.
"""

from __future__ import annotations

import logging
import os
import signal
import subprocess
import sys
import threading
from dataclasses import replace

import numpy as np
import pytest
from gimbal_fakes import pose_at
from support import REPO, wait_until

from pivotd.config import load_config
from pivotd.daemon.daemon import Daemon
from pivotd.daemon.reload import plan_reload
from pivotd.daemon.wiring import map_files_identity
from pivotd.sim.launch import derive_config

DEMO = REPO / "config" / "demo.yaml"
STORM = 300


def hup(d: Daemon) -> None:
    """What the daemon's SIGHUP handler does."""
    d._reload_requests += 1
    d._planner_wake.set()


@pytest.fixture
def make_daemon(tmp_path):
    made: list[tuple[Daemon, threading.Thread | None]] = []

    def make(changes: dict, loop: bool) -> Daemon:
        config = derive_config(DEMO, tmp_path / "pivotd.yaml", {"control.pose_timeout_s": 1e6, **changes})
        d = Daemon(config)
        d.pose = replace(pose_at(0.0), position=np.array([2.0, 0.0, 0.7]))  # never stale (pose_timeout_s)
        t = threading.Thread(target=d._planner_loop, name="test-planner", daemon=True) if loop else None
        if t is not None:
            t.start()
        made.append((d, t))
        return d

    yield make
    for d, t in made:
        d.request_stop()
        if t is not None:
            t.join(30)
        d.worker.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_storm_of_sighups_does_not_stop_replanning(make_daemon):
    d = make_daemon({"planner.replan_hz": 2}, loop=True)
    assert wait_until(lambda: d._plans >= 2, 60)
    for _ in range(STORM):  # each one taken by the planner thread before the next (the worst case for a schedule)
        hup(d)
        assert wait_until(lambda: d._reload_served == d._reload_requests, 30, 0.001)
    assert d._reloads + d._reload_errors >= 1
    after_storm = d._plans
    # Replanning goes on at replan_hz (2 Hz): three more plans come within a few periods, not minutes later.
    assert wait_until(lambda: d._plans >= after_storm + 3, 30), (d._plans, after_storm)
    status = d.status()
    assert status["reload_requests"] == STORM and status["reload_errors"] == 0
    assert status["reloads"] + status["reloads_coalesced"] == STORM


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_storm_of_real_sighups_is_answered_and_never_deadlocks_the_main_thread(make_daemon):
    """SIGHUPs sent to this process by another one every 0.5 ms, handled by the daemon's own handler in the main thread
    (waiting on an Event, as in Daemon.run), while two threads compete for the interpreter lock at the daemon's switch
    interval. A handler that takes a lock (threading.Event.set) hangs here: the next SIGHUP interrupts it while it
    holds the lock, and the nested handler waits for that lock for ever."""
    d = make_daemon({}, loop=True)
    saved = {s: signal.getsignal(s) for s in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)}
    switch = sys.getswitchinterval()
    busy_stop = threading.Event()

    def busy() -> None:
        x = 0
        while not busy_stop.is_set():
            x += 1

    busy_threads = [threading.Thread(target=busy, daemon=True) for _ in range(2)]
    try:
        sys.setswitchinterval(0.0005)
        d._install_signals()
        for t in busy_threads:
            t.start()
        sender = subprocess.Popen([sys.executable, "-c", "import os, time\nfor _ in range(3000):\n"
                                   f"    os.kill({os.getpid()}, 1)\n    time.sleep(0.0005)"])
        while sender.poll() is None:
            d._stop.wait(0.01)
        d._stop.wait(0.01)
    finally:
        busy_stop.set()
        for t in busy_threads:
            t.join()
        sys.setswitchinterval(switch)
        for s, handler in saved.items():
            signal.signal(s, handler)
    assert sender.returncode == 0
    assert d._reload_requests >= 1  # the kernel merges SIGHUPs still pending: fewer than were sent
    # every SIGHUP answered, and the last reload finished (a reload under way counts in neither reloads nor errors)
    assert wait_until(lambda: d._reload_served == d._reload_requests
                      and d._reloads + d._reload_errors == d._reload_runs, 30)
    status = d.status()
    assert status["reloads"] + status["reloads_coalesced"] == status["reload_requests"], status
    assert status["reload_errors"] == 0


@pytest.mark.slow
@pytest.mark.timeout(120)
def test_a_storm_of_real_sigterms_and_sighups_never_deadlocks_the_main_thread_and_stops_it(make_daemon):
    """SIGTERM must always stop the daemon: its handler, like SIGHUP's, takes no lock and does not log (the main
    thread logs the signal). SIGTERMs and SIGHUPs alternate every 0.5 ms while the main thread waits on the stop flag
    as Daemon.run does; a handler interrupted inside a lock by the next one would hang here."""
    d = make_daemon({}, loop=True)
    saved = {s: signal.getsignal(s) for s in (signal.SIGHUP, signal.SIGTERM, signal.SIGINT)}
    switch = sys.getswitchinterval()
    sender = None
    try:
        sys.setswitchinterval(0.0005)
        d._install_signals()
        sender = subprocess.Popen([sys.executable, "-c", "import os, time\nfor i in range(3000):\n"
                                   f"    os.kill({os.getpid()}, 15 if i % 2 else 1)\n    time.sleep(0.0005)"])
        while sender.poll() is None:
            d._stop.wait(0.01)
    finally:
        if sender is not None and sender.poll() is None:  # a handler raised: stop the storm before the defaults
            sender.kill()
            sender.wait()
        sys.setswitchinterval(switch)
        for s, handler in saved.items():
            signal.signal(s, handler)
    assert sender.returncode == 0
    assert d._stop.is_set() and d._stop_signal == signal.SIGTERM


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_sighups_while_a_reload_is_pending_coalesce_and_are_counted(make_daemon):
    d = make_daemon({}, loop=False)  # no planner thread: the requests pile up as during a long reload
    for _ in range(50):
        hup(d)
    d._reload_served, d._reload_runs = d._reload_requests, d._reload_runs + 1  # what the planner loop does
    d._do_reload()
    hup(d)  # one more after it
    d._reload_served, d._reload_runs = d._reload_requests, d._reload_runs + 1
    d._do_reload()
    status = d.status()
    assert (status["reload_requests"], status["reloads"], status["reloads_coalesced"]) == (51, 2, 49)


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_reload_that_changes_nothing_keeps_the_plan_and_does_not_ask_the_planner(make_daemon, caplog):
    d = make_daemon({}, loop=False)
    d._replan_once()
    running = d.plan
    assert running is not None
    requests = d.worker._next_id
    with caplog.at_level(logging.INFO, logger="pivotd.daemon"):
        d._do_reload()
    assert d._reloads == 1 and d._reload_errors == 0
    assert d.plan is running  # the control loop never lost its plan
    assert d.worker._next_id == requests  # the planner process (and its map) was not asked at all
    assert "no setting changed; planner and map kept" in caplog.text


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_reload_with_new_planning_settings_tracks_the_running_plan_until_the_new_one(make_daemon, caplog):
    d = make_daemon({}, loop=False)
    d._replan_once()
    running = d.plan
    config = d.config_path
    config.write_text(config.read_text().replace("lambda: 0.6", "lambda: 0.3"))
    with caplog.at_level(logging.INFO, logger="pivotd.daemon"):
        d._do_reload()
    assert d._reloads == 1 and d.cfg.pivot.lam == 0.3
    assert d.plan is running  # tracked until the first plan made with the new settings
    assert "applied: pivot.lam; map kept" in caplog.text
    d._replan_once()  # a replan is due at once (new planner)
    assert d.plan is not running and d._plans == 2

    # The map file rewritten on disk (same settings): read again, the plan still kept until the next one.
    map_file = d.cfg.map.file
    st = map_file.stat()
    os.utime(map_file, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))
    running = d.plan
    caplog.clear()
    with caplog.at_level(logging.INFO, logger="pivotd.daemon"):
        d._do_reload()
    assert d._reloads == 2 and d.plan is running
    assert "no setting changed (a map file changed on disk); map read again" in caplog.text


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_a_reload_with_a_new_mount_drops_the_running_plan(make_daemon):
    d = make_daemon({}, loop=False)
    d._replan_once()
    assert d.plan is not None
    config = d.config_path
    derive_config(config, config, {"gimbal.mount": {"xyz": [0.1, 0.0, 0.5], "rpy_deg": [0, 0, 0]}})
    d._do_reload()
    assert d._reloads == 1 and d.plan is None  # held until the first plan made with the new mount
    assert np.allclose(d.cfg.gimbal.mount.translation, [0.1, 0.0, 0.5])


def test_an_unchanged_map_file_is_not_read_again_and_a_changed_one_is(tmp_path):
    cfg = load_config(derive_config(DEMO, tmp_path / "pivotd.yaml", {}))
    identity = map_files_identity(cfg)
    same = plan_reload(cfg, cfg, identity)
    assert not same.map_file_changed and not same.reload_map and not same.reload_planner and same.keeps_plan
    lam = plan_reload(cfg, replace(cfg, pivot=replace(cfg.pivot, lam=0.3)), identity)
    assert lam.reload_planner and not lam.reload_map and lam.keeps_plan
    copy = tmp_path / "map.txt"
    copy.write_bytes(cfg.map.file.read_bytes())
    moved = plan_reload(cfg, replace(cfg, map=replace(cfg.map, file=copy)), identity)
    assert moved.applied == ("map.file",) and moved.reload_map
    local = replace(cfg, map=replace(cfg.map, file=copy))
    identity = map_files_identity(local)
    assert not plan_reload(local, local, identity).reload_planner
    copy.write_bytes(copy.read_bytes() + b"1.0 2.0 3.0\n")  # same path, new content
    changed = plan_reload(local, local, identity)
    assert changed.map_file_changed and changed.reload_map and changed.applied == ()
