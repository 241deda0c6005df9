"""ROS conventions an integrator relies on: URDF joint names in the JointState, ROS_DOMAIN_ID from the
environment, the loaded map latched on the landmarks topic, /diagnostics."""

from __future__ import annotations

import queue
import re
import textwrap
import time
from pathlib import Path

import numpy as np
import pytest
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.qos import QoS
from pivotd.bus.topics import BusTopics
from pivotd.config import load_config
from pivotd.errors import ConfigError

MINIMAL = "name: ros-node\nmap:\n  allow_empty: true\n"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "ros.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def load_error(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, _):
        yield a, b


@pytest.fixture
def remote_node(sessions):
    node = ros.RosNode(sessions[1], "remote", node_id=int(time.monotonic_ns() % 1000))
    yield node
    node.close()


# ---------------------------------------------------------------- joint names
def test_joint_names_default_to_pan_tilt_and_take_the_urdf_names(tmp_path):
    assert load_config(write(tmp_path, MINIMAL)).topics.joint_names == ("pan", "tilt")
    cfg = load_config(write(tmp_path, MINIMAL + "topics:\n  joint_names: [pan_joint, tilt_joint]\n"))
    assert cfg.topics.joint_names == ("pan_joint", "tilt_joint")


@pytest.mark.parametrize(("value", "needle"), [
    ("[pan_joint]", "must be a list of two joint names"),
    ("[a, b, c]", "must be a list of two joint names"),
    ("[pan_joint, pan_joint]", "the two joint names must differ, both are 'pan_joint'"),
    ("['', tilt]", "must be a non-empty joint name"),
    ("[pan, 3]", "must be a string"),
    ("{pan: tilt}", "must be a list of strings"),
])
def test_bad_joint_names_are_one_line_errors_naming_file_line_and_key(tmp_path, value, needle):
    path = write(tmp_path, MINIMAL + f"topics:\n  frame_id: map\n  joint_names: {value}\n")
    message = load_error(path)
    assert re.match(rf"{re.escape(str(path))}:6: topics\.joint_names(\[\d\])?: ", message), message
    assert needle in message, message


def test_joint_states_carry_the_configured_names_over_zenoh(sessions):
    bus = PivotBus(sessions[0], BusTopics(joint_names=("pan_joint", "tilt_joint")))
    got: queue.Queue = queue.Queue()
    sub = sessions[1].declare_subscriber("0/pivot/joint_states/sensor_msgs::msg::dds_::JointState_/*",
                                         lambda s: got.put(s.payload.to_bytes()))
    try:
        assert wait_for(bus.joint_state_publisher.matched)
        bus.publish_joint_state(12.5, 0.25, -0.5, 0.1, 0.0)
        js = ros.typestore().deserialize_cdr(drain(got, 1)[0], m.JOINT_STATE)
        assert list(js.name) == ["pan_joint", "tilt_joint"]
        np.testing.assert_allclose(js.position, [0.25, -0.5])
    finally:
        sub.undeclare()
        bus.close()


# ---------------------------------------------------------------- ROS_DOMAIN_ID
def test_domain_id_unset_takes_ros_domain_id_from_the_environment(tmp_path, monkeypatch):
    path = write(tmp_path, MINIMAL)
    assert load_config(path).topics.domain_id == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert load_config(path).topics.domain_id == 42
    monkeypatch.setenv("ROS_DOMAIN_ID", " 7 ")
    assert load_config(path).topics.domain_id == 7
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id:\n")).topics.domain_id == 7  # null: unset
    monkeypatch.setenv("ROS_DOMAIN_ID", "")  # empty is unset, as for ROS nodes
    assert load_config(path).topics.domain_id == 0


def test_an_explicit_domain_id_wins_over_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id: 3\n")).topics.domain_id == 3
    monkeypatch.setenv("ROS_DOMAIN_ID", "not-a-number")  # not consulted when the key is set
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id: 0\n")).topics.domain_id == 0


