"""tools/sim_pose: route kinematics, option checks, and the real executable publishing over Zenoh."""

import os
import queue
import signal
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from bus_support import drain, free_port, record_poses, wait_for

from pivotd.bus import messages as m
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.session import open_session
from pivotd.bus.topics import BusTopics
from pivotd.errors import InputError
from pivotd.geometry import quat_to_matrix
from pivotd.pivot.scenes import hallway
from pivotd.robot_path import load_path
from pivotd.sim.routes import Route, load_route
from pivotd.sim.sim_pose import parse_gap

REPO = Path(__file__).resolve().parent.parent
TOOL = REPO / "tools" / "sim_pose"
YCORRIDOR = REPO / "tests" / "data" / "fif" / "ycorridor_6x20.csv"


def yaw_of(q):
    R = quat_to_matrix(q)
    return np.arctan2(R[..., 1, 0], R[..., 0, 0])


def test_route_positions_and_tangent_yaw():
    r = Route(np.array([[0, 0, 0], [2, 0, 0], [2, 0, 0], [2, 2, 0]], float))
    assert r.length == pytest.approx(4.0)
    p = r.at(1.0, speed=0.5)
    np.testing.assert_allclose(p.position, [1, 0, 0])
    np.testing.assert_allclose(p.velocity, [0.5, 0, 0])
    assert yaw_of(r.at(0.0).quat) == pytest.approx(0.0)
    assert yaw_of(r.at(4.0).quat) == pytest.approx(np.pi / 2)
    assert yaw_of(r.at(2.0).quat) == pytest.approx(np.pi / 4)  # corner: halfway through the turn
    np.testing.assert_allclose(r.at(3.0).position, [2, 1, 0])
    np.testing.assert_allclose(r.at(10.0).position, [2, 2, 0])  # clamped at the end, standing still
    np.testing.assert_allclose(r.at(10.0, speed=1.0).velocity, 0.0)


def test_route_yaw_is_smooth_on_the_hallway():
    r = Route(hallway().path)
    s = np.linspace(0, r.length, 2000)
    yaw = np.unwrap(yaw_of(np.array([r.at(x).quat for x in s])))
    assert np.max(np.abs(np.diff(yaw))) < np.deg2rad(1.0)
    assert np.max(yaw) == pytest.approx(np.pi / 2, abs=0.1)  # the S turns left by 90 degrees and back


def test_route_uses_csv_quaternions():
    data = load_route(f"csv:{YCORRIDOR}")
    r = Route(data.positions, data.quats)
    np.testing.assert_allclose(r.at(0.0).quat, data.quats[0])
    np.testing.assert_allclose(r.at(r.arc[5]).quat, data.quats[5], atol=1e-12)


def test_bad_route_and_gap_specs():
    with pytest.raises(InputError, match="unknown route"):
        load_route("mars")
    with pytest.raises(InputError, match="no such file"):
        load_route("csv:/nonexistent.csv")
    for bad in ("3", "a:b", "-1:2", "1:0"):
        with pytest.raises(InputError, match="--gap"):
            parse_gap(bad)
    g = parse_gap("5:2.5")
    assert g.covers(5.0) and g.covers(7.4) and not g.covers(7.5) and not g.covers(4.9)


def run_tool(*args):
    env = dict(os.environ, PYTHONPATH=str(REPO))
    return subprocess.Popen([sys.executable, str(TOOL), *args], env=env, stdout=subprocess.PIPE,
                            stderr=subprocess.PIPE, text=True)


def stop_tool(proc):
    if proc.poll() is None:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(timeout=60)  # generous: a loaded host delays the exit, not a hang
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


@pytest.mark.slow
def test_bad_option_exits_2_with_one_line():
    proc = run_tool("--rate", "0", "--quiet")
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        stop_tool(proc)
    assert proc.returncode == 2
    assert err.strip().splitlines() == ["sim_pose: error: --rate must be > 0, got 0.0"]


@pytest.fixture
def listener():
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    session = open_session(listen=[endpoint])
    try:
        yield session, endpoint
    finally:
        session.close()


