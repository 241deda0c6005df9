"""End to end: a real `pivotd` with the mock gimbal and the simulated robot publishes live markers and the camera
TF that a plain Zenoh subscriber decodes; the view plan reaches a transient-local subscriber that starts late."""

from __future__ import annotations

import math
import queue
import signal

import numpy as np
import pytest
from bus_support import drain
from support import free_tcp_port, wait_until
from test_e2e_daemon import start_daemon, start_mock_gimbal, start_sim, write_config

from pivotd.bus import ros
from pivotd.bus.markers import MARKER_ARRAY, TF_MESSAGE
from pivotd.bus.messages import PATH
from pivotd.bus.probe import BusProbe
from pivotd.bus.qos import QoS
from pivotd.config import load_config
from pivotd.geometry import angle_between, quat_to_matrix

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def test_daemon_publishes_markers_tf_and_a_latched_view_plan(tmp_path):
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, _ = start_mock_gimbal(tmp_path)
    config = write_config(tmp_path, endpoint, url, **{"ros.tf": True, "ros.marker_range": 2.0})
    cfg = load_config(config)
    markers: queue.Queue = queue.Queue()
    tfs: queue.Queue = queue.Queue()
    with mock, start_daemon(config) as daemon:
        probe = None
        try:
            assert wait_until(lambda: daemon.returncode is not None or daemon.wait_stderr("ready", 0), 30), \
                daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            subs = [probe.session.declare_subscriber(ros.topic_key(0, "/pivot/markers", MARKER_ARRAY, "*"),
                                                     lambda s: markers.put(s.payload.to_bytes())),
                    probe.session.declare_subscriber(ros.topic_key(0, "/tf", TF_MESSAGE, "*"),
                                                     lambda s: tfs.put(s.payload.to_bytes()))]
            # the robot walks until every check is done (markers come while tracking; a loaded machine is slow)
            with start_sim(endpoint, "--speed", "1.0", "--duration", "90") as sim:
                assert wait_until(lambda: probe.status.get("state") == "tracking", 20), daemon.output()
                got = drain(markers, 3, timeout=20)
                assert len(got) == 3, daemon.output()
                tf_got = drain(tfs, 3, timeout=10)
                assert len(tf_got) == 3, daemon.output()
                # A transient-local subscriber started now still gets the current plan at once.
                late = ros.RosNode(probe.session, "late_viewer")
                plans: queue.Queue = queue.Queue()
                sub = late.subscriber("/pivot/view_plan", PATH, lambda s: plans.put(s.payload.to_bytes()),
                                      QoS.named("reliable", "transient_local", 1))
                assert drain(plans, 1, timeout=10), daemon.output()
                sub.close()
                late.close()
                assert sim.stop(signal.SIGTERM, timeout=20) == 0, sim.output()
            for s in subs:
                s.undeclare()
        finally:
            if probe is not None:
                probe.close()
    msg = ros.typestore().deserialize_cdr(got[-1], MARKER_ARRAY)
    by_ns = {}
    for mk in msg.markers:
        by_ns.setdefault(mk.ns, []).append(mk)
    assert len(by_ns["plan"]) == cfg.planner.horizon
    [cone] = by_ns["fov_cone"]
    pts = np.array([[p.x, p.y, p.z] for p in cone.points])
    spokes = pts[: len(pts) // 2].reshape(-1, 2, 3)
    apex = spokes[0, 0]
    arrow = by_ns["plan"][0].points
    axis = np.array([arrow[1].x - arrow[0].x, arrow[1].y - arrow[0].y, arrow[1].z - arrow[0].z])
    gen = spokes[:, 1] - apex
    np.testing.assert_allclose(angle_between(gen, np.repeat(axis[None], len(gen), 0)), cfg.pivot.fov / 2, atol=1e-6)
    np.testing.assert_allclose(np.linalg.norm(gen, axis=1), 2.0, atol=1e-9)
    [hl] = by_ns["in_view"]
    lm = np.array([[p.x, p.y, p.z] for p in hl.points]).reshape(-1, 3)
    assert lm.shape[0] > 0
    assert np.all(angle_between(lm - apex, np.repeat(axis[None], len(lm), 0)) <= cfg.pivot.fov / 2 + 1e-6)
    tf = ros.typestore().deserialize_cdr(tf_got[-1], TF_MESSAGE).transforms[0]
    q = tf.transform.rotation
    z = quat_to_matrix(np.array([q.x, q.y, q.z, q.w]))[:, 2]
    assert tf.child_frame_id == "pivot_camera" and abs(np.linalg.norm(z) - 1) < 1e-9
    assert z[2] > -math.sin(math.radians(60))  # a real camera direction within the tilt limits, not garbage
