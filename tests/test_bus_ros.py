"""rmw_zenoh wire conventions: key expressions, type hashes, QoS strings, attachments, liveliness keys."""

import struct

import pytest

from pivotd.bus import ros
from pivotd.errors import ConfigError

# Published values: rmw_zenoh docs/design.md (std_msgs/String) and `ros2 topic info -v` output of ROS 2 systems.
KNOWN_HASHES = {
    "std_msgs/msg/String": "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18",
    "nav_msgs/msg/Odometry": "RIHS01_3cc97dc7fb7502f8714462c526d369e35b603cfc34d946e3f2eda2766dfec6e0",
    "sensor_msgs/msg/JointState": "RIHS01_a13ee3a330e346c9d87b5aa18d24e11690752bd33a0350f11c5882bc9179260e",
    "sensor_msgs/msg/PointCloud2": "RIHS01_9198cabf7da3796ae6fe19c4cb3bdd3525492988c70522628af5daa124bae2b5",
    "nav_msgs/msg/Path": "RIHS01_1957a5bb3cee5da65c4e52e52b65a93df227efce4c20f8458b36e73066ca334b",
}


@pytest.mark.parametrize("msgtype", sorted(KNOWN_HASHES))
def test_type_hash_matches_published_value(msgtype):
    assert ros.type_hash(msgtype) == KNOWN_HASHES[msgtype]


def test_type_hash_shape_for_pivotd_types():
    for t in ("sensor_msgs/msg/JointState", "nav_msgs/msg/Path", "sensor_msgs/msg/PointCloud2",
              "geometry_msgs/msg/PoseStamped"):
        h = ros.type_hash(t)
        assert h.startswith("RIHS01_") and len(h) == 7 + 64
        int(h[7:], 16)


def test_unknown_type_is_config_error():
    with pytest.raises(ConfigError, match="unknown ROS message type"):
        ros.type_hash("nope_msgs/msg/Nothing")


def test_dds_type_names():
    assert ros.dds_type_name("std_msgs/msg/String") == "std_msgs::msg::dds_::String_"
    assert ros.ros_type_from_dds("sensor_msgs::msg::dds_::PointCloud2_") == "sensor_msgs/msg/PointCloud2"
    assert ros.ros_type_from_dds("garbage") is None
    with pytest.raises(ConfigError):
        ros.dds_type_name("String")


def test_topic_key_matches_rmw_zenoh_examples():
    # rmw_zenoh docs/design.md: chatter, and chatter in namespace /robot1.
    h = KNOWN_HASHES["std_msgs/msg/String"]
    assert ros.topic_key(0, "/chatter", "std_msgs/msg/String") == f"0/chatter/std_msgs::msg::dds_::String_/{h}"
    assert ros.topic_key(0, "/robot1/chatter/", "std_msgs/msg/String") == (
        f"0/robot1/chatter/std_msgs::msg::dds_::String_/{h}")
    assert ros.topic_key(7, "odom", "nav_msgs/msg/Odometry", "*") == "7/odom/nav_msgs::msg::dds_::Odometry_/*"
    assert ros.topic_key(0, "/odom", None, "*") == "0/odom/*/*"


@pytest.mark.parametrize("bad", ["", "/", "a//b", "a/*", "with space"])
def test_bad_topic_names_rejected(bad):
    with pytest.raises(ConfigError, match="topic"):
        ros.topic_key(0, bad, "std_msgs/msg/String")


def test_msgtype_of_key():
    assert ros.msgtype_of_key("0/a/b/nav_msgs::msg::dds_::Path_/RIHS01_x") == "nav_msgs/msg/Path"
    assert ros.msgtype_of_key("0/a/b/nav_msgs::msg::dds_::Path_/TypeHashNotSupported") == "nav_msgs/msg/Path"
    assert ros.msgtype_of_key("pivot/status") is None


def test_qos_strings_match_rmw_zenoh_format():
    # rmw_zenoh design.md examples: keep_last depth 10 and 7, everything else default.
    assert ros.qos_to_keyexpr(ros.QoS(depth=10)) == "::,10:,:,:,,"
    assert ros.qos_to_keyexpr(ros.QoS(depth=7)) == "::,7:,:,:,,"
    assert ros.qos_to_keyexpr(ros.QoS(depth=42)) == "::,:,:,:,,"
    assert ros.qos_to_keyexpr(ros.QoS(reliability=2, durability=1, depth=1)) == "2:1:,1:,:,:,,"


def test_liveliness_keys_follow_rmw_zenoh_layout():
    h = KNOWN_HASHES["std_msgs/msg/String"]
    node = ros.node_token_key(2, "aac3178e146ba6f1fc6e6a4085e77f21", 0, "listener")
    assert node == "@ros2_lv/2/aac3178e146ba6f1fc6e6a4085e77f21/0/0/NN/%/%/listener"
    pub = ros.entity_token_key(ros.PUBLISHER, 2, "8b20917502ee955ac4476e0266340d5c", 0, 10, "talker", "/chatter",
                               "std_msgs/msg/String", ros.QoS(depth=7))
    assert pub == (f"@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/"
                   f"std_msgs::msg::dds_::String_/{h}/::,7:,:,:,,")
    sub = ros.entity_token_key(ros.SUBSCRIPTION, 0, "z", 1, 11, "pivotd", "/pivot/landmarks",
                               "sensor_msgs/msg/PointCloud2", ros.QoS(depth=2), namespace="/robot1")
    parts = sub.split("/")
    assert parts[:9] == ["@ros2_lv", "0", "z", "1", "11", "MS", "%", "%robot1", "pivotd"]
    assert parts[9] == "%pivot%landmarks"
    assert parts[10] == "sensor_msgs::msg::dds_::PointCloud2_"
    assert len(parts) == 13


def test_attachment_layout_bytes():
    gid = bytes(range(16))
    raw = ros.Attachment(sequence=5, source_time_ns=1_700_000_000_123_456_789, gid=gid).encode()
    assert len(raw) == 33
    assert raw[:8] == struct.pack("<q", 5)
    assert raw[8:16] == struct.pack("<q", 1_700_000_000_123_456_789)
    assert raw[16] == 16
    assert raw[17:] == gid
    back = ros.Attachment.decode(raw)
    assert back == ros.Attachment(5, 1_700_000_000_123_456_789, gid)


def test_attachment_rejects_bad_bytes():
    with pytest.raises(ValueError, match="33"):
        ros.Attachment.decode(b"\x00" * 20)
    raw = bytearray(ros.Attachment(1, 2, bytes(16)).encode())
    raw[16] = 24
    with pytest.raises(ValueError, match="length prefix"):
        ros.Attachment.decode(bytes(raw))
    with pytest.raises(ValueError):
        ros.Attachment(1, 2, b"short").encode()


def test_gid_is_stable_and_distinct():
    a = ros.gid_from_key("@ros2_lv/0/x/0/10/MP/%/%/n/%a/T/H/::,:,:,:,,")
    assert a == ros.gid_from_key("@ros2_lv/0/x/0/10/MP/%/%/n/%a/T/H/::,:,:,:,,")
    assert a != ros.gid_from_key("@ros2_lv/0/x/0/11/MP/%/%/n/%a/T/H/::,:,:,:,,")
    assert len(a) == 16