@pytest.mark.parametrize("value", ["abc", "233", "-1", "1.5", "0x10", "²"])
def test_a_bad_ros_domain_id_is_an_error_naming_the_variable(tmp_path, monkeypatch, value):
    monkeypatch.setenv("ROS_DOMAIN_ID", value)
    path = write(tmp_path, MINIMAL)
    message = load_error(path)
    assert message.startswith(f"{path}: ROS_DOMAIN_ID={value!r} in the environment"), message
    assert "must be an integer in 0..232" in message and "topics.domain_id" in message, message


@pytest.mark.slow
def test_pivotd_check_takes_the_domain_from_the_environment_and_refuses_a_bad_one(tmp_path):
    import subprocess

    from support import PYTHON, REPO, child_env

    path = write(tmp_path, MINIMAL)

    def check(value: str) -> subprocess.CompletedProcess:
        return subprocess.run([PYTHON, "-m", "pivotd.cli", "check", "--config", str(path)], capture_output=True,
                              text=True, env=child_env(ROS_DOMAIN_ID=value), cwd=REPO, timeout=60)

    ok = check("7")
    assert ok.returncode == 0 and "topics (domain 7):" in ok.stdout, ok.stderr
    assert "joint states /pivot/joint_states (pan, tilt), " in ok.stdout, ok.stdout
    bad = check("300")
    assert bad.returncode == 2, bad.stdout
    assert bad.stderr.strip().splitlines() == [
        f"pivotd check: error: {path}: ROS_DOMAIN_ID='300' in the environment (used as topics.domain_id is not set): "
        "must be an integer in 0..232"]


# ---------------------------------------------------------------- the map on the landmarks topic
LATCHED = QoS.named("reliable", "transient_local", 1)


def test_the_published_map_reaches_a_late_subscriber_and_is_not_taken_as_input(sessions):
    """pivotd latches its map; a display started afterwards gets the latest one (points and weights); pivotd's own
    landmarks subscription ignores it and still takes a mapping node's cloud."""
    events: queue.Queue = queue.Queue()
    bus = PivotBus(sessions[0], BusTopics(), on_cloud=lambda layer, c: events.put((layer, c)))
    viewer = ros.RosNode(sessions[1], "viewer")
    latched: queue.Queue = queue.Queue()
    subs = []
    try:
        first = np.arange(30.0).reshape(10, 3)
        points = np.array([[1.0, 2.0, 3.0], [-4.0, 5.5, 0.25], [7.0, -8.0, 9.5]])
        bus.publish_map(1.0, first, np.ones(10))
        bus.publish_map(2.0, points, np.array([0.5, 1.0, 2.0]))
        subs.append(viewer.subscriber("/pivot/landmarks", m.POINT_CLOUD2, latched.put, LATCHED))
        sample = drain(latched, 1)[0]
        cloud = m.decode_cloud(sample.payload.to_bytes(), "/pivot/landmarks")
        np.testing.assert_allclose(cloud.points, points)
        np.testing.assert_allclose(cloud.weights, [0.5, 1.0, 2.0])
        assert cloud.stamp == pytest.approx(2.0) and cloud.frame_id == "map"
        assert ros.Attachment.decode(sample.attachment.to_bytes()).gid == bus.map_publisher.gid
        # A mapping node's cloud on the same topic is pivotd's input; its own map never was.
        mapper = viewer.publisher("/pivot/landmarks", m.POINT_CLOUD2, LATCHED)
        subs.append(mapper)
        assert wait_for(mapper.matched)
        mapper.put(m.encode_cloud(3.0, "map", np.full((4, 3), 0.5)))
        got = drain(events, 1)
        assert got and got[0][0] == "landmarks" and got[0][1].points.shape == (4, 3)
        assert events.empty()
        counts = bus.counters()["/pivot/landmarks"]
        assert counts["received"] == counts["accepted"] == 1, counts
    finally:
        for s in subs:
            s.close()
        viewer.close()
        bus.close()


