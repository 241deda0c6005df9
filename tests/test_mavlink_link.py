"""The MAVLink backend against the simulated gimbal manager, in process, over real UDP on loopback."""

from __future__ import annotations

import contextlib
import csv
import logging
import math
import signal
import socket
import threading
import time
from typing import Any

import pytest
from support import PYTHON, REPO, ManagedProcess, free_tcp_port, wait_until
from test_e2e_daemon import start_daemon, start_mock_gimbal, start_sim, write_config

from pivotd.bus.probe import BusProbe
from pivotd.config import load_config
from pivotd.firmware_proto.realtime import CsvMessageLog, FaultInjector
from pivotd.gimbal.interface import GimbalMode, LinkState
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.mavlink_link import MavlinkGimbal, MavlinkSettings
from pivotd.sim.mavlink_device import MavlinkGimbalModel, StatusFrame
from pivotd.sim.mavlink_server import MavlinkServer

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]

DEVICE = JointLimits(math.radians(-120), math.radians(120), math.radians(-30), math.radians(90))


class SimThread:
    """The simulator on its own thread; ``paused`` set: it neither reads nor sends (a stalled manager: datagrams
    queue in its UDP socket until it runs again)."""

    def __init__(self, fault_duration=1.0, log: CsvMessageLog | None = None, **model: Any) -> None:
        self.model = MavlinkGimbalModel(DEVICE, state_hz=50.0, log=log, **model)
        self.paused = threading.Event()
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        self.port = sock.getsockname()[1]
        self.server = MavlinkServer(self.model, sock, FaultInjector(), [], fault_duration)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            if self.paused.is_set():
                time.sleep(0.005)
                continue
            self.server.poll(min(0.02, self.server.next_due() - self.server.elapsed()))

    def __enter__(self) -> SimThread:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=2)
        self.server.sock.close()


def wait_for(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())


def gimbal(port: int, limits: JointLimits) -> MavlinkGimbal:
    return MavlinkGimbal(f"udpout:127.0.0.1:{port}", MavlinkSettings(limits, reply_timeout_s=0.1))


def test_limits_wider_than_the_device_reported_make_the_link_incompatible():
    with SimThread() as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-170), math.radians(170), math.radians(-30), math.radians(60)))
        g.start()
        try:
            assert wait_for(lambda: g.link_state == LinkState.INCOMPATIBLE, 10), (g.link_state, g.last_error)
            assert "pan [-170.0, 170.0] deg exceeds the device's [-120.0, 120.0] deg" in g.last_error
            assert sim.model.primary == (0, 0), "took control of a gimbal it must not drive"
        finally:
            g.stop()


def test_control_is_taken_followed_released_and_a_failure_stops_motion():
    with SimThread(fault_duration=1.0) as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-90), math.radians(90), math.radians(-20), math.radians(60)))
        g.start()
        try:
            assert g.wait_up(10), g.last_error
            assert sim.model.primary == (1, 191)
            assert g.device_limits.pan_max == pytest.approx(DEVICE.pan_max, abs=1e-6)
            # A setpoint beyond the configured limit arrives clamped (host-side limit), and the gimbal goes there.
            for _ in range(150):
                g.send_setpoint(math.radians(100), math.radians(-10), 0.0, 0.0)
                time.sleep(0.01)
            assert wait_for(lambda: abs(g.state.pan - math.radians(90)) < math.radians(0.5), 20), g.state
            assert g.state.tilt == pytest.approx(math.radians(-10), abs=math.radians(0.5))
            assert sim.model.pan.target == pytest.approx(math.radians(90), abs=1e-6)
            # A motor error (bit 5): reported as a driver fault, the device stops, clear_fault is refused ...
            sim.server.faults_at.append((0.0, 5))
            assert wait_for(lambda: g.state.mode == GimbalMode.FAULT, 20), g.state
            assert g.state.faults == 1 << 3 and not g.clear_fault()
            # ... until the device clears it by itself.
            assert wait_for(lambda: g.state.mode == GimbalMode.ENABLED, 20), g.state
            assert g.clear_fault() and g.state.faults == 0
            assert g.set_enabled(False)
            assert sim.model.primary == (0, 0)
            assert wait_for(lambda: g.state.mode == GimbalMode.DISABLED, 20), g.state
            assert g.set_enabled(True) and sim.model.primary == (1, 191)
        finally:
            g.stop()
        assert sim.model.primary == (0, 0), "stop() must release control"


