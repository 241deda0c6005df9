"""End to end: pivotd in client mode (config/spot.yaml's mode) started before its Zenoh router, as at boot.

It says once that it waits and for which router, keeps the gimbal held (the link and the control loop run, no
motion) and stays responsive to SIGTERM while it waits; once a router comes up it connects and reports its status.
The router is a zenoh-python session in router mode on loopback (what ``zenohd`` does).
"""

from __future__ import annotations

import signal
from pathlib import Path

import numpy as np
import pytest
from bus_support import open_client, open_router
from support import PYTHON, REPO, ManagedProcess, free_tcp_port, wait_until

from pivotd.cli.status import query_status
from pivotd.sim.analysis import read_device_log
from pivotd.sim.launch import derive_config

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

DEMO = REPO / "config" / "demo.yaml"


def start_mock_gimbal(tmp: Path) -> tuple[ManagedProcess, str, Path]:
    log = tmp / "gimbal.csv"
    mock = ManagedProcess([PYTHON, str(REPO / "tools" / "mock_gimbal"), "--tcp", "127.0.0.1:0", "--log", str(log)],
                          "mock_gimbal")
    line = mock.wait_stdout(lambda s: s.strip().isdigit(), 15)
    assert line, mock.output()
    return mock, f"socket://127.0.0.1:{line.strip()}", log


def client_daemon(tmp: Path, endpoint: str, port_url: str) -> ManagedProcess:
    config = derive_config(DEMO, tmp / "pivotd.yaml", {"zenoh.mode": "client", "zenoh.listen": [],
                                                        "zenoh.connect": [endpoint], "gimbal.port": port_url})
    return ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config)], "pivotd")


def waiting_lines(daemon: ManagedProcess, endpoint: str) -> list[str]:
    return [line for line in list(daemon.stderr) if f"waiting for the Zenoh router at {endpoint}" in line]


def test_without_a_router_it_waits_holding_the_gimbal_then_connects_when_one_comes_up(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path)
    router = client = None
    with mock, client_daemon(tmp_path, endpoint, url) as daemon:
        try:
            assert wait_until(lambda: waiting_lines(daemon, endpoint) or daemon.returncode is not None, 60), \
                daemon.output()
            assert daemon.returncode is None, daemon.output()
            # Meanwhile the gimbal link is up and fed: setpoints that hold it where it stands (no motion).
            assert wait_until(lambda: read_device_log(dev_log).sp_pos.shape[0] >= 300, 60), daemon.output()
            assert daemon.returncode is None, daemon.output()
            dev = read_device_log(dev_log)
            assert np.ptp(dev.sp_pos, axis=0).max() < 1e-6, np.ptp(dev.sp_pos, axis=0)
            assert np.abs(dev.sp_rate).max() < 1e-6
            # It kept retrying (still no "ready") and said so once.
            assert not daemon.wait_stderr("ready:", 0)
            assert len(waiting_lines(daemon, endpoint)) == 1, daemon.output()

            router = open_router(endpoint)
            assert daemon.wait_stderr("ready:", 60), daemon.output()
            assert daemon.wait_stderr(f"Zenoh router at {endpoint} reached after", 5), daemon.output()
            client = open_client(endpoint)
            docs: dict = {}

            def published() -> bool:  # the queryable answers "starting" until the first status document
                docs.update(query_status(client, "pivot/demo/status", 1.0))
                return docs.get("demo", {}).get("link") == "up"

            assert wait_until(published, 60, 0.5), (docs, daemon.output())
            assert docs["demo"]["state"] == "waiting", docs  # tracking needs poses: there are none here
            assert daemon.stop(signal.SIGTERM, timeout=30) == 0, daemon.output()
        finally:
            if client is not None:
                client.close()
            if router is not None:
                router.close()


def test_sigterm_while_waiting_for_the_router_exits_cleanly(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path)
    with mock, client_daemon(tmp_path, endpoint, url) as daemon:
        assert wait_until(lambda: waiting_lines(daemon, endpoint) or daemon.returncode is not None, 60), \
            daemon.output()
        assert daemon.returncode is None, daemon.output()
        assert wait_until(lambda: read_device_log(dev_log).sp_pos.shape[0] >= 50, 60), daemon.output()
        daemon.send_signal(signal.SIGHUP)  # answered while waiting, too
        assert daemon.wait_stderr("reloaded", 30), daemon.output()
        assert daemon.stop(signal.SIGTERM, timeout=60) == 0, daemon.output()
        assert daemon.wait_stderr("pivotd stopped", 5), daemon.output()
    assert any(kind == "rx:ENABLE" and "on=0" in detail for kind, _, detail in read_device_log(dev_log).other)
