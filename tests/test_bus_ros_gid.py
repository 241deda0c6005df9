"""Publisher GIDs exactly as rmw_zenoh computes them: XXH3-128 of the liveliness key, low 64 bits first.

The reference is an independent plain-Python XXH3-128 (tests/xxh3_reference.py), not the ``xxhash``
package pivotd uses; the byte order is rmw_zenoh's (``memcpy`` of ``low64`` then ``high64`` on a
little-endian host).
"""

import queue

import pytest
from bus_support import drain, session_pair, wait_for
from xxh3_reference import xxh3_128

from pivotd.bus import ros
from pivotd.bus.ros_gid import gid_hex, rmw_zenoh_gid

TALKER_KEY = ("@ros2_lv/2/8b20917502ee955ac4476e0266340d5c/0/10/MP/%/%/talker/%chatter/std_msgs::msg::dds_::String_/"
              "RIHS01_df668c740482bbd48fb39d76a70dfd4bd59db1288021743503259e948f6b1a18/::,7:,:,:,,")


def reference_gid(key: str) -> bytes:
    low, high = xxh3_128(key.encode())
    return low.to_bytes(8, "little") + high.to_bytes(8, "little")


def test_golden_gid_of_the_rmw_zenoh_design_talker():
    # Computed once with tests/xxh3_reference.py for the talker token of rmw_zenoh's docs/design.md.
    assert rmw_zenoh_gid(TALKER_KEY) == bytes.fromhex("ac170f31eadcd9ff0cd86d7a17907d1c")
    assert reference_gid(TALKER_KEY) == rmw_zenoh_gid(TALKER_KEY)
    assert gid_hex(rmw_zenoh_gid(TALKER_KEY)).startswith("ac.17.0f.31.")


def _token_keys() -> list[str]:
    """Real token keys of every length class XXH3 distinguishes (<=16, 17-128, 129-240, >240 bytes)."""
    zid = "aac3178e146ba6f1fc6e6a4085e77f21"
    keys = ["@ros2_lv", "@ros2_lv/0/z/0/0/NN/%/%/a", ros.node_token_key(0, zid, 0, "pivotd")]
    for ns, topic, msgtype in [("/", "/pivot/joint_states", "sensor_msgs/msg/JointState"),
                               ("/robot1", "/pivot/view_plan", "nav_msgs/msg/Path"),
                               ("/fleet/site_a/robot_17", "/fleet/site_a/robot_17/pivot/markers",
                                "visualization_msgs/msg/MarkerArray")]:
        for kind in (ros.PUBLISHER, ros.SUBSCRIPTION):
            for qos in (ros.QoS(depth=10), ros.QoS(durability=ros.DURABILITY_TRANSIENT_LOCAL, depth=1)):
                keys.append(ros.entity_token_key(kind, 0, zid, 0, 12, "pivotd", topic, msgtype, qos, ns))
    keys.append(ros.entity_token_key(ros.PUBLISHER, 0, zid, 0, 12, "pivotd", "/odom", "nav_msgs/msg/Odometry",
                                     ros.QoS(), hash_part=ros.NO_TYPE_HASH))
    return keys


KEYS = _token_keys()


def test_token_keys_cover_every_xxh3_length_class():
    lengths = [len(k) for k in KEYS]
    assert min(lengths) <= 16 and any(17 <= n <= 128 for n in lengths)
    assert any(129 <= n <= 240 for n in lengths) and max(lengths) > 240


@pytest.mark.parametrize("key", KEYS, ids=[f"{len(k)}B" for k in KEYS])
def test_gid_matches_the_independent_xxh3_reference(key):
    assert rmw_zenoh_gid(key) == reference_gid(key)


def test_gid_byte_order_is_low64_then_high64_little_endian():
    gid = rmw_zenoh_gid(TALKER_KEY)
    low, high = xxh3_128(TALKER_KEY.encode())
    assert int.from_bytes(gid[:8], "little") == low
    assert int.from_bytes(gid[8:], "little") == high
    assert gid != high.to_bytes(8, "big") + low.to_bytes(8, "big")  # not the canonical (big-endian) digest


def test_published_attachment_carries_the_rmw_zenoh_gid_of_the_publisher_token():
    """A real subscriber sees, in each sample's attachment, the GID rmw_zenoh derives from the MP token."""
    got: queue.Queue = queue.Queue()
    with session_pair() as (a, b, _):
        node = ros.RosNode(a, "pivotd", namespace="/robot1")
        pub = node.publisher("/robot1/chatter", "std_msgs/msg/String", ros.QoS(depth=7))
        tokens: queue.Queue = queue.Queue()
        lv = b.liveliness().declare_subscriber("@ros2_lv/0/**", lambda s: tokens.put(str(s.key_expr)), history=True)
        sub = b.declare_subscriber("0/robot1/chatter/*/*", lambda s: got.put(s.attachment.to_bytes()))
        try:
            assert wait_for(pub.matched)
            msg = ros.typestore().types["std_msgs/msg/String"](data="hi")
            pub.publish(msg)
            att = ros.Attachment.decode(drain(got, 1)[0])
            seen = set()
            assert wait_for(lambda: (seen.update(drain(tokens, tokens.qsize(), 0.1)) or True)
                            and any("/MP/" in k for k in seen))
            mp = next(k for k in seen if "/MP/" in k)
            assert mp == pub.token_key
            assert att.gid == reference_gid(mp)
        finally:
            sub.undeclare()
            lv.undeclare()
            pub.close()
            node.close()