def test_a_manager_stall_finds_few_setpoints_queued_and_the_gimbal_executes_no_burst_on_resume(tmp_path):
    """The simulated manager stops for 2 s (its thread paused, datagrams queue in its UDP socket) while the host
    sweeps pan at 0.5 rad/s with a setpoint every >= 10 ms. GIMBAL_MANAGER_SET_PITCHYAW has no validity, so the
    manager executes on resume whatever queued up: the host must stop sending 5 attitude-status periods (0.1 s at
    50 Hz, estimated from time_boot_ms) after the last status it received, not after the 0.5 s state timeout (before:
    ~48 setpoints queued and executed in a burst). The host reconnects by itself and the sweep restarts from the
    state measured after the resume."""
    log_path = tmp_path / "gimbal.csv"
    device_log = CsvMessageLog(log_path)
    silence = 5 * 0.02  # 5 periods of the simulator's 50 Hz status stream (a floor of 0.1 s too)
    with SimThread(log=device_log) as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-90), math.radians(90), math.radians(-20), math.radians(60)))
        g.start()
        try:
            assert g.wait_up(10), g.last_error
            start = g.state
            sent: list[tuple[int, float, float]] = []  # (count, send time, pan) of every setpoint sent
            t0 = time.monotonic()
            paused_at = None
            while True:
                now = time.monotonic()
                if paused_at is None and now - t0 > 0.5:
                    sim.paused.set()
                    paused_at = time.monotonic()
                if paused_at is not None and now - paused_at > 2.0:
                    break
                pan = start.pan + 0.5 * (now - t0)
                n = g.send_setpoint(pan, start.tilt, 0.5, 0.0)
                if n is not None:
                    sent.append((n, now, pan))  # the link judged the silence at a time >= now
                time.sleep(0.01)
            last_rx = g.state.rx_time  # the newest status received (kept while the link is down)
            into_silence = [(n, t) for n, t, _ in sent if t > last_rx]
            # each setpoint sent had a status at most `silence` old; they were sent >= 10 ms apart
            assert all(t - last_rx <= silence + 1e-3 for _, t in into_silence), (into_silence, last_rx)
            assert len(into_silence) <= silence / 0.01 + 1, into_silence
            c = g.counters()
            assert c["setpoints_withheld"] > 0 and c["silences"] >= 1, c
            assert g.silence_s() == pytest.approx(silence, abs=1e-3)  # not the 0.5 s state timeout
            resumed = time.monotonic()
            sim.paused.clear()
            # the link was lost (no status for 0.5 s) and comes back by itself; the sweep restarts from there
            assert g.wait_up(10), g.last_error
            back = None
            deadline = time.monotonic() + 5
            while back is None and time.monotonic() < deadline:
                st = g.state
                back = st if st.rx_time > resumed and st.mode == GimbalMode.ENABLED else None
                time.sleep(0.01)
            assert back is not None, g.state
            for i in range(20):
                assert g.send_setpoint(back.pan + 0.005 * i, back.tilt, 0.0, 0.0) is not None
                time.sleep(0.01)
            assert g.counters()["reconnects"] == 1
        finally:
            g.stop()
    device_log.close()
    with open(log_path, newline="") as fh:
        rows = list(csv.DictReader(fh))
    rx = [r for r in rows if r["dir"] == "rx"]
    resume = next(i for i in range(1, len(rx)) if float(rx[i]["t_s"]) - float(rx[i - 1]["t_s"]) > 1.0)
    burst = []  # what the manager executed on resuming, before the host's new handshake
    for r in rx[resume:]:
        if r["type"] != "SETPOINT":
            break
        burst.append(float(r["pan"]))
    assert len(burst) <= silence / 0.01 + 1 + 5, len(burst)  # + those still unread when it stopped
    # none aims beyond where the sweep was within `silence` of the last status the host received
    reach = max(pan for _, t, pan in sent if t <= last_rx + silence + 1e-3)
    assert not burst or max(burst) <= reach + 1e-5, (burst, reach)
    # after the reconnect (control taken again) the sweep starts where the gimbal was measured to stand
    taken = max(i for i, r in enumerate(rows) if r["type"] == "GIMBAL_MANAGER_CONFIGURE" and "on=1" in r["detail"])
    first = next(r for r in rows[taken:] if r["dir"] == "rx" and r["type"] == "SETPOINT")
    assert float(first["pan"]) == pytest.approx(back.pan, abs=1e-5)