@pytest.mark.slow
def test_sim_pose_publishes_odometry_and_path_and_honours_gap(listener):
    session, endpoint = listener
    events = queue.Queue()
    bus = PivotBus(session, BusTopics(), on_path=lambda p: events.put(("path", p)))
    recorder = record_poses(session, BusTopics(), events, lambda s: ("pose", s))
    rate, speed = 20.0, 2.0
    proc = run_tool("--connect", endpoint, "--rate", str(rate), "--speed", str(speed), "--gap", "1.0:1.0",
                    "--duration", "60", "--wait-subscribers", "30", "--quiet")
    try:
        poses, paths = [], []

        def collect():
            for kind, msg in drain(events, 200, timeout=0.1):
                (poses if kind == "pose" else paths).append(msg)
            return len(poses) >= 50 and poses[-1].stamp - poses[0].stamp > 3.0

        assert wait_for(collect, timeout=60), f"received {len(poses)} poses, {len(paths)} paths"
        stop_tool(proc)
        assert proc.returncode == 0
    finally:
        stop_tool(proc)
        recorder.undeclare()
        bus.close()

    # The path is the hallway route, published at t = 0 (same stamp as the first pose).
    np.testing.assert_allclose(paths[0].positions, hallway().path, atol=1e-12)
    t0 = paths[0].stamp
    assert poses[0].stamp == pytest.approx(t0, abs=1e-6)
    stamps = np.array([p.stamp for p in poses]) - t0
    steps = np.diff(stamps)
    big = np.flatnonzero(steps > 1.5 / rate)
    assert len(big) == 1, f"expected exactly one gap, steps {steps}"
    assert stamps[big[0]] == pytest.approx(1.0 - 1 / rate, abs=1e-3)
    assert steps[big[0]] == pytest.approx(1.0 + 1 / rate, abs=1e-3)
    np.testing.assert_allclose(np.delete(steps, big), 1 / rate, atol=1e-6)
    # Positions follow the route at the requested speed; yaw is along the path.
    route = Route(hallway().path)
    for p, t in zip(poses, stamps, strict=True):
        expected = route.at(speed * t)
        np.testing.assert_allclose(p.position, expected.position, atol=1e-6)
        np.testing.assert_allclose(abs(np.dot(p.quat, expected.quat)), 1.0, atol=1e-9)
    assert bus.counters()["/odom"].get("dropped_wrong_type", 0) == 0


@pytest.mark.slow
@pytest.mark.parametrize("pose_type", [m.POSE_STAMPED, m.POSE_WITH_COVARIANCE_STAMPED])
def test_sim_pose_csv_route_as_pose_stamped(listener, pose_type):
    session, endpoint = listener
    events = queue.Queue()
    topics = BusTopics(pose="/robot/pose", pose_type=pose_type, path="/robot/plan", domain_id=4)
    bus = PivotBus(session, topics)
    recorder = record_poses(session, topics, events)
    proc = run_tool("--connect", endpoint, "--route", f"csv:{YCORRIDOR}", "--odom-topic", "", "--pose-topic",
                    "/robot/pose", "--pose-type", pose_type, "--path-topic", "/robot/plan", "--domain-id", "4",
                    "--rate", "50", "--wait-subscribers", "30", "--duration", "60", "--quiet")
    try:
        first = drain(events, 1, timeout=60)
        assert first, f"no {pose_type} received"
        assert wait_for(lambda: bus.counters()["/robot/plan"]["accepted"] >= 1, timeout=30)
        assert wait_for(lambda: bus.counters()["/robot/pose"]["accepted"] >= 1, timeout=30)
    finally:
        stop_tool(proc)
        recorder.undeclare()
        bus.close()
    assert proc.returncode == 0
    data = load_path(YCORRIDOR)
    np.testing.assert_allclose(first[0].position, data.positions[0], atol=1e-9)
    np.testing.assert_allclose(first[0].quat, data.quats[0], atol=1e-9)


@pytest.mark.slow
def test_sim_pose_ends_by_itself_at_the_end_of_the_route(tmp_path):
    route = tmp_path / "short.csv"
    route.write_text("# x,y,z\n0,0,0\n1,0,0\n1,1,0\n")
    proc = run_tool("--route", f"csv:{route}", "--speed", "20", "--rate", "50")
    try:
        out, err = proc.communicate(timeout=60)
    finally:
        stop_tool(proc)
    assert proc.returncode == 0, err
    lines = out.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("t=0.0s s=0.00m/2.00m poses=1")


@pytest.mark.slow
def test_sim_pose_stops_on_sigint(listener):
    session, endpoint = listener
    events = queue.Queue()
    bus = PivotBus(session, BusTopics(), on_pose=events.put)
    proc = run_tool("--connect", endpoint, "--loop", "--quiet")
    try:
        assert drain(events, 1, timeout=60), "sim_pose never published"  # running, handlers installed
        proc.send_signal(signal.SIGINT)
        _, err = proc.communicate(timeout=30)
    finally:
        stop_tool(proc)
        bus.close()
    assert proc.returncode == 0, err
    assert "Traceback" not in err


