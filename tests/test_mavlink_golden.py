"""MAVLink backend, byte for byte against the published common.xml definitions (MAVLink 2 framing).

The expected frames are packed here by hand from the definitions: message id, CRC extra, the wire order of the
fields (sorted by type size, extensions last), units and signs (pitch positive up, yaw positive right, quaternion
w, x, y, z in the FRD vehicle frame). The expected angles come from pivotd's own geometry (pan/tilt → direction),
not from the conversion module under test, so a simulator sharing the backend's conventions cannot hide a
mistake in them.
"""

from __future__ import annotations

import math
import struct

import numpy as np
import pytest

from pivotd.firmware_proto.messages import FAULT_DRIVER, FAULT_ENCODER, FAULT_UNDERVOLTAGE
from pivotd.geometry import direction_to_pan_tilt, pan_tilt_to_direction
from pivotd.gimbal import mavlink_frames as mf
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.mavlink_link import configure_message, load_mavutil, setpoint_message

MAVUTIL = load_mavutil()
ML = MAVUTIL.mavlink

# common.xml: (message id, CRC extra)
HEARTBEAT = (0, 50)
COMMAND_LONG = (76, 152)
GIMBAL_MANAGER_INFORMATION = (280, 70)
GIMBAL_MANAGER_STATUS = (281, 48)
GIMBAL_DEVICE_ATTITUDE_STATUS = (285, 137)
GIMBAL_MANAGER_SET_PITCHYAW = (287, 1)
MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE = 1001
US = (1, 191)
MANAGER = (1, 154)


def crc_x25(data: bytes) -> int:
    """CRC-16/MCRF4XX as MAVLink specifies it (poly 0x1021 reflected, init 0xFFFF, no final xor)."""
    crc = 0xFFFF
    for byte in data:
        tmp = byte ^ (crc & 0xFF)
        tmp = (tmp ^ (tmp << 4)) & 0xFF
        crc = ((crc >> 8) ^ (tmp << 8) ^ (tmp << 3) ^ (tmp >> 4)) & 0xFFFF
    return crc


def frame_v2(msg: tuple[int, int], payload: bytes, seq: int = 0, src: tuple[int, int] = US) -> bytes:
    """A MAVLink 2 frame: trailing zero bytes of the payload dropped (one kept), CRC over header and payload
    and the CRC extra."""
    msgid, extra = msg
    payload = payload.rstrip(b"\x00") or payload[:1]
    header = struct.pack("<BBBBBBBHB", 0xFD, len(payload), 0, 0, seq, src[0], src[1], msgid & 0xFFFF, msgid >> 16)
    crc = crc_x25(header[1:] + payload + bytes([extra]))
    return header + payload + struct.pack("<H", crc)


class _Sink:
    def __init__(self) -> None:
        self.data = b""

    def write(self, b: bytes) -> None:
        self.data += bytes(b)


def packed(msg, src: tuple[int, int] = US) -> bytes:
    sink = _Sink()
    mav = ML.MAVLink(sink, srcSystem=src[0], srcComponent=src[1])
    mav.send(msg)
    return sink.data


def test_crc_matches_the_check_value_of_crc16_mcrf4xx():
    assert crc_x25(b"123456789") == 0x6F91


def expected_pitch_yaw(pan: float, tilt: float) -> tuple[float, float]:
    """MAVLink pitch (positive up) and yaw (positive right) of the optical axis, from pivotd's geometry: the axis in
    the FLU base frame, turned into FRD (y and z flip)."""
    d = pan_tilt_to_direction(pan, tilt)
    x, y, z = d[0], -d[1], -d[2]
    return math.atan2(-z, math.hypot(x, y)), math.atan2(y, x)


def test_the_setpoint_is_gimbal_manager_set_pitchyaw_byte_for_byte():
    pan, tilt, pan_rate, tilt_rate = 0.3, 0.2, 0.5, -0.25  # turned left, looking down
    pitch, yaw = expected_pitch_yaw(pan, tilt)
    assert pitch < 0 and yaw < 0  # down is negative pitch, left is negative yaw
    # a small step along the rates gives the rates' signs in MAVLink terms
    h = 1e-6
    p2, y2 = expected_pitch_yaw(pan + h * pan_rate, tilt + h * tilt_rate)
    pitch_rate, yaw_rate = (p2 - pitch) / h, (y2 - yaw) / h
    limits = JointLimits(-3.0, 3.0, -1.5, 1.5)
    msg = setpoint_message(ML, MANAGER, 0, limits, pan, tilt, pan_rate, tilt_rate)
    # wire order: flags u32, pitch, yaw, pitch_rate, yaw_rate f32, target_system, target_component, device u8
    payload = struct.pack("<IffffBBB", 32, pitch, yaw, pitch_rate, yaw_rate, *MANAGER, 0)
    want = frame_v2(GIMBAL_MANAGER_SET_PITCHYAW, payload)
    got = packed(msg)
    assert got[:10] == want[:10]
    np.testing.assert_allclose(struct.unpack_from("<ffff", got, 14), struct.unpack_from("<ffff", want, 14), atol=2e-6)
    assert len(got) == len(want) and got[10:14] == want[10:14]  # flags: yaw in the vehicle frame (32)
    assert got[30:-2] == want[30:-2] == bytes(MANAGER)  # target system, component; device 0 truncated away
    # the CRC (with CRC extra 1) of the frame as sent
    assert struct.unpack("<H", got[-2:])[0] == crc_x25(got[1:-2] + bytes([GIMBAL_MANAGER_SET_PITCHYAW[1]]))


