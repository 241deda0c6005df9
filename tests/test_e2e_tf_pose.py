"""End to end with the pose from TF: a real `pivotd` (``topics.pose_source: tf``) and `tools/mock_gimbal`, the robot
played by ROS nodes of the test on Zenoh (loopback, scouting off, free ports).

The chain is ``map -> odom`` (a localizer, 10 Hz) ``-> base_footprint`` (odometry, 50 Hz) ``-> base_link``
(latched on ``/tf_static`` before the daemon starts, as robot_state_publisher does). The daemon tracks on the
composed pose, records exactly the poses the nodes' transforms compose to, and holds when the localizer goes
quiet while odometry goes on, as it does for a silent pose topic.
"""

from __future__ import annotations

import itertools
import threading
import time

import numpy as np
import pytest
from support import PYTHON, ManagedProcess, free_tcp_port, wait_until
from test_e2e_daemon import start_mock_gimbal, write_config

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.probe import BusProbe
from pivotd.bus.qos import QoS
from pivotd.bus.session import open_session
from pivotd.config import load_config
from pivotd.geometry import matrix_to_quat, quat_to_matrix, yaw_to_matrix
from pivotd.pivot.scenes import hallway
from pivotd.sim.routes import Route
from pivotd.viz.figures import build_figure, joint_limits_deg, save_figure
from pivotd.viz.recording import read_recording

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]

LATCHED = QoS.named("reliable", "transient_local", 1)
R_MO, T_MO = yaw_to_matrix(np.deg2rad(30.0)), np.array([1.0, 2.0, 0.0])  # map -> odom
T_FB = np.array([0.0, 0.0, 0.05])  # base_footprint -> base_link (static, no rotation)
ID = np.array([0.0, 0.0, 0.0, 1.0])


class Robot:
    """The robot's TF publishers and path; :meth:`run` streams until stopped (a thread)."""

    def __init__(self, session) -> None:
        self.node = ros.RosNode(session, "robot")
        self.tf = self.node.publisher("/tf", m.TF_MESSAGE, QoS(depth=100))
        self.tf_static = self.node.publisher("/tf_static", m.TF_MESSAGE, LATCHED)
        self.plan = self.node.publisher("/plan", m.PATH, LATCHED)
        # the localizer is another node (another publisher GID) on the same /tf topic
        self.slam_node = ros.RosNode(session, "slam", node_id=1)
        self.slam = self.slam_node.publisher("/tf", m.TF_MESSAGE, QoS(depth=100))
        self.route = Route(hallway().path)
        self.slam_on = threading.Event()
        self.slam_on.set()
        self.stop = threading.Event()
        self.truth: list[tuple[np.ndarray, np.ndarray]] = []  # base_link in map: (position, quat) of every step
        self.lock = threading.Lock()

    def latch(self, stamp: float) -> None:
        self.tf_static.put(m.encode_transforms([(stamp, "base_footprint", "base_link", T_FB, ID)]))
        self.plan.put(m.encode_path(stamp, "map", self.route.positions))

    def run(self) -> None:
        t0, k = time.time(), 0
        while not self.stop.is_set():
            t = 0.02 * k
            stamp = t0 + t
            pose = self.route.at(min(0.5 * t, self.route.length))
            R_mb = quat_to_matrix(pose.quat)
            p_mf = pose.position - R_mb @ T_FB  # base_footprint in map
            with self.lock:
                self.truth.append((pose.position.copy(), pose.quat.copy()))
            if k % 5 == 0 and self.slam_on.is_set():
                self.slam.put(m.encode_transforms([(stamp, "map", "odom", T_MO, matrix_to_quat(R_MO))]))
            self.tf.put(m.encode_transforms([(stamp, "odom", "base_footprint", R_MO.T @ (p_mf - T_MO),
                                              matrix_to_quat(R_MO.T @ R_mb))]))
            k += 1
            self.stop.wait(max(0.0, t0 + 0.02 * k - time.time()))

    def close(self) -> None:
        for entity in (self.tf, self.tf_static, self.plan, self.slam, self.node, self.slam_node):
            entity.close()


