"""End to end: what the status document says after a stall of the daemon itself, a refused and a good reload
(docs/design/daemon.md, status document)."""

from __future__ import annotations

import os
import shutil
import signal
import time
from pathlib import Path

import pytest
from support import REPO

from pivotd.bench.soak import SoakStack

pytestmark = [pytest.mark.slow, pytest.mark.timeout(300)]

RECOVER_S = 60.0


def touch(path: Path) -> None:
    """Give ``path`` a later modification time (its content unchanged): the map file changed on disk."""
    st = path.stat()
    os.utime(path, ns=(st.st_atime_ns, st.st_mtime_ns + 1_000_000_000))


def test_a_stall_of_the_daemon_is_a_host_stall_not_a_link_loss_nor_a_fault_episode(tmp_path):
    with SoakStack(tmp_path, seed=4) as stack:
        assert stack.wait_healthy(90.0) is not None, stack.daemon_logs()
        before = stack.status
        counters = before["link_counters"]
        os.kill(stack.daemon.pid, signal.SIGSTOP)  # the whole daemon: control, link threads, supervision
        time.sleep(3.0)
        os.kill(stack.daemon.pid, signal.SIGCONT)
        resumed = time.time()
        assert stack.wait(lambda st: st["link_counters"].get("host_stalls", 0) > counters.get("host_stalls", 0),
                          RECOVER_S) is not None, stack.status
        assert stack.wait_healthy(RECOVER_S, since=resumed) is not None, stack.status
        after = stack.status
        assert after["link_counters"]["link_losses"] == counters["link_losses"], after["link_counters"]
        assert after["link_counters"]["reconnects"] == counters["reconnects"], after["link_counters"]
        # the device's watchdog held it during the stall (bit 4): cleared, but the host's stall, not a gimbal fault
        assert after["fault_episodes"] == before["fault_episodes"], after
        assert stack.stop_daemon() == 0


def test_last_error_has_its_time_and_clears_and_the_map_version_grows_with_each_reload(tmp_path):
    map_file = tmp_path / "map.txt"  # a copy the test may touch: a reload reads a map again only if it changed
    shutil.copyfile(REPO / "config" / "demo_hallway_map.txt", map_file)
    with SoakStack(tmp_path, seed=6, changes={"map.file": str(map_file)}) as stack:
        assert stack.wait_healthy(90.0) is not None, stack.daemon_logs()
        st = stack.status
        assert st["last_error"] is None and st["map"]["version"] >= 1, st
        good = stack.config_path.read_text()
        versions = [st["map"]["version"]]
        stack.daemon.send_signal(signal.SIGHUP)  # nothing changed: the map is kept, and so is its version
        assert stack.wait(lambda s: s["reloads"] == 1, RECOVER_S) is not None, stack.status
        assert stack.status["map"]["version"] == versions[0], stack.status["map"]
        touch(map_file)
        stack.daemon.send_signal(signal.SIGHUP)  # the map file changed: a new map store in the planner process
        assert stack.wait(lambda s: s["reloads"] == 2, RECOVER_S) is not None, stack.status
        versions.append(stack.status["map"]["version"])
        stack.config_path.write_text(good + "\nplanner: [unclosed\n")
        t_bad = time.time()
        stack.daemon.send_signal(signal.SIGHUP)
        assert stack.wait(lambda s: s["reload_errors"] == 1, RECOVER_S) is not None, stack.status
        err = stack.status["last_error"]
        assert err["source"] == "reload" and err["resolved_time"] is None, err
        assert str(stack.config_path) in err["message"] and t_bad <= err["time"] <= time.time(), err
        assert stack.status["map"]["version"] == versions[-1]  # refused: the map did not change
        stack.config_path.write_text(good)
        touch(map_file)
        stack.daemon.send_signal(signal.SIGHUP)
        assert stack.wait(lambda s: s["reloads"] == 3, RECOVER_S) is not None, stack.status
        cleared = stack.status["last_error"]
        assert cleared["message"] == err["message"] and cleared["time"] == err["time"], cleared
        assert cleared["resolved_time"] is not None and cleared["resolved_time"] >= err["time"], cleared
        versions.append(stack.status["map"]["version"])
        assert versions[0] < versions[1] < versions[2], versions
        assert stack.wait_healthy(RECOVER_S) is not None, stack.status
        assert stack.stop_daemon() == 0
