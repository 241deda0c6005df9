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


def test_a_zero_tick_moves_angle_zero_and_the_limits_with_it():
    assert ct.angle_to_ticks(0.0, zero=1000) == 1000 and ct.angle_to_ticks(math.pi / 2, zero=1000) == 2024
    assert ct.angle_to_ticks(math.pi / 2, reversed_axis=True, zero=3000) == 1976
    assert ct.ticks_to_angle(2024, zero=1000) == pytest.approx(math.pi / 2)
    assert ct.ticks_to_angle(1976, reversed_axis=True, zero=3000) == pytest.approx(math.pi / 2)
    assert ct.limits_to_ticks(math.radians(-60), math.radians(90), zero=1000) == (1000 - 682, 1000 + 1024)
    assert ct.limits_to_ticks(math.radians(-30), math.radians(45), True, 3000) == (3000 - 512, 3000 + 341)
    # At 2048, ±180° less a tick fits; around tick 1000 only -87.9° … +272.0° does.
    assert ct.position_limits_problem("pan", math.radians(-179.9), math.radians(179.9)) is None
    assert ct.position_limits_problem("pan", math.radians(-87), math.radians(150), zero=1000) is None
    problem = ct.position_limits_problem("pan", math.radians(-90), math.radians(90), zero=1000)
    assert problem is not None and "ticks [-24, 2024]" in problem and "[-87.9, 272.0]°" in problem, problem
    # Reversed, the reachable range is mirrored: -272.0° … +87.9°.
    assert ct.position_limits_problem("tilt", math.radians(-10), math.radians(89), True, 1000) is not None
    assert ct.position_limits_problem("tilt", math.radians(-200), math.radians(87), True, 1000) is None


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_with_zero_ticks_commanded_zero_lands_on_them_and_the_limits_follow(tmp_path):
    limits = JointLimits(math.radians(-60), math.radians(90), math.radians(-30), math.radians(45))
    with ChainOnPty() as sim:
        # The pty's own latency_timer, as sysfs would show it for a U2D2 left at the FTDI default.
        (tmp_path / os.path.basename(sim.path)).mkdir()
        (tmp_path / os.path.basename(sim.path) / "latency_timer").write_text("16\n")
        g = DynamixelGimbal(sim.path, settings(limits, tilt_reversed=True, pan_zero_tick=1000, tilt_zero_tick=3000,
                                               control_period_s=0.01), baudrate=1_000_000, usb_serial_root=tmp_path)
        g.start()
        try:
            assert g.wait_up(20), g.last_error
            assert g.latency_warning is not None and "is 16 ms" in g.latency_warning
            assert g.bus_warning is None  # 1 Mbps: 2.1 ms of a 10 ms period
            pan, tilt = sim.chain.servos[1], sim.chain.servos[2]
            assert (pan.get(ct.MIN_POSITION_LIMIT), pan.get(ct.MAX_POSITION_LIMIT)) == (1000 - 682, 1000 + 1024)
            assert (tilt.get(ct.MIN_POSITION_LIMIT), tilt.get(ct.MAX_POSITION_LIMIT)) == (3000 - 512, 3000 + 341)
            # The servos start at their centre (tick 2048): pan +92.1° (held at its limit, 90°), tilt +83.5°
            # (beyond +45°: held at 45°).
            assert pan.get(ct.GOAL_POSITION) == 2024 and tilt.get(ct.GOAL_POSITION) == 2488
            for _ in range(100):
                g.send_setpoint(0.0, 0.0)
                time.sleep(0.005)
            assert wait_for(lambda: pan.get(ct.GOAL_POSITION) == 1000 and tilt.get(ct.GOAL_POSITION) == 3000, 20)
            assert wait_for(lambda: pan.get(ct.PRESENT_POSITION) == 1000 and tilt.get(ct.PRESENT_POSITION) == 3000
                            and abs(g.state.pan) < 1e-9 and abs(g.state.tilt) < 1e-9, 20), g.state
            # Beyond the limits: clamped on the host to the limit's tick, which the servo accepts.
            for _ in range(100):
                g.send_setpoint(math.radians(120), math.radians(-50))
                time.sleep(0.005)
            assert wait_for(lambda: pan.get(ct.GOAL_POSITION) == 2024 and tilt.get(ct.GOAL_POSITION) == 3341, 20)
            assert wait_for(lambda: abs(g.state.pan - math.radians(90)) < 0.01
                            and abs(g.state.tilt - math.radians(-30)) < 0.01, 20), g.state
            assert g.counters()["write_errors"] == 0
        finally:
            g.stop()


