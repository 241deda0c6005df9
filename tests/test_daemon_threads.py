"""A thread of the daemon that must not die and does: the status says so instead of the last tick's state, and a stop
does not wait for a park that cannot happen (pivotd/daemon/daemon.py)."""

from __future__ import annotations

import contextlib

import pytest
from support import REPO, free_tcp_port, wait_until

from pivotd.daemon.daemon import Daemon
from pivotd.gimbal.interface import LinkState
from pivotd.sim.launch import derive_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


def test_a_dead_control_thread_makes_the_state_failed_and_names_it(tmp_path):
    config = derive_config(REPO / "config" / "demo.yaml", tmp_path / "pivotd.yaml",
                           {"zenoh.listen": [f"tcp/127.0.0.1:{free_tcp_port()}"], "gimbal.port": "mock://"})
    daemon = Daemon(config)
    try:
        daemon._start()
        assert wait_until(lambda: daemon.link.link_state == LinkState.UP, 30)
        assert wait_until(lambda: daemon.control.stats.ticks > 10, 30)
        st = daemon.status()
        assert st["state"] == "waiting" and st["threads_dead"] == [], st
        control = next(t for t in daemon._threads if t.name == "pivotd-control")
        # End the real control thread while no stop was asked for (only a bug could do that in a running daemon).
        daemon._halt.set()
        control.join(10)
        daemon._halt.clear()
        assert not control.is_alive()
        st = daemon.status()
        assert st["state"] == "failed" and st["threads_dead"] == ["pivotd-control"], st
        assert st["last_error"]["message"] == "daemon: thread pivotd-control died", st["last_error"]
        daemon.request_stop()
        daemon._park()  # returns at once: nothing can move the gimbal without the control thread
        assert daemon.state != "parking"
    finally:
        daemon._stop.set()
        daemon._halt.set()
        for t in daemon._threads:
            t.join(5)
        for close in (lambda: daemon.link.stop(disable=True), daemon.bus.close, daemon.session.close):
            with contextlib.suppress(Exception):
                close()
        daemon.worker.close()
