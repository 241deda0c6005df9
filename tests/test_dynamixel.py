"""DYNAMIXEL backend: Protocol 2.0 bytes against the published specification (through the real dynamixel_sdk on a
pty), unit conversions of the X-series control table, and the backend against the simulated servo chain."""

from __future__ import annotations

import math
import os
import pty
import select
import threading
import time
import tty

import pytest

from pivotd.firmware_proto.messages import FAULT_DRIVER, FAULT_OVERCURRENT, FAULT_OVERTEMP
from pivotd.gimbal import dynamixel_table as ct
from pivotd.gimbal.dynamixel_link import DynamixelGimbal, DynamixelSettings, load_sdk
from pivotd.gimbal.interface import GimbalMode, LinkState
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.motion import AxisLimits
from pivotd.sim import dynamixel_protocol as dp
from pivotd.sim.dynamixel_device import DynamixelChain

SDK = load_sdk()
# Published Protocol 2.0 examples: PING to ID 1, and WRITE of Goal Position (116) = 512 to ID 1.
PING_ID1 = bytes.fromhex("ff ff fd 00 01 03 00 01 19 4e")
WRITE_GOAL_512_ID1 = bytes.fromhex("ff ff fd 00 01 09 00 03 74 00 00 02 00 00 ca 89")


@pytest.fixture(autouse=True)
def patient_sdk(monkeypatch):
    """The SDK waits about 34 ms (2 × its 16 ms latency timer + 2 ms) for a status packet; the simulated servos here
    answer from a thread of this process, which a loaded machine may not run that soon: wait up to a second."""
    monkeypatch.setattr(SDK.port_handler, "LATENCY_TIMER", 500)


@pytest.fixture
def pty_pair():
    master, slave = pty.openpty()
    tty.setraw(slave)
    yield master, os.ttyname(slave)
    os.close(master)
    os.close(slave)


def read_all(fd: int, timeout: float = 1.0) -> bytes:
    out = b""
    while select.select([fd], [], [], timeout if not out else 0.05)[0]:
        out += os.read(fd, 4096)
    return out


def test_our_packets_are_the_published_examples():
    assert dp.encode(1, dp.INST_PING) == PING_ID1
    assert dp.encode(1, dp.INST_WRITE, bytes.fromhex("74 00 00 02 00 00")) == WRITE_GOAL_512_ID1
    assert dp.crc16(WRITE_GOAL_512_ID1[:-2]) == 0x89CA


def test_the_sdk_sends_the_published_bytes_and_reads_stuffed_status_packets(pty_pair):
    master, path = pty_pair
    port = SDK.PortHandler(path)
    assert port.openPort() and port.setBaudRate(1_000_000)
    ph = SDK.PacketHandler(2.0)
    try:
        ph.write4ByteTxOnly(port, 1, ct.GOAL_POSITION[0], 512)
        assert read_all(master) == WRITE_GOAL_512_ID1
        # A status packet whose data holds FF FF FD is stuffed (LEN counts the extra FD); the SDK removes it.
        reply = dp.status(1, 0, bytes([0xFF, 0xFF, 0xFD, 0x01]))
        assert reply[5] == 9 and b"\xff\xff\xfd\xfd\x01" in reply  # INST, ERR, 4 data, FD, CRC

        def answer() -> None:  # at once: the SDK waits about 34 ms for a status packet (a second here)
            select.select([master], [], [], 2.0)
            os.read(master, 4096)
            os.write(master, reply)

        t = threading.Thread(target=answer)
        t.start()
        data, comm, error = ph.readTxRx(port, 1, 200, 4)
        t.join()
        assert (comm, error, list(data)) == (SDK.COMM_SUCCESS, 0, [0xFF, 0xFF, 0xFD, 0x01])
    finally:
        port.closePort()


def test_stuffing_follows_the_specification_and_goal_positions_never_need_it():
    body = bytes([dp.INST_WRITE, 200, 0, 0xFF, 0xFF, 0xFD, 0x01])
    assert dp.stuff(body) == bytes([dp.INST_WRITE, 200, 0, 0xFF, 0xFF, 0xFD, 0xFD, 0x01])
    assert dp.unstuff(dp.stuff(body)) == body
    (pkt,) = dp.PacketDecoder().feed(dp.encode(1, dp.INST_WRITE, body[1:]))
    assert pkt.params == body[1:]
    # dynamixel_sdk 4.1 does not stuff what it sends (its addStuffing rebinds a local list when the packet
    # grows); the Sync Write of goal positions (0..4095: high bytes 0) can never contain FF FF FD.
    for ticks in range(4096):
        goal = ticks.to_bytes(4, "little")
        params = bytes([116, 0, 4, 0, 1]) + goal + bytes([2]) + goal
        assert b"\xff\xff\xfd" not in params