@pytest.mark.slow
def test_limits_beyond_the_ticks_around_a_zero_tick_make_the_link_incompatible():
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(JointLimits(-1.0, 1.0, math.radians(-60), math.radians(60)),
                                                tilt_zero_tick=300))
        g.start()
        try:
            assert wait_for(lambda: g.link_state == LinkState.INCOMPATIBLE, 20), g.last_error
            assert "tilt limits [-60, 60]° are ticks [-382, 982] around zero tick 300" in g.last_error
            assert not any(s.torque for s in sim.chain.servos.values())
        finally:
            g.stop()


@pytest.mark.slow
def test_a_servo_that_does_not_answer_gets_a_hint_naming_port_id_and_baud(tmp_path):
    with ChainOnPty() as sim:
        g = DynamixelGimbal(sim.path, settings(JointLimits(-1.0, 1.0, -0.5, 0.5), pan_id=5, control_period_s=0.01),
                            usb_serial_root=tmp_path)  # the default baud; no latency_timer there: no warning
        g.start()
        try:
            assert wait_for(lambda: g.last_error is not None and "id 5" in g.last_error, 20), g.last_error
            msg = g.last_error
            assert "\n" not in msg and "ping on servo 5: [TxRxResult] There is no status packet!" in msg, msg
            assert f"no answer from id 5 on {sim.path} at 57600 baud" in msg, msg
            assert all(w in msg for w in ("gimbal.dynamixel.pan_id", "gimbal.baud", "12 V", "TTL", "RS-485")), msg
            assert g.link_state != LinkState.UP and g.latency_warning is None
            assert g.bus_warning is not None and "at least 35.8 ms, longer than the control period 10 ms" in (
                g.bus_warning)
        finally:
            g.stop()


def test_the_latency_timer_of_the_adapter_behind_the_port_is_read_through_its_symlink(tmp_path):
    from pivotd.gimbal.dynamixel_link import latency_timer_problem

    sysfs = tmp_path / "usb-serial"
    (sysfs / "ttyUSB7").mkdir(parents=True)
    timer = sysfs / "ttyUSB7" / "latency_timer"
    dev = tmp_path / "dev"
    dev.mkdir()
    (dev / "ttyUSB7").write_text("")
    by_id = tmp_path / "usb-FTDI_USB__-__Serial_Converter_X-if00-port0"
    by_id.symlink_to(dev / "ttyUSB7")
    timer.write_text("16\n")
    problem = latency_timer_problem(str(by_id), sysfs)
    assert problem is not None and f"{timer} is 16 ms" in problem and "echo 1 >" in problem, problem
    timer.write_text("1\n")
    assert latency_timer_problem(str(by_id), sysfs) is None
    timer.write_text("garbage\n")
    assert latency_timer_problem(str(by_id), sysfs) is None
    assert latency_timer_problem(str(dev / "ttyACM0"), sysfs) is None  # no such adapter: nothing to say


def gimbal_cli_config(tmp_path, port: str) -> str:
    path = tmp_path / "servos.yaml"
    path.write_text(f"""\
map: {{allow_empty: true}}
gimbal:
  backend: dynamixel
  port: {port}
  baud: 1000000
  dynamixel: {{pan_zero_tick: 1024}}
  limits: {{pan_min_deg: -80, pan_max_deg: 170, tilt_min_deg: -45, tilt_max_deg: 90}}
""")
    return str(path)


@pytest.mark.slow
@pytest.mark.timeout(60)
def test_gimbal_ping_and_goto_against_the_servos(tmp_path, capsys):
    from pivotd.cli import main

    with ChainOnPty() as sim:
        config = gimbal_cli_config(tmp_path, sim.path)
        pan, tilt = sim.chain.servos[1], sim.chain.servos[2]
        # Outside the limits: refused before a byte goes to the servos.
        assert main(["gimbal", "--config", config, "goto", "175", "0"]) == 2
        err = capsys.readouterr().err
        assert "pivotd gimbal: error: goto: pan 175° is outside gimbal.limits pan [-80, 170]°" in err, err
        assert sim.chain.packets == 0
        # The servos sit at their centre (tick 2048): pan reads +90° around its zero tick 1024.
        assert main(["gimbal", "--config", config, "ping"]) == 0
        out = capsys.readouterr().out
        assert f"gimbal dynamixel at {sim.path}: up, pan 90.00°, tilt 0.00°" in out, out
        assert not pan.torque and not tilt.torque  # disabled again at exit
        assert main(["gimbal", "--config", config, "goto", "30", "-20"]) == 0
        out = capsys.readouterr().out
        assert "reached pan 30." in out or "reached pan 29." in out, out
        with sim.lock:
            assert abs(pan.get(ct.PRESENT_POSITION) - (1024 + 341)) <= 6  # 30° = 341.3 ticks past 1024, ±0.5°
            assert abs(tilt.get(ct.PRESENT_POSITION) - (2048 - 228)) <= 6
            assert pan.get(ct.GOAL_POSITION) == 1024 + 341 and tilt.get(ct.GOAL_POSITION) == 2048 - 228
            assert not pan.torque and not tilt.torque


