"""End to end: the daemon's first view plan on a path is the first plan of ``pivotd plan --config`` on it.

A real `pivotd` (in-process mock gimbal, Zenoh on loopback) gets the path, then a pose at the path's start as
``pivotd plan --config`` places the robot there; its first view plan, as published, must equal the offline tool's
first replan on the same config, map and path: same camera positions and directions.
"""

from __future__ import annotations

import json
import subprocess
import time

import numpy as np
import pytest
from support import PYTHON, REPO, child_env, free_tcp_port, wait_until
from test_e2e_daemon import start_daemon, write_config

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.probe import BusProbe
from pivotd.config import load_config
from pivotd.daemon.offline import path_message, robot_poses
from pivotd.geometry import quat_to_matrix
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import load_path

pytestmark = [pytest.mark.slow, pytest.mark.timeout(240)]

#: the path: the demo hallway's first 30 points (14.5 m, through its first bend; longer than the horizon)
PATH_POINTS = 30


def _offline_first_plan(config, path_csv, out) -> dict:
    proc = subprocess.run([PYTHON, "-m", "pivotd.cli", "plan", "--config", str(config), "--path", str(path_csv),
                           "--first-plan-out", str(out), "--json"], capture_output=True, text=True, env=child_env(),
                          cwd=REPO, timeout=180)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["replans"] > 1 and summary["first_plan_out"] == str(out)
    return json.loads(out.read_text())


def test_the_daemons_first_plan_on_a_path_is_plan_configs_first_plan(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    # the gimbal at its park pose when the daemon starts: the mock device stands at 0, 0
    config = write_config(tmp_path, endpoint, "mock://", **{"gimbal.park": {"pan_deg": 0, "tilt_deg": 0},
                                                            "ros.markers": False})
    cfg = load_config(config)
    path_csv = tmp_path / "path.csv"
    np.savetxt(path_csv, hallway().path[:PATH_POINTS], delimiter=",", fmt="%.6f")
    path = load_path(path_csv)
    offline = _offline_first_plan(config, path_csv, tmp_path / "first.json")
    assert offline["path_mode"] == "on_path" and len(offline["directions"]) == cfg.planner.horizon
    poses = robot_poses(path, cfg.planner.waypoint_spacing)
    start, quat = poses.positions[0], poses.quats[0]
    np.testing.assert_array_equal(offline["body_position"], start)
    np.testing.assert_array_equal(offline["body_quat"], quat)

    with start_daemon(config) as daemon:
        probe = node = None
        try:
            assert wait_until(lambda: daemon.returncode is not None or daemon.wait_stderr("ready", 0), 60), \
                daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            node = ros.RosNode(probe.session, "route_planner")
            path_pub = node.publisher(cfg.topics.path, m.PATH, cfg.ros.qos.path)
            pose_pub = node.publisher(cfg.topics.pose, cfg.topics.pose_type)
            positions, quats = path_message(path)
            path_pub.put(m.encode_path(time.time(), cfg.topics.frame_id, positions, quats))
            # the path is in the daemon before the first pose: its first replan is on the path
            assert wait_until(lambda: (probe.status.get("planner") or {}).get("path_points") == PATH_POINTS, 30), \
                daemon.output()
            assert not probe.plans

            def first_plan_arrived() -> bool:
                pose_pub.put(m.encode_pose(cfg.topics.pose_type, time.time(), cfg.topics.frame_id, start, quat))
                return bool(probe.plans)

            assert wait_until(first_plan_arrived, 60, interval=0.05), daemon.output()
            first = probe.plans[0]
            path_pub.close()
            pose_pub.close()
        finally:
            if node is not None:
                node.close()
            if probe is not None:
                probe.close()
    directions = quat_to_matrix(first.quats)[:, :, 2]  # the view plan's camera +z axes
    np.testing.assert_allclose(first.positions, offline["positions"], rtol=0, atol=1e-9)
    np.testing.assert_allclose(directions, offline["directions"], rtol=0, atol=1e-6)