def test_pose_noise_in_process(listener):
    import threading

    from pivotd.sim.sim_pose import build_parser, run

    session, endpoint = listener
    events = queue.Queue()
    recorder = record_poses(session, BusTopics(), events)
    args = build_parser().parse_args(["--connect", endpoint, "--rate", "100", "--speed", "1", "--pose-noise", "0.1",
                                      "--duration", "1.5", "--wait-subscribers", "30", "--path-topic", "", "--quiet"])
    result = []
    worker = threading.Thread(target=lambda: result.append(run(args)))
    worker.start()
    try:
        worker.join(timeout=60)
        poses = drain(events, 151, timeout=10)
    finally:
        recorder.undeclare()
    assert result == [0]
    assert len(poses) == 151
    t0 = poses[0].stamp
    route = Route(hallway().path)
    err = np.array([p.position - route.at(p.stamp - t0).position for p in poses])
    assert 0.07 < err.std() < 0.13
    assert np.all(np.abs(err.mean(axis=0)) < 0.05)


# --- timed routes (--timed): time stamps and attitudes, turns in place ------------------------------------------


def _turn_in_place_route(tmp_path):
    """1 m along +x in 1 s, then a 90° left turn in place over 2 s, then 1 m along +y in 1 s."""
    from pivotd.sim.scene_families import FamilyScene, write_scene

    yaw = np.array([0.0, 0.0, np.pi / 4, np.pi / 2, np.pi / 2])
    pos = np.array([[0, 0, 0.7], [1, 0, 0.7], [1, 0, 0.7], [1, 0, 0.7], [1, 1, 0.7]], float)
    quats = np.column_stack([np.zeros((5, 2)), np.sin(yaw / 2), np.cos(yaw / 2)])
    scene = FamilyScene("t", "t", 0, np.zeros((1, 3)), pos, quats, np.array([0.0, 1.0, 2.0, 3.0, 4.0]))
    return write_scene(scene, tmp_path)[1]


def test_timed_route_interpolates_in_time_and_turns_in_place(tmp_path):
    from pivotd.sim.routes import TimedRoute

    data = load_route(_turn_in_place_route(tmp_path))
    r = TimedRoute(data.positions, data.quats, data.stamps)
    assert r.duration == pytest.approx(4.0)
    p = r.at_time(0.5)
    np.testing.assert_allclose(p.position, [0.5, 0, 0.7], atol=1e-9)
    np.testing.assert_allclose(p.velocity, [1, 0, 0], atol=1e-9)
    for t, want in ((1.5, np.pi / 8), (2.5, 3 * np.pi / 8)):
        p = r.at_time(t)
        np.testing.assert_allclose(p.position, [1, 0, 0.7], atol=1e-9)  # the position holds while it turns
        np.testing.assert_allclose(p.velocity, 0.0, atol=1e-12)
        assert yaw_of(p.quat) == pytest.approx(want, abs=0.02)  # nlerp, close to the slerp angle
    np.testing.assert_allclose(r.at_time(3.5).position, [1, 0.5, 0.7], atol=1e-9)
    np.testing.assert_allclose(r.at_time(9.0).velocity, 0.0)  # past the end: stopped at the last row
    with pytest.raises(InputError, match="decrease at row 3"):
        TimedRoute(data.positions[:3], data.quats[:3], np.array([0.0, 2.0, 1.0]))


@pytest.mark.slow
def test_timed_needs_a_route_with_time_stamps():
    proc = run_tool("--timed", "--quiet")
    try:
        _, err = proc.communicate(timeout=60)
    finally:
        stop_tool(proc)
    assert proc.returncode == 2
    assert err.strip().splitlines() == ["sim_pose: error: --timed: route 'hallway' has no time stamps "
                                        "(expected rows t,x,y,z,qw,qx,qy,qz)"]