def test_a_setpoint_outside_the_limits_leaves_clamped_with_zero_rate_on_that_axis():
    limits = JointLimits(-1.0, 1.0, -0.5, 0.5)
    msg = setpoint_message(ML, MANAGER, 154, limits, 2.0, 0.2, 1.0, 0.3)
    assert (msg.yaw, msg.yaw_rate) == pytest.approx((-1.0, 0.0))
    assert (msg.pitch, msg.pitch_rate) == pytest.approx((-0.2, -0.3))
    assert msg.gimbal_device_id == 154 and msg.flags == 32


@pytest.mark.parametrize("take", [True, False])
def test_taking_and_releasing_control_is_do_gimbal_manager_configure_byte_for_byte(take):
    msg = configure_message(ML, MANAGER, US, 0, take)
    params = (1.0, 191.0, -1.0, -1.0, 0.0, 0.0, 0.0) if take else (-3.0, -3.0, -1.0, -1.0, 0.0, 0.0, 0.0)
    # wire order: param1..7 f32, command u16, target_system, target_component, confirmation u8
    payload = struct.pack("<7fHBBB", *params, MAV_CMD_DO_GIMBAL_MANAGER_CONFIGURE, *MANAGER, 0)
    assert packed(msg) == frame_v2(COMMAND_LONG, payload)


def quat_wxyz_frd(pitch: float, yaw: float) -> tuple[float, float, float, float]:
    """Rotation Rz(yaw)·Ry(pitch) as (w, x, y, z), built from its matrix with pivotd.geometry (x, y, z, w)."""
    from pivotd.geometry import matrix_to_quat

    cy, sy, cp, sp = math.cos(yaw), math.sin(yaw), math.cos(pitch), math.sin(pitch)
    Rz = np.array([[cy, -sy, 0], [sy, cy, 0], [0, 0, 1]])
    Ry = np.array([[cp, 0, sp], [0, 1, 0], [-sp, 0, cp]])
    x, y, z, w = matrix_to_quat(Rz @ Ry)
    return w, x, y, z


@pytest.mark.parametrize(("pan_deg", "tilt_deg"), [(30, 20), (-120, -35), (0, 80), (170, 5)])
def test_attitude_status_bytes_decode_to_the_joint_angles_that_point_the_same_way(pan_deg, tilt_deg):
    pan, tilt = math.radians(pan_deg), math.radians(tilt_deg)
    pitch, yaw = expected_pitch_yaw(pan, tilt)
    q = quat_wxyz_frd(pitch, yaw)
    # the quaternion turns FRD x̂ into the optical axis
    from pivotd.geometry import quat_to_matrix

    axis_frd = quat_to_matrix(np.array([q[1], q[2], q[3], q[0]])) @ np.array([1.0, 0.0, 0.0])
    np.testing.assert_allclose(direction_to_pan_tilt(axis_frd * [1, -1, -1]), (pan, tilt), atol=1e-9)
    # wire order: time_boot_ms u32, q[4], angular velocity x, y, z f32, failure_flags u32, flags u16,
    # target_system, target_component u8; extensions: delta_yaw, delta_yaw_velocity f32, gimbal_device_id u8
    wz = -0.4  # yawing left at 0.4 rad/s = pan rate +0.4
    payload = struct.pack("<I4f3fIHBBffB", 1234, *q, 0.0, 0.0, wz, 32, 32, 0, 0, math.nan, math.nan, 1)
    raw = frame_v2(GIMBAL_DEVICE_ATTITUDE_STATUS, payload, src=MANAGER)
    parser = ML.MAVLink(None)
    (msg,) = parser.parse_buffer(raw)
    assert msg.get_type() == "GIMBAL_DEVICE_ATTITUDE_STATUS" and msg.failure_flags == 32 and msg.gimbal_device_id == 1
    got = mf.joints_from_attitude(msg.q, msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z)
    np.testing.assert_allclose(got[:3], (pan, tilt, 0.4), atol=2e-6)
    assert mf.device_faults(msg.failure_flags) == FAULT_DRIVER  # motor error