HEADING = math.radians(90.1)  # the simulated vehicle heads (nearly) East


class HeadingFeed:
    """The vehicle heading given to the link at 20 Hz on its own thread, as a pose stream would."""

    def __init__(self, g: MavlinkGimbal, heading: float) -> None:
        self.g, self.heading = g, heading
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            self.g.set_vehicle_heading(self.heading, 0.0)
            self.stop.wait(0.05)

    def __enter__(self) -> HeadingFeed:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=2)


def drive_and_measure(g: MavlinkGimbal, sim: SimThread, pan: float, tilt: float) -> None:
    """Stream setpoints to (pan, tilt) [rad] until the gimbal stands there; the measured pan and tilt must then
    equal the simulated gimbal's joints (its angles relative to the vehicle) within 0.1 deg."""
    tol = math.radians(0.1)
    for _ in range(150):
        g.send_setpoint(pan, tilt, 0.0, 0.0)
        time.sleep(0.01)
    assert wait_for(lambda: abs(sim.model.pan.pos - pan) < 1e-4 and abs(sim.model.tilt.pos - tilt) < 1e-4, 20), \
        (sim.model.pan, sim.model.tilt)
    assert wait_for(lambda: abs(g.state.pan - sim.model.pan.pos) < tol and abs(g.state.tilt - sim.model.tilt.pos)
                    < tol, 10), (math.degrees(g.state.pan), math.degrees(sim.model.pan.pos), g.state)
    assert abs(g.state.pan_rate) < math.radians(0.1), g.state  # at rest relative to the vehicle


@pytest.mark.parametrize(("frame", "turn_deg_s", "host_heading"), [
    (StatusFrame.VEHICLE, 3.0, False),  # delta_yaw sent but not to be applied
    (StatusFrame.EARTH, 3.0, False),  # delta_yaw / delta_yaw_velocity turn it back, the vehicle turning
    (StatusFrame.EARTH_NO_DELTA, 0.0, True),  # delta_yaw NaN: the heading the host gives
    (StatusFrame.LEGACY_LOCK, 0.0, True),  # YAW_LOCK without a frame flag: earth frame, delta_yaw (0) ignored
    (StatusFrame.LEGACY_FOLLOW, 0.0, False),  # no flag at all: vehicle frame
])
def test_the_measured_pan_is_relative_to_the_vehicle_in_every_frame_the_gimbal_reports_in(frame, turn_deg_s,
                                                                                          host_heading):
    """On a vehicle heading 90.1 deg (turning at 3 deg/s where the device reports the turn), the gimbal driven
    to pan 30 deg, tilt 10 deg is measured there, whatever the frame of its attitude status. Before, the
    earth-frame statuses were read as vehicle-frame ones: pan off by the heading, -60.1 deg."""
    with SimThread(yaw_frame=frame, heading=HEADING, heading_rate=math.radians(turn_deg_s)) as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-90), math.radians(90), math.radians(-20), math.radians(60)))
        feed = HeadingFeed(g, HEADING) if host_heading else contextlib.nullcontext()
        with feed:
            g.start()
            try:
                assert g.wait_up(10), g.last_error
                drive_and_measure(g, sim, math.radians(30), math.radians(10))
                drive_and_measure(g, sim, math.radians(-75), math.radians(-15))
                c = g.counters()
                assert c["heading_unknown"] == c["yaw_frame_invalid"] == 0, c
            finally:
                g.stop()