def test_control_table_conversions():
    assert ct.GOAL_POSITION == (116, 4) and ct.PRESENT_POSITION == (132, 4) and ct.PRESENT_VELOCITY == (128, 4)
    assert ct.BUS_WATCHDOG == (98, 1) and ct.HARDWARE_ERROR_STATUS == (70, 1) and ct.TORQUE_ENABLE == (64, 1)
    assert ct.PROFILE_VELOCITY == (112, 4) and ct.PROFILE_ACCELERATION == (108, 4) and ct.OPERATING_MODE == (11, 1)
    assert ct.MAX_POSITION_LIMIT == (48, 4) and ct.MIN_POSITION_LIMIT == (52, 4)
    assert ct.angle_to_ticks(math.pi / 2) == 3072 and ct.angle_to_ticks(math.pi / 2, reversed_axis=True) == 1024
    assert ct.ticks_to_angle(1024) == pytest.approx(-math.pi / 2)
    # rounded inwards: 60° is 682.67 ticks from the centre
    assert ct.limits_to_ticks(math.radians(-60), math.radians(60)) == (2048 - 682, 2048 + 682)
    assert ct.limits_to_ticks(math.radians(-30), math.radians(60), reversed_axis=True) == (2048 - 682, 2048 + 341)
    # 0.229 rev/min and 214.577 rev/min² units, rounded down so the servo never exceeds our limit
    assert ct.velocity_units(math.radians(90)) == 65  # 90°/s = 15 rev/min = 65.5 units
    assert ct.velocity_units(math.radians(90)) * ct.VELOCITY_UNIT <= math.radians(90)
    assert ct.acceleration_units(math.radians(360)) == 16  # 360°/s² = 3600 rev/min² = 16.8 units
    assert ct.watchdog_units(250) == 13 and ct.watchdog_units(5) == 1 and ct.watchdog_units(60000) == 127
    assert ct.hardware_faults(1 << 2) == FAULT_OVERTEMP and ct.hardware_faults(1 << 5) == FAULT_OVERCURRENT
    assert ct.hardware_faults(1 << 4) == FAULT_DRIVER and ct.hardware_faults(1 << 1 | 1 << 6) == 0


class ChainOnPty:
    """The simulated servo chain served on a pty by a thread (what ``tools/mock_gimbal --protocol dynamixel``
    runs, in process)."""

    def __init__(self) -> None:
        self.chain = DynamixelChain((1, 2))
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)
        os.set_blocking(self.master, False)
        self.path = os.ttyname(self.slave)
        self.t0 = time.monotonic()
        self.lock = threading.Lock()
        self.stop = threading.Event()
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self.stop.is_set():
            ready = select.select([self.master], [], [], 0.002)[0]
            data = b""
            if ready:
                try:
                    data = os.read(self.master, 4096)
                except OSError:
                    data = b""
            with self.lock:
                out = self.chain.feed(data, time.monotonic() - self.t0) if data else b""
                self.chain.step(time.monotonic() - self.t0)
            if out:
                os.write(self.master, out)

    def __enter__(self) -> ChainOnPty:
        self.thread.start()
        return self

    def __exit__(self, *exc) -> None:
        self.stop.set()
        self.thread.join(timeout=2)
        os.close(self.master)
        os.close(self.slave)