def test_unknown_angular_velocity_gives_unknown_rates():
    q = quat_wxyz_frd(0.1, 0.2)
    rates = mf.joints_from_attitude(q, math.nan, math.nan, math.nan)[2:]
    assert all(math.isnan(r) for r in rates)


def test_manager_information_and_status_decode_with_their_published_layout():
    # GIMBAL_MANAGER_INFORMATION wire order: time_boot_ms, cap_flags u32, roll/pitch/yaw min/max f32, device u8
    payload = struct.pack("<II6fB", 10, 32 | 256, 0.0, 0.0, -1.5, 0.5, -2.0, 2.5, 154)
    (info,) = ML.MAVLink(None).parse_buffer(frame_v2(GIMBAL_MANAGER_INFORMATION, payload, src=MANAGER))
    lim = mf.joint_limits_from_manager(info.pitch_min, info.pitch_max, info.yaw_min, info.yaw_max)
    # pitch up 0.5 .. down 1.5 → tilt (positive down) −0.5 .. 1.5; yaw right 2.5 .. left 2.0 → pan −2.5 .. 2.0
    assert (lim.tilt_min, lim.tilt_max, lim.pan_min, lim.pan_max) == pytest.approx((-0.5, 1.5, -2.5, 2.0))
    # GIMBAL_MANAGER_STATUS wire order: time_boot_ms, flags u32, device, primary sys/comp, secondary sys/comp u8
    payload = struct.pack("<IIBBBBB", 10, 32, 154, *US, 0, 0)
    (st,) = ML.MAVLink(None).parse_buffer(frame_v2(GIMBAL_MANAGER_STATUS, payload, src=MANAGER))
    assert (st.primary_control_sysid, st.primary_control_compid) == US


def test_our_heartbeat_is_an_onboard_controller_byte_for_byte():
    msg = ML.MAVLink_heartbeat_message(18, 8, 0, 0, 4, 3)
    payload = struct.pack("<IBBBBB", 0, 18, 8, 0, 4, 3)
    assert packed(msg) == frame_v2(HEARTBEAT, payload)


def test_device_failures_map_to_pivotd_fault_bits_and_limit_flags_are_no_faults():
    assert mf.device_faults(8) == FAULT_ENCODER
    assert mf.device_faults(16) == FAULT_UNDERVOLTAGE
    assert mf.device_faults(1 | 2 | 4 | 256 | 512) == 0  # at a limit, calibrating, no manager


def test_limits_wider_than_the_device_are_refused_with_the_numbers():
    device = JointLimits(-1.0, 1.0, -0.5, 1.0)
    assert mf.limits_problem(JointLimits(-0.9, 0.9, -0.4, 0.9), device, False) is None
    msg = mf.limits_problem(JointLimits(-1.2, 0.9, -0.4, 0.9), device, False)
    assert msg == "gimbal.limits pan [-68.8, 51.6] deg exceeds the device's [-57.3, 57.3] deg"
    assert "tilt" in mf.limits_problem(JointLimits(-0.9, 0.9, -0.6, 0.9), device, False)
    assert "infinite yaw" in mf.limits_problem(JointLimits(continuous_pan=True), device, False)


def test_the_frame_flags_are_the_values_pymavlink_generates_from_common_xml():
    assert mf.GIMBAL_DEVICE_FLAGS_YAW_LOCK == ML.GIMBAL_DEVICE_FLAGS_YAW_LOCK == 16
    assert mf.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME == ML.GIMBAL_DEVICE_FLAGS_YAW_IN_VEHICLE_FRAME == 32
    assert mf.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME == ML.GIMBAL_DEVICE_FLAGS_YAW_IN_EARTH_FRAME == 64


@pytest.mark.parametrize(("flags", "frame"), [
    (32, mf.YawFrame.VEHICLE), (32 | 16, mf.YawFrame.VEHICLE),  # the frame flag rules over the lock
    (64, mf.YawFrame.EARTH), (64 | 8 | 4, mf.YawFrame.EARTH),
    (16, mf.YawFrame.EARTH_LEGACY), (16 | 8 | 4, mf.YawFrame.EARTH_LEGACY),  # no frame flag: YAW_LOCK = earth
    (0, mf.YawFrame.VEHICLE), (8 | 4, mf.YawFrame.VEHICLE),
    (32 | 64, mf.YawFrame.INVALID),
])
def test_the_yaw_frame_follows_the_flags_by_the_rule_of_common_xml(flags, frame):
    assert mf.yaw_frame(flags) == frame


