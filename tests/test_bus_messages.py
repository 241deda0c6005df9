"""CDR codecs of pivotd's ROS messages: round trips through rosbags and validation of bad input."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from pivotd.bus import messages as m
from pivotd.bus.ros import typestore
from pivotd.geometry import normalize, quat_to_matrix

TOPIC = "/odom"
Q90 = np.array([0.0, 0.0, np.sin(np.pi / 4), np.cos(np.pi / 4)])


def rosbags_msg(name, **kw):
    return typestore().types[name](**kw)


def pose_stamped_from_rosbags(frame="map", pos=(1.0, 2.0, 3.0), quat=(0.0, 0.0, 0.0, 1.0), big_endian=False):
    T = typestore().types
    msg = T["geometry_msgs/msg/PoseStamped"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=12, nanosec=500_000_000),
                                        frame_id=frame),
        pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=pos[0], y=pos[1], z=pos[2]),
                                         orientation=T["geometry_msgs/msg/Quaternion"](
                                             x=quat[0], y=quat[1], z=quat[2], w=quat[3])))
    return bytes(typestore().serialize_cdr(msg, m.POSE_STAMPED, little_endian=not big_endian))


# ------------------------------------------------------------------------------------------ round trips


def test_cdr_header_is_little_endian_encapsulation():
    assert m.encode_pose_stamped(1.0, "map", [0, 0, 0], [0, 0, 0, 1])[:4] == b"\x00\x01\x00\x00"


def test_odometry_round_trip():
    payload = m.encode_odometry(1234.25, "map", "base_link", [1.0, -2.0, 0.5], Q90, [0.8, 0.0, 0.0])
    s = m.decode_pose(payload, m.ODOMETRY, TOPIC, rx_time=7.0)
    assert s.stamp == pytest.approx(1234.25)
    assert s.frame_id == "map" and s.rx_time == 7.0
    np.testing.assert_allclose(s.position, [1.0, -2.0, 0.5])
    np.testing.assert_allclose(s.quat, Q90)
    raw = typestore().deserialize_cdr(payload, m.ODOMETRY)
    assert raw.child_frame_id == "base_link"
    assert raw.twist.twist.linear.x == pytest.approx(0.8)


def test_pose_stamped_from_rosbags_and_big_endian():
    for big in (False, True):
        s = m.decode_pose(pose_stamped_from_rosbags(big_endian=big), m.POSE_STAMPED, "/pose")
        assert s.stamp == pytest.approx(12.5)
        np.testing.assert_allclose(s.position, [1, 2, 3])


def test_pose_with_covariance_stamped_as_amcl_publishes_it():
    """Built field by field with rosbags (not our encoder), big- and little-endian, with a real covariance."""
    T = typestore().types
    cov = np.diag([0.04, 0.04, 0.0, 0.0, 0.0, 0.01]).reshape(36)
    msg = T[m.POSE_WITH_COVARIANCE_STAMPED](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=40, nanosec=250_000_000),
                                        frame_id="map"),
        pose=T["geometry_msgs/msg/PoseWithCovariance"](
            pose=T["geometry_msgs/msg/Pose"](position=T["geometry_msgs/msg/Point"](x=3.0, y=-1.0, z=0.0),
                                             orientation=T["geometry_msgs/msg/Quaternion"](
                                                 x=Q90[0], y=Q90[1], z=Q90[2], w=Q90[3])),
            covariance=cov))
    for big in (False, True):
        payload = bytes(typestore().serialize_cdr(msg, m.POSE_WITH_COVARIANCE_STAMPED, little_endian=not big))
        s = m.decode_pose(payload, m.POSE_WITH_COVARIANCE_STAMPED, "/amcl_pose")
        assert s.stamp == pytest.approx(40.25) and s.frame_id == "map"
        np.testing.assert_allclose(s.position, [3, -1, 0])
        np.testing.assert_allclose(s.quat, Q90)
    ours = m.encode_pose_with_covariance_stamped(40.25, "map", [3, -1, 0], Q90, cov)
    assert ours == bytes(typestore().serialize_cdr(msg, m.POSE_WITH_COVARIANCE_STAMPED))
    for msgtype in m.POSE_TYPES:  # the encoder of each pose type decodes as that type
        s = m.decode_pose(m.encode_pose(msgtype, 1.0, "map", [3, -1, 0], Q90), msgtype, "/p")
        np.testing.assert_allclose(s.position, [3, -1, 0])
    with pytest.raises(m.MessageError):  # a PoseStamped payload is too short for this type
        m.decode_pose(pose_stamped_from_rosbags(), m.POSE_WITH_COVARIANCE_STAMPED, "/amcl_pose")


def test_quaternion_is_normalized():
    s = m.decode_pose(pose_stamped_from_rosbags(quat=(0.0, 0.0, 0.0, 2.0)), m.POSE_STAMPED, "/pose")
    np.testing.assert_allclose(s.quat, [0, 0, 0, 1])


def test_path_round_trip_and_zero_quaternions():
    pos = np.array([[0.0, 0.0, 0.0], [1.0, 0.0, 0.0], [2.0, 1.0, 0.5]])
    quats = np.array([[0, 0, 0, 1.0], [0, 0, 0, 0.0], Q90])
    p = m.decode_path(m.encode_path(5.0, "map", pos, quats), "/plan")
    np.testing.assert_allclose(p.positions, pos)
    np.testing.assert_allclose(p.quats, [[0, 0, 0, 1], [0, 0, 0, 1], Q90], atol=1e-12)
    assert p.stamp == 5.0 and p.frame_id == "map"


def test_joint_state_encoding_decodes_with_rosbags():
    payload = m.encode_joint_state(10.5, ["pan", "tilt"], [0.1, -0.2], [0.3, 0.4])
    js = typestore().deserialize_cdr(payload, m.JOINT_STATE)
    assert list(js.name) == ["pan", "tilt"]
    np.testing.assert_allclose(js.position, [0.1, -0.2])
    np.testing.assert_allclose(js.velocity, [0.3, 0.4])
    assert len(js.effort) == 0
    assert js.header.stamp.sec == 10 and js.header.stamp.nanosec == 500_000_000


def test_view_plan_orientation_z_axis_is_direction():
    rng = np.random.default_rng(1)
    dirs = normalize(rng.normal(size=(20, 3)))
    dirs[0] = [0, 0, 1.0]  # parallel to world up: still a valid frame
    pos = rng.normal(size=(20, 3))
    p = m.decode_path(m.encode_view_plan(3.0, "map", pos, dirs), "/pivot/view_plan")
    R = quat_to_matrix(p.quats)
    np.testing.assert_allclose(R[:, :, 2], dirs, atol=1e-9)
    np.testing.assert_allclose(p.positions, pos)
    # Optical convention: image x (right) stays horizontal for non-vertical views.
    assert np.all(np.abs(R[1:, 2, 0]) < 1e-9)
    with pytest.raises(ValueError):
        m.encode_view_plan(3.0, "map", pos, dirs[:5])


def test_cloud_round_trip_with_weights():
    pts = np.array([[1.0, 2.0, 3.0], [-1.5, 0.25, 8.0]])
    c = m.decode_cloud(m.encode_cloud(2.0, "map", pts, np.array([0.5, 2.0])), "/pivot/landmarks")
    np.testing.assert_allclose(c.points, pts)
    np.testing.assert_allclose(c.weights, [0.5, 2.0])
    assert c.points.dtype == np.float64 and c.stamp == 2.0


@pytest.mark.parametrize("big_endian", [False, True])
@pytest.mark.parametrize("point_step", [None, 20, 32])
def test_cloud_layouts(big_endian, point_step):
    rng = np.random.default_rng(2)
    pts = rng.normal(size=(12, 3)).astype(np.float32).astype(float)
    c = m.decode_cloud(m.encode_cloud(0.0, "map", pts, big_endian=big_endian, point_step=point_step, height=3,
                                      row_padding=7), "/c")
    np.testing.assert_array_equal(c.points, pts)
    assert c.weights is None


def test_cloud_drops_nan_points_and_bad_weights():
    pts = np.array([[0, 0, 0], [np.nan, 1, 1], [2, 2, np.inf], [3, 3, 3], [4, 4, 4]], float)
    w = np.array([1.0, 1.0, 1.0, np.nan, 2.0])
    c = m.decode_cloud(m.encode_cloud(0.0, "map", pts, w), "/c")
    np.testing.assert_array_equal(c.points, [[0, 0, 0], [4, 4, 4]])
    np.testing.assert_array_equal(c.weights, [1.0, 2.0])


def test_empty_cloud_is_valid():
    c = m.decode_cloud(m.encode_cloud(0.0, "map", np.zeros((0, 3))), "/c")
    assert c.points.shape == (0, 3) and c.weights is None


def test_cloud_float64_fields_from_rosbags():
    T = typestore().types
    pts = np.array([[1.0, 2.0, 3.0], [4.0, 5.0, 6.0]])
    data = np.zeros((2, 32), np.uint8)
    data[:, 8:32] = pts.astype("<f8").view(np.uint8).reshape(2, 24)
    pf = T["sensor_msgs/msg/PointField"]
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=1, nanosec=0), frame_id="map"),
        height=1, width=2, fields=[pf(name=n, offset=8 + 8 * i, datatype=8, count=1) for i, n in enumerate("xyz")],
        is_bigendian=False, point_step=32, row_step=64, data=data.reshape(-1), is_dense=True)
    c = m.decode_cloud(bytes(typestore().serialize_cdr(msg, m.POINT_CLOUD2)), "/c")
    np.testing.assert_array_equal(c.points, pts)


@settings(max_examples=40, deadline=None)
@given(n=st.integers(0, 50), pad=st.integers(0, 12), big=st.booleans(), weighted=st.booleans(),
       seed=st.integers(0, 2**31 - 1))
def test_cloud_round_trip_property(n, pad, big, weighted, seed):
    rng = np.random.default_rng(seed)
    pts = rng.uniform(-100, 100, size=(n, 3)).astype(np.float32).astype(float)
    w = rng.uniform(0, 5, n).astype(np.float32).astype(float) if weighted else None
    c = m.decode_cloud(m.encode_cloud(1.0, "map", pts, w, big_endian=big, point_step=(16 if weighted else 12) + pad),
                       "/c")
    np.testing.assert_array_equal(c.points, pts)
    if weighted:
        np.testing.assert_array_equal(c.weights, w)
    else:
        assert c.weights is None


# ------------------------------------------------------------------------------------------ validation


def reason_of(fn, *args, **kw):
    with pytest.raises(m.MessageError) as info:
        fn(*args, **kw)
    assert str(info.value).startswith(args[2] if fn is m.decode_pose else args[1])  # names the topic
    assert "\n" not in str(info.value)
    return info.value.reason


@pytest.mark.parametrize("bad", [[np.nan, 0, 0], [0, np.inf, 0]])
def test_nonfinite_pose_rejected(bad):
    assert reason_of(m.decode_pose, m.encode_odometry(0, "map", "b", bad, [0, 0, 0, 1]), m.ODOMETRY, TOPIC) == (
        "nonfinite")


def test_nan_quaternion_and_zero_quaternion_rejected():
    assert reason_of(m.decode_pose, m.encode_pose_stamped(0, "map", [0, 0, 0], [0, 0, np.nan, 1]),
                     m.POSE_STAMPED, TOPIC) == "nonfinite"
    assert reason_of(m.decode_pose, m.encode_pose_stamped(0, "map", [0, 0, 0], [0, 0, 0, 0]),
                     m.POSE_STAMPED, TOPIC) == "zero_quaternion"


def test_frame_policy():
    payload = m.encode_odometry(0, "odom", "b", [0, 0, 0], [0, 0, 0, 1])
    assert reason_of(m.decode_pose, payload, m.ODOMETRY, TOPIC) == "wrong_frame"
    assert m.decode_pose(payload, m.ODOMETRY, TOPIC, expected_frame=None).frame_id == "odom"
    assert m.decode_pose(m.encode_odometry(0, "/map", "b", [0, 0, 0], [0, 0, 0, 1]), m.ODOMETRY, TOPIC).frame_id
    empty = m.encode_odometry(0, "", "b", [0, 0, 0], [0, 0, 0, 1])
    assert m.decode_pose(empty, m.ODOMETRY, TOPIC).frame_id == "map"
    assert reason_of(m.decode_pose, empty, m.ODOMETRY, TOPIC, accept_empty_frame=False) == "wrong_frame"


@pytest.mark.parametrize("payload", [b"", b"\x00\x01", b"\x07\x07\x00\x00abcd", b"\x00\x01\x00\x00" + b"\xff" * 7])
def test_malformed_pose_payloads(payload):
    assert reason_of(m.decode_pose, payload, m.ODOMETRY, TOPIC) == "malformed"


def test_truncated_and_mistyped_payloads():
    good = m.encode_odometry(0, "map", "b", [0, 0, 0], [0, 0, 0, 1])
    assert reason_of(m.decode_pose, good[: len(good) // 2], m.ODOMETRY, TOPIC) == "malformed"
    assert reason_of(m.decode_pose, good, "std_msgs/msg/String", TOPIC) == "wrong_type"
    # A Path payload decoded as Odometry must not pass as a pose.
    with pytest.raises(m.MessageError):
        m.decode_pose(m.encode_path(0, "map", np.zeros((1, 3))), m.ODOMETRY, TOPIC)


def test_path_validation():
    assert reason_of(m.decode_path, m.encode_path(0, "map", np.zeros((0, 3))), "/plan") == "empty"
    assert reason_of(m.decode_path, m.encode_path(0, "map", [[0, 0, 0], [np.nan, 0, 0]]), "/plan") == "nonfinite"
    assert reason_of(m.decode_path, m.encode_path(0, "odom", [[0, 0, 0]]), "/plan") == "wrong_frame"


def test_cloud_validation():
    pts = np.zeros((10, 3))
    assert reason_of(m.decode_cloud, m.encode_cloud(0, "map", pts), "/c", max_points=9) == "oversized"
    assert m.decode_cloud(m.encode_cloud(0, "map", pts), "/c", max_points=10).points.shape == (10, 3)
    assert reason_of(m.decode_cloud, m.encode_cloud(0, "base", pts), "/c") == "wrong_frame"
    # A huge payload is refused before decoding.
    assert reason_of(m.decode_cloud, b"\x00\x01\x00\x00" + bytes(200_000), "/c", max_points=10) == "oversized"


def _cloud_msg(fields, data, width, point_step, row_step):
    T = typestore().types
    pf = T["sensor_msgs/msg/PointField"]
    msg = T["sensor_msgs/msg/PointCloud2"](
        header=T["std_msgs/msg/Header"](stamp=T["builtin_interfaces/msg/Time"](sec=0, nanosec=0), frame_id="map"),
        height=1, width=width, fields=[pf(name=n, offset=o, datatype=d, count=1) for n, o, d in fields],
        is_bigendian=False, point_step=point_step, row_step=row_step, data=np.frombuffer(data, np.uint8), is_dense=True)
    return bytes(typestore().serialize_cdr(msg, m.POINT_CLOUD2))


def test_cloud_bad_fields_and_layouts():
    xy = [("x", 0, 7), ("y", 4, 7)]
    assert reason_of(m.decode_cloud, _cloud_msg(xy, bytes(8), 1, 8, 8), "/c") == "bad_fields"
    ints = [("x", 0, 5), ("y", 4, 5), ("z", 8, 5)]
    assert reason_of(m.decode_cloud, _cloud_msg(ints, bytes(12), 1, 12, 12), "/c") == "bad_fields"
    xyz = [("x", 0, 7), ("y", 4, 7), ("z", 8, 7)]
    assert reason_of(m.decode_cloud, _cloud_msg(xyz, bytes(20), 2, 12, 24), "/c") == "malformed"  # data too short
    assert reason_of(m.decode_cloud, _cloud_msg(xyz, bytes(16), 2, 8, 16), "/c") == "malformed"  # z beyond step
    assert reason_of(m.decode_cloud, _cloud_msg(xyz, bytes(24), 2, 12, 12), "/c") == "malformed"  # row_step small


def _rosbags_path_arrays(payload: bytes) -> tuple[np.ndarray, np.ndarray]:
    msg = m.typestore().deserialize_cdr(payload, m.PATH)
    pos = np.array([[p.pose.position.x, p.pose.position.y, p.pose.position.z] for p in msg.poses]).reshape(-1, 3)
    quat = np.array([[p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z, p.pose.orientation.w]
                     for p in msg.poses]).reshape(-1, 4)
    return pos, quat


def test_path_decoder_reads_exactly_what_rosbags_reads():
    """The direct CDR reader against rosbags' generic decoder: random sizes, stamps, frame ids of varying length
    per pose (the strided fast path and the record-by-record path), both byte orders."""
    t = m.typestore().types
    rng = np.random.default_rng(7)
    for trial in range(150):
        n = int(rng.integers(0, 60))
        pos, quat = rng.normal(size=(n, 3)) * 1e3, rng.normal(size=(n, 4))
        mixed = trial % 3 == 0
        frames = ["map" if not mixed else "f" * int(rng.integers(0, 9)) for _ in range(n)]
        poses = [t[m.POSE_STAMPED](header=t["std_msgs/msg/Header"](stamp=m.seconds_to_stamp(rng.uniform(0, 1e9)),
                                                                      frame_id=frames[i]),
                                   pose=t["geometry_msgs/msg/Pose"](
                                       position=t["geometry_msgs/msg/Point"](x=pos[i, 0], y=pos[i, 1], z=pos[i, 2]),
                                       orientation=t["geometry_msgs/msg/Quaternion"](x=quat[i, 0], y=quat[i, 1],
                                                                                     z=quat[i, 2], w=quat[i, 3])))
                 for i in range(n)]
        msg = t[m.PATH](header=t["std_msgs/msg/Header"](stamp=m.seconds_to_stamp(12.5), frame_id="map"), poses=poses)
        little = bytes(m.typestore().serialize_cdr(msg, m.PATH))
        big = bytes(m.typestore().serialize_cdr(msg, m.PATH, little_endian=False))
        for payload in (little, big):
            stamp, frame, p, q = m.path_arrays(payload, "/plan")
            ref_p, ref_q = _rosbags_path_arrays(payload)
            assert stamp == 12.5 and frame == "map"
            np.testing.assert_array_equal(p, ref_p)
            np.testing.assert_array_equal(q, ref_q)


def test_large_path_decodes_to_its_poses_and_truncations_are_malformed():
    from pivotd.bus.large_messages import large_path

    payload = large_path(200_000, step=0.5)
    path = m.decode_path(payload, "/plan")
    ref_p, _ = _rosbags_path_arrays(payload)
    np.testing.assert_array_equal(path.positions, ref_p)
    assert len(payload) >= 200_000 and path.positions.shape[0] > 2500
    for cut in (5, 30, len(payload) // 2, len(payload) - 1):
        assert reason_of(m.decode_path, payload[:cut], "/plan") == "malformed"