def test_an_earth_frame_status_without_any_heading_is_dropped_and_the_link_comes_up_once_one_is_given(caplog):
    """delta_yaw NaN and no heading given: every status is dropped (counted, logged once), none is a measured
    state, the link does not come up and says why; once the heading is given, it comes up by itself and measures
    the pan relative to the vehicle."""
    caplog.set_level(logging.WARNING, logger="pivotd.gimbal.mavlink_link")
    with SimThread(yaw_frame=StatusFrame.EARTH_NO_DELTA, heading=HEADING) as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-90), math.radians(90), math.radians(-20), math.radians(60)))
        g.start()
        try:
            assert wait_for(lambda: g.counters()["heading_unknown"] >= 50 and g.last_error, 20), g.counters()
            assert g.link_state != LinkState.UP and g.state is None
            assert "no usable GIMBAL_DEVICE_ATTITUDE_STATUS" in g.last_error, g.last_error
            assert "and no vehicle heading given within 0.5 s" in g.last_error, g.last_error
            dropped = [r for r in caplog.records if "GIMBAL_DEVICE_ATTITUDE_STATUS dropped" in r.getMessage()]
            assert len(dropped) == 1, [r.getMessage() for r in dropped]
            with HeadingFeed(g, HEADING):
                assert g.wait_up(20), g.last_error
                drive_and_measure(g, sim, math.radians(30), math.radians(10))
        finally:
            g.stop()


def test_the_simulator_command_line_reports_yaw_in_the_earth_frame(tmp_path):
    """``tools/mock_gimbal --protocol mavlink --yaw-frame earth --heading-deg 90.1``, a subprocess on UDP: the link
    measures the pan the device log records (relative to the vehicle)."""
    mock, url, dev_log = start_mock_gimbal(tmp_path, "--yaw-frame", "earth", "--heading-deg", "90.1",
                                           backend="mavlink")
    with mock:
        g = MavlinkGimbal(url, MavlinkSettings(JointLimits(math.radians(-90), math.radians(90), math.radians(-20),
                                                           math.radians(60)), reply_timeout_s=0.1))
        g.start()
        try:
            assert g.wait_up(15), (g.last_error, mock.output())
            for _ in range(150):
                g.send_setpoint(math.radians(30), math.radians(10), 0.0, 0.0)
                time.sleep(0.01)
            assert wait_for(lambda: abs(g.state.pan - math.radians(30)) < math.radians(0.1), 20), g.state
        finally:
            g.stop()
    with open(dev_log, newline="") as fh:
        states = [r for r in csv.DictReader(fh) if r["dir"] == "tx" and r["type"] == "STATE"]
    assert float(states[-1]["pan"]) == pytest.approx(math.radians(30), abs=math.radians(0.1))


def test_a_status_with_both_frame_flags_is_dropped_and_counted(caplog):
    """YAW_IN_VEHICLE_FRAME and YAW_IN_EARTH_FRAME together are not allowed: no status is taken as the measured
    state (a given heading does not help), the link does not come up and says why, logged once."""
    caplog.set_level(logging.WARNING, logger="pivotd.gimbal.mavlink_link")
    with SimThread(yaw_frame=StatusFrame.BOTH_FLAGS, heading=HEADING) as sim:
        g = gimbal(sim.port, JointLimits(math.radians(-90), math.radians(90), math.radians(-20), math.radians(60)))
        with HeadingFeed(g, HEADING):
            g.start()
            try:
                assert wait_for(lambda: g.counters()["yaw_frame_invalid"] >= 50 and g.last_error, 20), g.counters()
                assert g.link_state != LinkState.UP and g.state is None
                assert "both YAW_IN_VEHICLE_FRAME and YAW_IN_EARTH_FRAME set (flags 0x60)" in g.last_error, \
                    g.last_error
                assert g.counters()["heading_unknown"] == 0
            finally:
                g.stop()
    dropped = [r for r in caplog.records if "GIMBAL_DEVICE_ATTITUDE_STATUS dropped" in r.getMessage()]
    assert len(dropped) == 1, [r.getMessage() for r in dropped]


def device_states(path) -> list[dict]:
    """The STATE rows (the joints relative to the vehicle) of the simulator's CSV log so far."""
    with open(path, newline="") as fh:
        return [r for r in csv.DictReader(fh) if r["dir"] == "tx" and r["type"] == "STATE" and r.get("pan")]