def wait_for(predicate, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if predicate():
            return True
        time.sleep(0.01)
    return bool(predicate())


AXIS = AxisLimits(math.radians(90), math.radians(360), math.radians(1800))


def settings(limits: JointLimits, **kw) -> DynamixelSettings:
    return DynamixelSettings(limits, AXIS, AXIS, **kw)


@pytest.mark.slow
def test_limits_beyond_the_position_range_make_the_link_incompatible():
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(JointLimits(-3.5, 3.5, -1.0, 1.0)), baudrate=1_000_000)
        g.start()
        try:
            assert wait_for(lambda: g.link_state == LinkState.INCOMPATIBLE, 20), g.last_error
            assert "within ±180°" in g.last_error
            assert not any(s.torque for s in sim.chain.servos.values())
        finally:
            g.stop()


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_servos_are_configured_from_our_limits_follow_fault_reboot_and_stop_on_their_watchdog():
    limits = JointLimits(math.radians(-90), math.radians(90), math.radians(-30), math.radians(60))
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(limits, tilt_reversed=True, watchdog_ms=300), baudrate=1_000_000)
        g.start()
        try:
            assert g.wait_up(20), g.last_error
            pan, tilt = sim.chain.servos[1], sim.chain.servos[2]
            assert (pan.get(ct.MIN_POSITION_LIMIT), pan.get(ct.MAX_POSITION_LIMIT)) == (1024, 3072)
            assert (tilt.get(ct.MIN_POSITION_LIMIT), tilt.get(ct.MAX_POSITION_LIMIT)) == (2048 - 682, 2048 + 341)
            assert pan.get(ct.PROFILE_VELOCITY) == 65 and pan.get(ct.PROFILE_ACCELERATION) == 16
            assert pan.get(ct.BUS_WATCHDOG) == 15 and pan.torque and tilt.torque
            assert pan.get(ct.OPERATING_MODE) == ct.POSITION_CONTROL_MODE
            # Setpoints (one beyond the pan limit: clamped on the host) are followed; the reversed tilt servo
            # turns the other way.
            for _ in range(200):
                g.send_setpoint(math.radians(120), math.radians(20))
                time.sleep(0.005)
            assert wait_for(lambda: abs(g.state.pan - math.radians(90)) < 0.01
                            and abs(g.state.tilt - math.radians(20)) < 0.01, 20), g.state
            assert tilt.axis.pos == pytest.approx(math.radians(-20), abs=0.01)
            # Overheating on the pan servo: fault, torque off; clear_fault reboots it and torque comes back.
            with sim.lock:
                sim.chain.inject_error(1, 1 << 2, time.monotonic() - sim.t0)
            assert wait_for(lambda: g.state.mode == GimbalMode.FAULT, 20), g.state
            assert g.state.faults == FAULT_OVERTEMP
            assert g.clear_fault(timeout=10.0)
            assert wait_for(lambda: g.state.mode == GimbalMode.ENABLED and g.state.faults == 0, 20), g.state
            assert g.counters()["reboots"] == 1
            # The host goes silent (a crash, an unplugged cable): the servos' Bus Watchdog stops them.
            for _ in range(50):
                g.send_setpoint(math.radians(-60), math.radians(-20))
                time.sleep(0.005)
            g.stop(disable=False)
            assert wait_for(lambda: pan.watchdog_expired and tilt.watchdog_expired, 20)
            with sim.lock:
                held = (pan.axis.pos, tilt.axis.pos)
            assert wait_for(lambda: pan.axis.vel == 0.0 and tilt.axis.vel == 0.0, 20)
            time.sleep(0.3)
            with sim.lock:
                assert abs(pan.axis.pos - held[0]) < math.radians(20)  # braked, did not go on to -60°
                assert pan.axis.pos > math.radians(-59)
        finally:
            g.stop()


@pytest.mark.slow
def test_disabling_turns_the_torque_off():
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(JointLimits(-1.0, 1.0, -0.5, 0.5)), baudrate=1_000_000)
        g.start()
        try:
            assert g.wait_up(20), g.last_error
            assert g.set_enabled(False)
            assert not any(s.torque for s in sim.chain.servos.values())
            assert wait_for(lambda: g.state.mode == GimbalMode.DISABLED, 20)
            assert g.send_setpoint(0.2, 0.1) is not None  # accepted, but not written while the torque is off
            time.sleep(0.1)
            assert sim.chain.servos[1].get(ct.GOAL_POSITION) != ct.angle_to_ticks(0.2)
        finally:
            g.stop()


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_a_configuration_cut_short_after_a_reboot_is_completed_before_the_fault_is_called_cleared():
    """A status packet lost half-way through configuring a rebooted servo (Profile Velocity written, no answer):
    clear_fault says False; the next clear_fault, and torque on, configure it again (the reboot reset its
    profile and its Bus Watchdog to 0: no speed limit, no watchdog) before they report success."""
    limits = JointLimits(math.radians(-90), math.radians(90), math.radians(-30), math.radians(60))
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(limits, watchdog_ms=300), baudrate=1_000_000)
        g.start()
        try:
            assert g.wait_up(20), g.last_error
            pan = sim.chain.servos[1]
            handle, lost = sim.chain._handle, []

            def lose_one_answer(pkt, now, sent_us):  # the device model's answer to one WRITE goes missing
                out = handle(pkt, now, sent_us)
                if not lost and pkt.inst == dp.INST_WRITE and pkt.dxl_id == 1 and (
                        int.from_bytes(pkt.params[:2], "little") == ct.PROFILE_VELOCITY[0]):
                    lost.append(now)
                    return b""
                return out

            sim.chain._handle = lose_one_answer
            with sim.lock:
                sim.chain.inject_error(1, 1 << 2, time.monotonic() - sim.t0)
            assert wait_for(lambda: g.state.mode == GimbalMode.FAULT, 20), g.state
            assert not g.clear_fault(timeout=10.0)  # rebooted, then a write went unanswered
            assert lost and g.counters()["reboots"] == 1
            assert pan.get(ct.BUS_WATCHDOG) == 0  # (the watchdog is written last: still off)
            assert g.clear_fault(timeout=10.0)
            assert pan.get(ct.PROFILE_VELOCITY) == 65 and pan.get(ct.BUS_WATCHDOG) == 15
            assert g.set_enabled(True, timeout=10.0) and pan.torque
            assert g.counters()["reboots"] == 1  # configured again, not rebooted again
        finally:
            g.stop()
