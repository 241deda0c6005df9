"""The MAVLink backend against the simulated gimbal manager, in process, over real UDP on loopback."""

from __future__ import annotations

import math
import socket
import threading
import time

import pytest

from firmware_proto.realtime import FaultInjector
from pivotd.gimbal.interface import GimbalMode, LinkState
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.mavlink_link import MavlinkGimbal, MavlinkSettings
from pivotd.sim.mavlink_device import MavlinkGimbalModel
from pivotd.sim.mavlink_server import MavlinkServer

pytestmark = [pytest.mark.slow, pytest.mark.timeout(60)]

DEVICE = JointLimits(math.radians(-120), math.radians(120), math.radians(-30), math.radians(90))


class SimThread:
    def __init__(self, fault_duration=1.0) -> None:
        self.model = MavlinkGimbalModel(DEVICE, state_hz=50.0)
        sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
        sock.bind(("127.0.0.1", 0))
        self.port = sock.getsockname()[1]
        self.server = MavlinkServer(self.model, sock, FaultInjector(), [], fault_duration)
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
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