def quat_wxyz_frd_roll(pitch: float, yaw: float, roll: float) -> tuple[float, float, float, float]:
    """Rz(yaw)·Ry(pitch)·Rx(roll) as (w, x, y, z), built from its matrix with pivotd.geometry (x, y, z, w)."""
    from pivotd.geometry import matrix_to_quat, quat_to_matrix

    cr, sr = math.cos(roll), math.sin(roll)
    Rx = np.array([[1, 0, 0], [0, cr, -sr], [0, sr, cr]])
    w, x, y, z = quat_wxyz_frd(pitch, yaw)
    x, y, z, w = matrix_to_quat(quat_to_matrix(np.array([x, y, z, w])) @ Rx)
    return w, x, y, z


@pytest.mark.parametrize(("pan_deg", "tilt_deg", "roll_deg", "heading_deg"),
                         [(30, 20, 0, 90.1), (-120, -35, 0, -170), (170, 5, 0, 45), (40, 30, 12, 90.1)])
def test_an_earth_frame_attitude_status_decodes_to_the_joints_relative_to_the_vehicle(pan_deg, tilt_deg, roll_deg,
                                                                                        heading_deg):
    """YAW_IN_EARTH_FRAME with the vehicle's heading in delta_yaw: the quaternion is the camera's attitude from
    North (yaw = the relative yaw + heading), the angular velocity's z is the relative yaw rate + the vehicle's
    turn rate (delta_yaw_velocity), x and y in the earth axes. Decoded with delta_yaw, it gives the joints of the
    optical axis relative to the vehicle; pitch and roll are untouched by the turn."""
    pan, tilt, roll, heading = (math.radians(a) for a in (pan_deg, tilt_deg, roll_deg, heading_deg))
    pitch, yaw = expected_pitch_yaw(pan, tilt)
    q = quat_wxyz_frd_roll(pitch, yaw + heading, roll)
    pan_rate, tilt_rate, turn = 0.4, -0.2, 0.3  # rad/s: the joints, and the vehicle turning right
    yaw_rate_earth, pitch_rate = -pan_rate + turn, -tilt_rate
    ye = yaw + heading
    wx, wy = -math.sin(ye) * pitch_rate, math.cos(ye) * pitch_rate  # zero roll rate, earth axes
    payload = struct.pack("<I4f3fIHBBffB", 1234, *q, wx, wy, yaw_rate_earth, 0, 64, 0, 0, heading, turn, 1)
    (msg,) = ML.MAVLink(None).parse_buffer(frame_v2(GIMBAL_DEVICE_ATTITUDE_STATUS, payload, src=MANAGER))
    assert mf.yaw_frame(msg.flags) == mf.YawFrame.EARTH
    got = mf.joints_from_attitude(msg.q, msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z,
                                  msg.delta_yaw, msg.delta_yaw_velocity)
    np.testing.assert_allclose(got, (pan, tilt, pan_rate, tilt_rate), atol=2e-6)
    # decoded as if it were in the vehicle frame, pan is off by the heading (the bug this guards against)
    old = mf.joints_from_attitude(msg.q, msg.angular_velocity_x, msg.angular_velocity_y, msg.angular_velocity_z)
    assert abs(mf.wrap_pi(old[0] - pan) + heading) < 1e-5 and old[1] == pytest.approx(tilt, abs=2e-6)


def test_an_unknown_turn_rate_gives_an_unknown_pan_rate_and_a_known_tilt_rate():
    q = quat_wxyz_frd(0.1, 0.2 + 1.5)
    pan, tilt, pan_rate, tilt_rate = mf.joints_from_attitude(q, 0.0, 0.0, 0.3, 1.5, math.nan)
    assert (pan, tilt) == pytest.approx((-0.2, -0.1)) and math.isnan(pan_rate) and tilt_rate == pytest.approx(0.0)


@pytest.mark.parametrize(("enu_yaw_deg", "pitch_deg", "heading_deg"),
                         [(0, 0, 90), (90, 0, 0), (-0.1, 0, 90.1), (180, 0, -90), (30, 20, 60)])
def test_the_heading_of_a_pose_in_an_east_aligned_world_frame(enu_yaw_deg, pitch_deg, heading_deg):
    """REP-103 world frame x East, y North: a body facing East has the MAVLink heading 90 deg (clockwise from
    North); pitching the body does not change it."""
    from pivotd.geometry import matrix_to_quat

    y, p = math.radians(enu_yaw_deg), math.radians(pitch_deg)
    Rz = np.array([[math.cos(y), -math.sin(y), 0], [math.sin(y), math.cos(y), 0], [0, 0, 1]])
    Ry = np.array([[math.cos(p), 0, math.sin(p)], [0, 1, 0], [-math.sin(p), 0, math.cos(p)]])
    heading = mf.heading_from_body_quat(matrix_to_quat(Rz @ Ry))
    assert mf.wrap_pi(heading - math.radians(heading_deg)) == pytest.approx(0.0, abs=1e-9)