@pytest.mark.timeout(180)
def test_the_daemon_publishes_the_pan_of_an_earth_frame_gimbal_relative_to_the_vehicle(tmp_path):
    """The real daemon drives ``tools/mock_gimbal --protocol mavlink --yaw-frame earth --heading-deg 90.1`` while
    the simulated robot drives its route; once the robot stops publishing, the daemon holds the gimbal where it
    measured it, and the pan it publishes is the gimbal's (relative to the vehicle) within 0.1 deg. Before, it was
    off by the heading, and the state the control loop restarted from with it."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path, "--yaw-frame", "earth", "--heading-deg", "90.1",
                                           backend="mavlink")
    config = write_config(tmp_path, endpoint, url, "mavlink")
    cfg = load_config(config)
    with mock, start_daemon(config) as daemon:
        assert daemon.wait_stderr("ready", 30), daemon.output()
        probe = BusProbe.connect(endpoint, cfg.topics)
        try:
            with start_sim(endpoint, "--speed", "1.0", "--duration", "8"):
                assert wait_until(lambda: probe.status.get("state") == "tracking", 30), daemon.output()
                assert wait_until(lambda: len({round(float(r["pan"]), 2) for r in device_states(dev_log)}) > 10,
                                  30), daemon.output()

            def at_rest() -> bool:
                docs = [d for d in list(probe.statuses)[-3:] if d.get("gimbal")]
                rows = device_states(dev_log)[-20:]
                return (len(docs) == 3 and probe.status.get("state") != "tracking"
                        and len({d["gimbal"]["pan_deg"] for d in docs}) == 1 and len(rows) == 20
                        and max(float(r["pan"]) for r in rows) - min(float(r["pan"]) for r in rows) < 1e-6)

            assert wait_until(at_rest, 60), (probe.status, daemon.output())
            published = probe.status["gimbal"]["pan_deg"]
            device = math.degrees(float(device_states(dev_log)[-1]["pan"]))
            assert published == pytest.approx(device, abs=0.1), (published, device)
            moved = [math.degrees(float(r["pan"])) for r in device_states(dev_log)]
            assert max(moved) - min(moved) > 5.0, (min(moved), max(moved))  # it tracked, not just stood
            assert probe.status["link_counters"]["heading_unknown"] == 0
        finally:
            probe.close()
        assert daemon.stop(signal.SIGTERM, timeout=20) == 0, daemon.output()


@pytest.mark.timeout(180)
def test_the_daemon_gives_an_earth_frame_gimbal_without_delta_yaw_the_heading_of_its_poses(tmp_path):
    """``--yaw-frame earth-no-delta --heading-deg 90``: the device reports yaw from North and NaN for delta_yaw. The
    robot drives east (+x of the ENU map frame: heading 90 deg), so the heading the daemon passes on from its poses
    turns the status back into the vehicle frame: the link comes up and the pan it publishes is the device's."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path, "--yaw-frame", "earth-no-delta", "--heading-deg", "90",
                                           backend="mavlink")
    config = write_config(tmp_path, endpoint, url, "mavlink")
    cfg = load_config(config)
    route = tmp_path / "east.csv"
    route.write_text("x,y,z\n" + "".join(f"{0.25 * k:.2f},0.0,0.0\n" for k in range(41)))
    sim = ManagedProcess([PYTHON, str(REPO / "tools" / "sim_pose"), "--route", f"csv:{route}", "--connect", endpoint,
                          "--rate", "50", "--quiet", "--wait-subscribers", "15", "--speed", "0.5", "--loop"],
                         "sim_pose")
    with mock, start_daemon(config) as daemon, sim:
        assert daemon.wait_stderr("ready", 30), daemon.output()
        probe = BusProbe.connect(endpoint, cfg.topics)
        try:
            assert wait_until(lambda: probe.status.get("state") == "tracking", 60), (probe.status, daemon.output())

            def steady() -> bool:
                docs = [d for d in list(probe.statuses)[-2:] if d.get("gimbal")]
                rows = device_states(dev_log)[-5:]
                return len(docs) == 2 and len(rows) == 5 and abs(
                    docs[-1]["gimbal"]["pan_deg"] - math.degrees(float(rows[-1]["pan"]))) < 0.5

            assert wait_until(steady, 60), (probe.status, daemon.output())
        finally:
            probe.close()
        assert daemon.stop(signal.SIGTERM, timeout=20) == 0, daemon.output()
