"""End to end with ``topics.wire: ros2dds_bridge``: a real `pivotd` and `tools/mock_gimbal`; the DDS robot behind
zenoh-bridge-ros2dds (namespace ``/robot1``) is played by a plain Zenoh session of the test on loopback (scouting
off, free ports): bare CDR built by rosbags on the bridge's keys, no attachment, no liveliness token.

The path is latched before the daemon starts (a transient-local writer, routed through a cache as the bridge does),
the pose streams at 50 Hz; the daemon tracks on the path, and a subscriber on the plain key receives its joint
states as bare CDR.
"""

from __future__ import annotations

import queue
import threading
import time

import numpy as np
import pytest
import zenoh.ext as zext
from bus_support import drain
from support import PYTHON, ManagedProcess, free_tcp_port, wait_until
from test_e2e_daemon import start_mock_gimbal, write_config

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.probe import BusProbe
from pivotd.bus.session import open_session
from pivotd.config import load_config
from pivotd.pivot.scenes import hallway
from pivotd.sim.routes import Route

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_daemon_tracks_a_dds_robot_through_the_bridges_plain_keys(tmp_path):
    bridge_endpoint, endpoint = f"tcp/127.0.0.1:{free_tcp_port()}", f"tcp/127.0.0.1:{free_tcp_port()}"
    bridge = open_session(listen=[bridge_endpoint])
    route = Route(hallway().path)
    plan = zext.declare_advanced_publisher(bridge, "robot1/plan", cache=zext.CacheConfig(max_samples=1),
                                           publisher_detection=True)
    plan.put(m.encode_path(1.0, "map", route.positions))
    odom = bridge.declare_publisher("robot1/odom")
    joints: queue.Queue = queue.Queue()
    joint_sub = bridge.declare_subscriber(
        "robot1/pivot/joint_states", lambda s: joints.put((s.payload.to_bytes(), s.attachment)))
    stop = threading.Event()

    def stream() -> None:
        t0, k = time.time(), 0
        while not stop.is_set():
            pose = route.at(min(0.02 * k * 0.5, route.length))
            odom.put(m.encode_odometry(t0 + 0.02 * k, "map", "base_link", pose.position, pose.quat))
            k += 1
            stop.wait(max(0.0, t0 + 0.02 * k - time.time()))

    streamer = threading.Thread(target=stream, daemon=True)
    mock, url, _ = start_mock_gimbal(tmp_path)
    config = write_config(tmp_path, endpoint, url, **{"topics.wire": "ros2dds_bridge", "topics.namespace": "/robot1",
                                                      "zenoh.connect": [bridge_endpoint]})
    cfg = load_config(config)
    probe = None
    try:
        with mock, ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config)], "pivotd") as daemon:
            assert wait_until(lambda: daemon.returncode is not None or daemon.wait_stderr("ready", 0), 30), \
                daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            streamer.start()
            assert wait_until(lambda: probe.status.get("state") == "tracking", 30), daemon.output()
            assert wait_until(lambda: (probe.status.get("planner") or {}).get("path_mode") == "on_path", 20), \
                probe.status
            bus = probe.status["bus"]
            assert bus["/robot1/odom"]["accepted"] > 0 and bus["/robot1/plan"]["accepted"] == 1, bus
            # joint states: bare CDR on the plain key, no attachment
            got = drain(joints, 5, timeout=20)
            assert len(got) == 5, daemon.output()
            for payload, attachment in got:
                assert attachment is None
                msg = ros.typestore().deserialize_cdr(payload, m.JOINT_STATE)
                assert list(msg.name) == ["pan", "tilt"] and np.all(np.isfinite(msg.position))
            tokens = [r for r in bridge.liveliness().get(f"{ros.ADMIN_SPACE}/**", timeout=2.0) if r.ok is not None]
            assert tokens == []
            stop.set()
            streamer.join(5)
            assert daemon.stop(timeout=20) == 0, daemon.output()
    finally:
        stop.set()
        if probe is not None:
            probe.close()
        joint_sub.undeclare()
        plan.undeclare()
        odom.undeclare()
        bridge.close()