def test_a_big_map_is_strided_to_the_preview_bound_over_the_whole_map(monkeypatch):
    from pivotd.daemon import worker
    from pivotd.maps.formats import LandmarkCloud
    from pivotd.maps.store import BASE_LAYER, MapStore

    monkeypatch.setattr(worker, "MAX_PREVIEW_POINTS", 300)
    rng = np.random.default_rng(3)
    pts = rng.uniform([-50, -20, 0], [50, 20, 3], (1000, 3))
    store = MapStore()
    store.set_layer(BASE_LAYER, LandmarkCloud(pts.astype(np.float32), np.linspace(1, 2, 1000, dtype=np.float32), None))
    # a layer from the bus is not part of it
    store.set_layer("landmarks", LandmarkCloud(np.zeros((5, 3), np.float32), np.ones(5, np.float32), None))
    info = worker._map_info(store, preview=True)
    points, weights = info.preview
    assert points.shape == (250, 3) and weights.shape == (250,)  # every 4th of 1000
    assert len(np.unique(points, axis=0)) == 250
    assert {tuple(p) for p in points} <= {tuple(p) for p in pts.astype(np.float32)}
    # spread over the whole map: every 10 m x 10 m cell of the map's 100 m x 40 m holds some of them
    cells = {(int((x + 50) // 10), int((y + 20) // 10)) for x, y, _ in points}
    assert len(cells) == 40
    small = worker._map_info(MapStore(), preview=True).preview
    assert small[0].shape == (0, 3)
    assert worker._map_info(store).preview is None  # only replies that loaded the map carry it


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_the_daemon_latches_its_map_file_for_late_displays_and_again_after_a_reload(tmp_path):
    """A real pivotd (in-process mock gimbal) with a map file: a display that starts later gets the map on the
    landmarks topic; after the map file changed and a SIGHUP, a new display gets the new map. It publishes
    /diagnostics too."""
    import signal

    from support import free_tcp_port, wait_until
    from test_e2e_daemon import start_daemon, write_config

    from pivotd.bus.probe import BusProbe

    rng = np.random.default_rng(11)
    first = rng.uniform([-10, -3, 0], [10, 3, 2.5], (400, 3)).astype(np.float32)
    second = rng.uniform([-5, -3, 0], [5, 3, 2.5], (150, 3)).astype(np.float32)
    map_file = tmp_path / "map.npy"
    np.save(map_file, first)
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    config = write_config(tmp_path, endpoint, "mock://", **{"map.file": str(map_file), "ros.markers": False})
    cfg = load_config(config)

    def late_display(node: ros.RosNode) -> np.ndarray:
        got: queue.Queue = queue.Queue()
        sub = node.subscriber(cfg.topics.landmarks, m.POINT_CLOUD2, got.put, LATCHED)
        try:
            samples = drain(got, 1, timeout=30)
            assert samples, "no map reached the late subscriber"
            return m.decode_cloud(samples[0].payload.to_bytes(), cfg.topics.landmarks).points
        finally:
            sub.close()

    def as_set(points: np.ndarray) -> set:
        return {tuple(p) for p in np.asarray(points, np.float32)}

    with start_daemon(config) as daemon:
        probe = node = None
        try:
            assert daemon.wait_stderr("map: 400 landmarks published", 90), daemon.output()
            probe = BusProbe.connect(endpoint, cfg.topics)
            node = ros.RosNode(probe.session, "rviz")
            diagnostics: queue.Queue = queue.Queue()
            diag_sub = node.subscriber("/diagnostics", m.DIAGNOSTIC_ARRAY, diagnostics.put)
            assert as_set(late_display(node)) == as_set(first)
            # /diagnostics from the daemon: one entry per component, named after the node; no pose yet: STALE
            samples = drain(diagnostics, 1, timeout=30)
            diag_sub.close()
            assert samples, daemon.output()
            msg = ros.typestore().deserialize_cdr(samples[0].payload.to_bytes(), m.DIAGNOSTIC_ARRAY)
            levels = {st.name: int(st.level) for st in msg.status}
            assert levels[f"{cfg.name}: pose"] == 3 and levels[f"{cfg.name}: gimbal link"] in (0, 2), levels
            assert {st.name.partition(": ")[2] for st in msg.status} == {
                "state", "gimbal link", "pose", "gimbal faults", "planner"}
            np.save(map_file, second)
            daemon.send_signal(signal.SIGHUP)
            assert daemon.wait_stderr("map: 150 landmarks published", 90), daemon.output()
            assert as_set(late_display(node)) == as_set(second)
            # the daemon did not take its own map back as a landmarks layer
            assert wait_until(lambda: probe.status.get("reloads") == 1, 30), probe.status
            st = probe.status
            assert st["map"]["landmarks"] == 150 and "landmarks" not in st["map"]["layers"], st["map"]
            assert st["bus"][cfg.topics.landmarks]["received"] == 0, st["bus"]
        finally:
            if node is not None:
                node.close()
            if probe is not None:
                probe.close()
        assert daemon.stop() == 0, daemon.output()


# ---------------------------------------------------------------- /diagnostics
def _status(**changes) -> dict:
    doc = {"name": "robot7", "state": "tracking", "link": "up", "link_error": None, "pose_age_s": 0.02,
           "gimbal": {"mode": "active", "faults": 0, "fault_names": []}, "fault_episodes": 0,
           "last_error": None, "reloads": 2, "needs_restart": [],
           "planner": {"plans": 40, "solve_ms_p50": 12.5, "solve_ms_p99": 31.0, "visible_now": 120, "timeouts": 0,
                       "worker_restarts": 0}}
    doc.update(changes)
    return doc


def _decoded(status: dict) -> dict:
    """The DiagnosticArray of ``status`` as rosbags decodes it: component -> (level, message, hw id, values)."""
    from pivotd.bus.diagnostics import diagnostic_entries

    payload = m.encode_diagnostics(123.25, diagnostic_entries(status, 0.5, 0.2, "/dev/ttyACM0"))
    msg = ros.typestore().deserialize_cdr(payload, m.DIAGNOSTIC_ARRAY)
    assert msg.header.stamp.sec == 123 and msg.header.stamp.nanosec == 250_000_000
    out = {}
    for st in msg.status:
        node, _, component = st.name.partition(": ")
        assert node == status["name"]
        out[component] = (int(st.level), st.message, st.hardware_id, {kv.key: kv.value for kv in st.values})
    return out


def test_diagnostics_of_a_healthy_daemon_are_ok_and_carry_the_fields():
    from pivotd.bus.diagnostics import COMPONENTS

    d = _decoded(_status())
    assert list(d) == list(COMPONENTS)
    assert {c: v[0] for c, v in d.items()} == dict.fromkeys(COMPONENTS, 0)
    assert d["state"][3]["state"] == "tracking" and d["state"][3]["reloads"] == "2"
    assert d["gimbal link"][2] == d["gimbal faults"][2] == "/dev/ttyACM0"
    assert d["pose"][3] == {"pose_age_s": "0.02", "pose_timeout_s": "0.5"}
    assert d["gimbal faults"][3]["faults"] == "0x0000"
    planner = d["planner"][3]
    assert (planner["solve_ms_p50"], planner["solve_ms_p99"], planner["plans"]) == ("12.5", "31.0", "40")
    assert planner["budget_ms"] == "200.0"


def test_diagnostics_levels_follow_the_daemon_state_link_pose_faults_and_solve_time():
    d = _decoded(_status(state="fault", link="down", link_error="serial port closed", pose_age_s=0.8,
                         gimbal={"mode": "fault", "faults": 0x11, "fault_names": ["overcurrent", "watchdog"]},
                         planner={"plans": 5, "solve_ms_p50": 150.0, "solve_ms_p99": 250.0}))
    assert {c: v[0] for c, v in d.items()} == {"state": 2, "gimbal link": 2, "pose": 1, "gimbal faults": 2,
                                              "planner": 1}
    assert d["gimbal link"][1] == "down: serial port closed"
    assert d["pose"][1] == "pose stale (0.80 s > 0.5 s): holding"
    assert d["gimbal faults"][1] == "faults: overcurrent,watchdog" and d["gimbal faults"][3]["faults"] == "0x0011"
    assert "250 ms above the 200 ms budget" in d["planner"][1]
    # nothing known yet: STALE
    d = _decoded(_status(state="waiting", link="stopped", pose_age_s=None, gimbal=None, planner={"plans": 0}))
    assert {c: v[0] for c, v in d.items()} == {"state": 1, "gimbal link": 3, "pose": 3, "gimbal faults": 3,
                                              "planner": 3}


# ---------------------------------------------------------------- use_sim_time
def test_use_sim_time_is_a_topics_key(tmp_path):
    assert load_config(write(tmp_path, MINIMAL)).topics.use_sim_time is False
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  use_sim_time: true\n")).topics.use_sim_time is True
    path = write(tmp_path, MINIMAL + "topics:\n  use_sim_time: yes please\n")
    assert re.match(rf"{re.escape(str(path))}:5: topics\.use_sim_time: must be true or false", load_error(path))


def test_with_use_sim_time_the_bus_time_is_the_last_clock_received(sessions, remote_node):
    bus = PivotBus(sessions[0], BusTopics(use_sim_time=True))
    try:
        assert bus.now() is None  # no /clock yet: a ROS node's time is 0, pivotd stamps nothing
        clock = remote_node.publisher("/clock", m.CLOCK, QoS.named("reliable", "volatile", 1))
        assert wait_for(clock.matched)
        clock.put(m.encode_clock(100.5))
        assert wait_for(lambda: bus.now() == 100.5), bus.counters()
        bad = bytearray(m.encode_clock(7.0))
        bad[8:12] = (2_000_000_000).to_bytes(4, "little")  # nanosec beyond a second
        clock.put(bytes(bad))
        assert wait_for(lambda: bus.counters()["/clock"].get("dropped_malformed") == 1), bus.counters()
        clock.put(m.encode_clock(99.0))  # a simulation reset goes back: followed, as ROS nodes do
        assert wait_for(lambda: bus.now() == 99.0)
        assert bus.counters()["/clock"]["accepted"] == 2
        clock.close()
    finally:
        bus.close()
    wall = PivotBus(sessions[0], BusTopics())
    try:
        before = time.time()
        assert before <= wall.now() <= time.time() and "/clock" not in wall.counters()
    finally:
        wall.close()


@pytest.mark.slow
@pytest.mark.timeout(240)
def test_the_daemon_stamps_joint_states_with_the_simulation_clock(tmp_path):
    from support import free_tcp_port
    from test_e2e_daemon import start_daemon, write_config

    from pivotd.bus.session import open_session

    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    config = write_config(tmp_path, endpoint, "mock://", **{"topics.use_sim_time": True, "ros.markers": False})
    cfg = load_config(config)
    with start_daemon(config) as daemon:
        session = node = None
        try:
            assert daemon.wait_stderr("ready", 90), daemon.output()
            session = open_session(connect=[endpoint])
            node = ros.RosNode(session, "gazebo")
            stamps: queue.Queue = queue.Queue()
            sub = node.subscriber(cfg.topics.joint_states, m.JOINT_STATE, lambda s: stamps.put(
                m.stamp_to_seconds(ros.typestore().deserialize_cdr(s.payload.to_bytes(), m.JOINT_STATE).header.stamp)))
            clock = node.publisher("/clock", m.CLOCK, QoS.named("reliable", "volatile", 1))
            seen = []
            for sim_t in (1234.5, 1300.25):
                def stamped(t=sim_t) -> bool:
                    clock.put(m.encode_clock(t))  # a simulator publishes its clock all the time
                    seen.extend(drain(stamps, stamps.qsize(), 0.05))
                    return t in seen
                assert wait_for(stamped, 60, 0.05), (seen[-5:], daemon.output())
            # every joint state carried a simulation time, none the wall clock
            assert set(seen) <= {1234.5, 1300.25}, sorted(set(seen))[:5]
            sub.close()
            clock.close()
        finally:
            if node is not None:
                node.close()
            if session is not None:
                session.close()
        assert daemon.stop() == 0, daemon.output()


def test_with_use_sim_time_clock_is_an_input_key_of_the_access_control():
    from pivotd.bus.security import input_key_exprs

    assert "0/clock/**" not in input_key_exprs(BusTopics())
    assert "4/clock/**" in input_key_exprs(BusTopics(use_sim_time=True, domain_id=4))