def test_daemon_tracks_on_the_pose_from_tf_and_holds_when_the_localizer_goes_quiet(tmp_path):
    robot_endpoint, endpoint = f"tcp/127.0.0.1:{free_tcp_port()}", f"tcp/127.0.0.1:{free_tcp_port()}"
    session = open_session(listen=[robot_endpoint])
    robot = Robot(session)
    streamer = threading.Thread(target=robot.run, daemon=True)
    mock, url, _ = start_mock_gimbal(tmp_path)
    config = write_config(tmp_path, endpoint, url, **{"topics.pose_source": "tf", "zenoh.connect": [robot_endpoint]})
    cfg = load_config(config)
    recording = tmp_path / "run.mcap"
    probe = None
    try:
        robot.latch(1.0)  # the static link and the path exist before the daemon does
        with mock, ManagedProcess([PYTHON, "-m", "pivotd.cli", "--config", str(config), "--record", str(recording)],
                                  "pivotd") as daemon:
            assert wait_until(lambda: daemon.returncode is not None or daemon.wait_stderr("ready", 0), 30), \
                daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            streamer.start()
            assert wait_until(lambda: probe.status.get("state") == "tracking", 30), daemon.output()
            assert wait_until(lambda: (probe.status.get("planner") or {}).get("path_mode") == "on_path", 20), \
                probe.status
            st = probe.status
            assert st["tf"]["chain"] == ["map", "odom", "base_footprint", "base_link"], st["tf"]
            assert st["bus"]["/tf_static"]["accepted"] == 1 and "/odom" not in st["bus"]
            # the localizer stops; odometry goes on: the chain is stale, the daemon holds, then tracks again
            robot.slam_on.clear()
            assert wait_until(lambda: probe.status.get("state") == "holding", 20), daemon.output()
            assert probe.status["tf"]["dropped"]["stale"] > 0
            robot.slam_on.set()
            assert wait_until(lambda: probe.status.get("state") == "tracking", 20), daemon.output()
            robot.stop.set()
            streamer.join(5)
            assert daemon.stop(timeout=20) == 0, daemon.output()
    finally:
        robot.stop.set()
        if probe is not None:
            probe.close()
        robot.close()
        session.close()
    run = read_recording(recording, config)
    with robot.lock:
        truth_p = np.array([p for p, _ in robot.truth])
        truth_q = np.array([q for _, q in robot.truth])
    assert run.pose_pos.shape[0] > 50
    for p, q in zip(run.pose_pos, run.pose_quat, strict=True):  # each pose the daemon took is a true one
        d = np.linalg.norm(truth_p - p, axis=1)
        i = int(np.argmin(d))
        assert d[i] < 1e-6, (p, truth_p[i])
        assert abs(float(np.dot(truth_q[i], q))) == pytest.approx(1.0, abs=1e-9)
    check_state_timeline(run, tmp_path)


def is_subsequence(wanted: list[str], seen: list[str]) -> bool:
    it = iter(seen)
    return all(any(s == w for s in it) for w in wanted)


def check_state_timeline(run, tmp_path) -> None:
    """The recording's state timeline: the states the run went through, in order, each change once, with both
    clocks; the status at 1 Hz; ``pivotd plot`` draws exactly these steps and the config's joint limits."""
    events = run.states("state")
    states = [e.value for e in events]
    assert states[:2] == ["starting", "waiting"] and states[-2:] == ["parking", "stopped"], states
    assert is_subsequence(["waiting", "tracking", "holding", "tracking", "parking", "stopped"], states), states
    assert all(a != b for a, b in itertools.pairwise(states)), states
    assert [e.previous for e in events] == [None, *states[:-1]]
    assert "up" in [e.value for e in run.states("link")] and all(e.value == 0 for e in run.states("faults"))
    for a, b in itertools.pairwise(events):  # wall and monotonic time advance together (no clock step in a test)
        assert b.monotonic >= a.monotonic and abs((b.wall_time - a.wall_time) - (b.monotonic - a.monotonic)) < 0.5
    assert run.statuses and all({"state", "link", "recording"} <= set(doc) for _, doc in run.statuses)
    assert {doc["state"] for _, doc in run.statuses} <= set(states)
    assert [t for t, _ in run.statuses] == sorted(t for t, _ in run.statuses)
    fig = build_figure(run, "joints")
    joints, timeline = fig.axes
    names = [t.get_text() for t in timeline.get_yticklabels()]
    assert [names[int(v)] for v in timeline.get_lines()[0].get_ydata()] == [*states, states[-1]]
    np.testing.assert_allclose(timeline.get_lines()[0].get_xdata()[:-1], [e.t for e in events])
    limits = {line.get_label().split()[0]: line.get_ydata()[0] for line in joints.get_lines()
              if " limits " in line.get_label()}
    assert limits == {axis: lo for axis, (lo, _) in joint_limits_deg(run).items()}
    assert joint_limits_deg(run)["pan"] == pytest.approx((np.degrees(run.cfg.gimbal.limits.pan_min),
                                                          np.degrees(run.cfg.gimbal.limits.pan_max)))
    save_figure(fig, tmp_path / "joints.png", dpi=20)
