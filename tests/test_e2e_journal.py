"""End to end: pivotd with its stderr as the journal's stream (``$JOURNAL_STREAM`` naming it, as systemd sets it).

Each line carries its sd-daemon priority prefix and no timestamp; the ready line names the version; every state
change (first pose, first path, tracking, a pose gap and its end) is one line; SIGTERM with the gimbal's link down
(the simulator killed) stops at once instead of waiting out the park timeout.
"""

from __future__ import annotations

import re
import signal

import pytest
from support import PYTHON, ManagedProcess, free_tcp_port, wait_until
from test_e2e_daemon import start_mock_gimbal, start_sim, write_config

from pivotd.bus.probe import BusProbe
from pivotd.config import load_config
from pivotd.version import version

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

#: far longer than the test waits for the exit: the old daemon waited it out with the link down
PARK_TIMEOUT_S = 200.0
PREFIXED = re.compile(r"^<([0-7])>(DEBUG|INFO|WARNING|ERROR|CRITICAL) ")


def start_journal_daemon(config) -> ManagedProcess:
    """pivotd whose ``$JOURNAL_STREAM`` is the device:inode of its own stderr (a pipe here, a socket under systemd)."""
    script = 'JOURNAL_STREAM=$(stat -L -c %d:%i /proc/self/fd/2) exec "$@"'
    return ManagedProcess(["sh", "-c", script, "sh", PYTHON, "-m", "pivotd.cli", "--config", str(config)], "pivotd")


def lines_with(lines: list[str], needle: str) -> list[str]:
    return [line for line in lines if needle in line]


def test_journal_priorities_state_lines_once_and_prompt_stop_with_the_link_down(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, _ = start_mock_gimbal(tmp_path)
    config = write_config(tmp_path, endpoint, url, **{"gimbal.park_timeout_s": PARK_TIMEOUT_S})
    cfg = load_config(config)
    pose_topic = cfg.topics.pose
    with mock, start_journal_daemon(config) as daemon:
        probe = None
        try:
            assert wait_until(lambda: daemon.returncode is not None or daemon.wait_stderr(" ready: ", 0), 30), \
                daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            with start_sim(endpoint, "--speed", "1.2", "--duration", "60", "--gap", "5:2") as sim:
                assert wait_until(lambda: probe.status.get("state") == "tracking", 30), daemon.output()
                assert daemon.wait_stderr(f"poses on {pose_topic} again after a gap", 40), daemon.output()
                assert sim.stop(signal.SIGTERM, timeout=20) == 0, sim.output()
            # the end of the walk is a second stale episode: wait for its WARNING before the link goes down (a link
            # down first, on a loaded machine, would report that instead)
            stale = f"no pose on {pose_topic} for "
            assert wait_until(lambda: len(lines_with(list(daemon.stderr), stale)) >= 2, 30), daemon.output()
            assert probe.status.get("version") == version()
            mock.kill()  # the gimbal is gone: its link goes down
            assert wait_until(lambda: probe.status.get("link") not in ("up", None), 30), daemon.output()
            code = daemon.stop(signal.SIGTERM, timeout=60)
            assert code == 0, daemon.output()
        finally:
            if probe is not None:
                probe.close()
    lines = [line for line in daemon.stderr if line]
    unprefixed = [line for line in lines if not PREFIXED.match(line)]
    assert not unprefixed, daemon.output()
    levels = {"DEBUG": "7", "INFO": "6", "WARNING": "4", "ERROR": "3", "CRITICAL": "2"}
    assert all(levels[PREFIXED.match(line)[2]] == PREFIXED.match(line)[1] for line in lines), daemon.output()
    assert not [line for line in lines if re.search(r"\d{4}-\d\d-\d\d \d\d:\d\d:\d\d", line)], daemon.output()
    assert len(lines_with(lines, f"pivotd {version()} 'demo' ready: ")) == 1, daemon.output()
    for once in (f"INFO pivotd.daemon: first pose on {pose_topic}: robot at [",
                 f"INFO pivotd.daemon: first path on {cfg.topics.path}: ",
                 "INFO pivotd.daemon: tracking: the gimbal follows the plan"):
        assert len(lines_with(lines, once)) == 1, (once, daemon.output())
    # the gap, and the end of the walk: each stale episode one WARNING, each end of one an INFO, alternating
    edges = [line for line in lines
             if f"no pose on {pose_topic} for " in line or f"poses on {pose_topic} again" in line]
    assert len(edges) >= 3, daemon.output()
    assert all(line.startswith("<4>WARNING") == (i % 2 == 0) for i, line in enumerate(edges)), edges
    assert all(line.startswith("<6>INFO") == (i % 2 == 1) for i, line in enumerate(edges)), edges
    assert len(lines_with(lines, "<4>WARNING pivotd.daemon: gimbal link down: not parking")) == 1, daemon.output()
    assert not lines_with(lines, "park pose not reached"), daemon.output()