@pytest.mark.slow
def test_sim_pose_plays_the_stop_turn_route_in_place(listener, tmp_path):
    """The stop_turn family's route around its first stop (cropped, times from 0): while the published
    position holds, the published attitude turns by the corner's angle."""
    import threading

    from pivotd.sim.routes import TimedRoute
    from pivotd.sim.scene_families import FamilyScene, stop_turn, write_scene
    from pivotd.sim.sim_pose import build_parser, run

    scene = stop_turn(3, speed=1.2)
    still = np.flatnonzero(np.all(np.diff(scene.route, axis=0) == 0, axis=1))  # rows that repeat a position
    lo, hi = max(0, still[0] - 4), still[0] + (np.flatnonzero(np.diff(still) > 1)[0] + 1) + 5
    crop = FamilyScene("crop", "stop_turn", 3, scene.landmarks, scene.route[lo:hi], scene.quats[lo:hi],
                       scene.stamps[lo:hi] - scene.stamps[lo])
    _, spec = write_scene(crop, tmp_path)
    session, endpoint = listener
    events = queue.Queue()
    recorder = record_poses(session, BusTopics(), events)
    args = build_parser().parse_args(["--connect", endpoint, "--route", spec, "--timed", "--rate", "50",
                                      "--wait-subscribers", "30", "--path-topic", "", "--quiet"])
    result = []
    worker = threading.Thread(target=lambda: result.append(run(args)))
    worker.start()
    try:
        worker.join(timeout=120)
        poses = drain(events, 10_000, timeout=2)
    finally:
        recorder.undeclare()
    assert result == [0]
    data = load_route(spec)  # as written (6 decimals)
    timed = TimedRoute(data.positions, data.quats, data.stamps)
    assert len(poses) == int(timed.duration * 50) + 1
    t0 = poses[0].stamp
    for p in poses:
        want = timed.at_time(p.stamp - t0)  # stamps as doubles of the epoch: ~0.2 µs apart
        np.testing.assert_allclose(p.position, want.position, atol=1e-5)
        assert abs(np.dot(p.quat, want.quat)) == pytest.approx(1.0, abs=1e-9)
    pos = np.array([p.position for p in poses])
    yaw = np.unwrap(yaw_of(np.array([p.quat for p in poses])))
    held = np.all(np.abs(pos - data.positions[still[0] - lo]) < 1e-9, axis=1)
    assert held.sum() > 50  # more than a second standing at the corner
    assert abs(yaw[held].max() - yaw[held].min()) == pytest.approx(np.pi / 2, abs=1e-6)
    assert np.ptp(pos[~held], axis=0)[:2].min() > 0.5  # it drives along x before the turn and along y after


@pytest.mark.slow
@pytest.mark.parametrize("map_odom_hz", [0.0, 5.0])
def test_sim_pose_tf_composes_to_the_published_pose(listener, map_odom_hz):
    """``--tf``: map -> odom (static, or on /tf at 5 Hz with a moving correction) and odom -> base_link at the pose
    rate; pivotd's bus, taking the pose from TF, composes exactly the poses sim_pose publishes on /odom."""
    session, endpoint = listener
    composed: queue.Queue = queue.Queue()
    truth: queue.Queue = queue.Queue()
    topics = BusTopics(pose_source="tf")
    bus = PivotBus(session, topics, on_pose=composed.put, tf_timeout=30.0)
    recorder = record_poses(session, BusTopics(), truth)
    args = ["--tf-map-odom-hz", str(map_odom_hz)] if map_odom_hz else []
    proc = run_tool("--connect", endpoint, "--tf", *args, "--rate", "50", "--speed", "1.0", "--duration", "60",
                    "--wait-subscribers", "30", "--quiet")
    got, odom = [], []
    try:
        def collect():
            got.extend(drain(composed, 500, timeout=0.05))
            odom.extend(drain(truth, 500, timeout=0.05))
            return len(got) >= 60 and len(odom) >= 60

        assert wait_for(collect, timeout=60), f"{len(got)} composed poses, {len(odom)} on /odom"
    finally:
        stop_tool(proc)
        recorder.undeclare()
        bus.close()
    assert proc.returncode == 0
    by_stamp = {round(p.stamp, 6): p for p in odom}
    matched = 0
    for p in got:
        twin = [o for o in odom if np.allclose(o.position, p.position, atol=1e-9)]
        if twin:
            matched += 1
            np.testing.assert_allclose(abs(np.dot(twin[0].quat, p.quat)), 1.0, atol=1e-9)
        if not map_odom_hz:
            assert round(p.stamp, 6) in by_stamp  # the static link does not count: the odometry's stamp
            np.testing.assert_allclose(by_stamp[round(p.stamp, 6)].position, p.position, atol=1e-9)
    assert matched >= len(got) - 2  # a composed pose at either end of the two recordings may have no twin
    st = bus.tf_pose.status()
    assert st["chain"] == ["map", "odom", "base_link"]
    # nothing dropped, except missing links while the first of the two links had arrived and the other not yet
    assert all(v == 0 for k, v in st["dropped"].items() if k != "missing_link")
    c = bus.counters()
    assert c["/tf_static"]["accepted"] == (0 if map_odom_hz else 1)
    if map_odom_hz:  # map -> odom's stamp is older than the odometry's between its publications
        assert any(p.stamp < max(q.stamp for q in got) - 0.1 for p in got)