@pytest.mark.slow
@pytest.mark.timeout(90)
def test_gimbal_scan_visits_each_axis_limits_less_the_margin_and_zero(tmp_path, capsys):
    from pivotd.cli import main

    with ChainOnPty() as sim:
        config = gimbal_cli_config(tmp_path, sim.path)
        assert main(["gimbal", "--config", config, "scan", "--margin", "70"]) == 2
        assert "--margin: 70° leaves nothing of the tilt range (135°" in capsys.readouterr().err
        assert sim.chain.packets == 0
        assert main(["gimbal", "--config", config, "scan", "--margin", "60"]) == 0
        out = capsys.readouterr().out
        targets = [line.split("(target ")[1] for line in out.splitlines() if line.startswith("reached")]
        assert targets == ["pan -20.00°, tilt 0.00°)", "pan 110.00°, tilt 0.00°)", "pan 0.00°, tilt 0.00°)",
                           "pan 0.00°, tilt 15.00°)", "pan 0.00°, tilt 30.00°)", "pan 0.00°, tilt 0.00°)"], out
        assert sim.chain.servos[1].get(ct.GOAL_POSITION) == 1024 and sim.chain.servos[2].get(ct.GOAL_POSITION) == 2048


def test_the_simulator_logs_joint_angles_around_the_zero_ticks_and_directions_it_is_given(tmp_path):
    import csv
    import struct

    from pivotd.firmware_proto.realtime import CsvMessageLog

    log = CsvMessageLog(tmp_path / "servos.csv")
    chain = DynamixelChain((1, 2), log=log, zero_ticks=(1000, 3000), reversed_axes=(False, True))
    goals = struct.pack("<HH", *ct.GOAL_POSITION) + bytes([1]) + (1341).to_bytes(4, "little") + bytes([2]) + (
        2800).to_bytes(4, "little")
    chain.feed(dp.encode(dp.BROADCAST_ID, dp.INST_SYNC_WRITE, goals), 0.0)
    chain.step(0.05)
    log.close()
    with open(tmp_path / "servos.csv") as f:
        rows = list(csv.DictReader(f))
    setpoint = next(r for r in rows if r["type"] == "SETPOINT")
    assert float(setpoint["pan"]) == pytest.approx(341 * ct.POSITION_RESOLUTION, abs=1e-6)
    assert float(setpoint["tilt"]) == pytest.approx(200 * ct.POSITION_RESOLUTION, abs=1e-6)  # reversed
    state = next(r for r in rows if r["type"] == "STATE")  # the servos rest at their centre, tick 2048
    assert float(state["pan"]) == pytest.approx((2048 - 1000) * ct.POSITION_RESOLUTION, abs=1e-6)
    assert float(state["tilt"]) == pytest.approx(-(2048 - 3000) * ct.POSITION_RESOLUTION, abs=1e-6)


def test_the_bus_traffic_of_a_control_period_against_the_baud_rate():
    from pivotd.gimbal.dynamixel_link import bus_rate_problem

    # Sync Write 24 bytes, Sync Read 16, two status packets of 11 + 72: 206 bytes of 10 bit times
    assert ct.bus_cycle_s(57600) == pytest.approx(2060 / 57600)
    assert ct.bus_cycle_s(1_000_000) == pytest.approx(2.06e-3)
    assert bus_rate_problem(1_000_000, 0.01) is None and bus_rate_problem(57600, None) is None
    assert bus_rate_problem(57600, 0.04) is None  # 25 Hz fits at the factory baud rate
    problem = bus_rate_problem(115200, 0.01)
    assert problem is not None and "at 115200 baud" in problem and "17.9 ms" in problem, problem
