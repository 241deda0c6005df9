"""End to end: pivotd under a systemd-like supervisor (NOTIFY_SOCKET, WATCHDOG_USEC) with --record."""

from __future__ import annotations

import os
import re
import signal
import socket

import pytest
from mcap.reader import make_reader
from support import PYTHON, REPO, ManagedProcess, child_env, free_tcp_port, wait_until

from pivotd.bus.messages import JOINT_STATE, ODOMETRY, PATH, deserialize
from pivotd.bus.session import open_session
from pivotd.bus.topics import status_key_for
from pivotd.cli.status import query_status
from pivotd.config import load_config
from pivotd.daemon.recorder import CONFIG_ATTACHMENT, RecordingFiles, map_checksum
from pivotd.sim.launch import derive_config
from pivotd.version import version

pytestmark = [pytest.mark.slow, pytest.mark.timeout(120)]


def test_notify_watchdog_and_mcap_recording(tmp_path):
    sock_path = tmp_path / "notify.sock"
    sock = socket.socket(socket.AF_UNIX, socket.SOCK_DGRAM)
    sock.bind(str(sock_path))
    sock.settimeout(0.2)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    config = derive_config(REPO / "config" / "demo.yaml", tmp_path / "pivotd.yaml",
                           {"zenoh.listen": [endpoint], "gimbal.port": "mock://"})
    record = tmp_path / "run.mcap"
    messages: list[str] = []

    def drain() -> None:
        while True:
            try:
                messages.append(sock.recv(4096).decode())
            except TimeoutError:
                return

    env = child_env(NOTIFY_SOCKET=str(sock_path), WATCHDOG_USEC="1000000")
    with ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config), "--record", str(record)], "pivotd",
                        env=env) as daemon:
        assert wait_until(lambda: drain() or any("READY=1" in m for m in messages), 30), daemon.output()
        sim_cmd = [PYTHON, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--connect", endpoint,
                   "--rate", "50", "--duration", "60", "--quiet", "--wait-subscribers", "10"]

        def tracking_reported() -> bool:
            return any(m.startswith("STATUS=tracking; gimbal link up; ") and "landmarks in view" in m
                       for m in messages)

        session = open_session(connect=[endpoint])

        def poses_taken() -> int:  # poses the daemon decoded and accepted: the ones it records
            doc = query_status(session, status_key_for("demo"), 1.0).get("demo", {})
            return doc.get("bus", {}).get("/odom", {}).get("accepted", 0)

        try:
            with ManagedProcess(sim_cmd, "sim_pose") as sim:
                # systemctl status shows what the daemon does: a STATUS= line while tracking the simulated robot
                # (waited for while the robot walks, until the daemon has taken the poses the recording is checked
                # for below; then the robot stops)
                assert wait_until(lambda: drain() or (tracking_reported() and poses_taken() > 110), 60), \
                    [m for m in messages if m.startswith("STATUS=")]
                assert sim.stop(signal.SIGTERM, timeout=20) == 0, sim.output()
        finally:
            session.close()
        # the watchdog is fed at least every 0.5 s (WATCHDOG_USEC 1 s) while the control loop runs
        assert wait_until(lambda: drain() or sum("WATCHDOG=1" in m for m in messages) >= 6, 30), messages
        statuses = [m for m in messages if m.startswith("STATUS=")]
        assert all("\n" not in m for m in statuses)
        daemon.send_signal(signal.SIGHUP)
        assert wait_until(lambda: drain() or any("RELOADING=1" in m for m in messages), 10), daemon.output()
        assert any("MONOTONIC_USEC=" in m for m in messages if "RELOADING=1" in m)
        assert daemon.stop(signal.SIGTERM, timeout=20) == 0, daemon.output()
    drain()
    sock.close()
    assert any("STOPPING=1" in m for m in messages)
    first_ready = next(i for i, m in enumerate(messages) if "READY=1" in m)
    first_stop = next(i for i, m in enumerate(messages) if "STOPPING=1" in m)
    assert first_ready < first_stop

    # --record run.mcap wrote one new file named after it with its UTC start time (never run.mcap itself)
    files = RecordingFiles(record).existing()
    assert len(files) == 1 and re.fullmatch(r"run-\d{8}-\d{6}\.mcap", files[0].name), files
    assert not record.exists()
    record = files[0]
    # The recording is a valid MCAP with ROS 2 schemas: rosbags decodes every message.
    counts: dict[str, int] = {}
    with open(record, "rb") as fh:
        reader = make_reader(fh)
        assert reader.get_header().profile == "ros2"
        # it carries the run: the config text, the map (its checksum and its file), pivotd's version
        attachments = {a.name: a.data for a in reader.iter_attachments()}
        metadata = {m.name: m.metadata for m in reader.iter_metadata()}
        cfg = load_config(config)
        assert attachments[CONFIG_ATTACHMENT] == config.read_bytes()
        assert attachments[f"map/{cfg.map.file.name}"] == cfg.map.file.read_bytes()
        assert metadata["pivotd.map"]["sha256"] == map_checksum(cfg.map.file)[0]
        assert metadata["pivotd"]["version"] == version() and metadata["pivotd"]["part"] == "1"
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            deserialize(message.data, schema.name, channel.topic)
            counts[schema.name] = counts.get(schema.name, 0) + 1
    assert counts.get(ODOMETRY, 0) > 100, counts
    assert counts.get(JOINT_STATE, 0) > 100, counts
    assert counts.get(PATH, 0) >= 2, counts
    assert os.path.getsize(record) > 10_000
