"""Large valid ROS messages built in O(size) (for flooding benchmarks and tests of the input limits).

Encoding a 20 MB ``nav_msgs/Path`` through rosbags takes minutes; these builders encode a small message
once and repeat its per-element record, which CDR lays out identically for identical elements.
"""

from __future__ import annotations

import struct

import numpy as np

from pivotd.bus import messages as m
from pivotd.bus.ros import typestore

_COUNT_AT = 4 + 8 + 4 + 4  # encapsulation, stamp, frame_id "map\0": the first sequence length of Path/cloud


def large_path(nbytes: int, step: float = 0.05) -> bytes:
    """A valid ``nav_msgs/Path`` of at least ``nbytes`` bytes in frame ``map``: poses ``step`` m apart along x."""
    mark = np.array([[1.25, 2.5, 3.75]])  # found again in the record to locate the position's bytes
    one = m.encode_path(0.0, "map", mark)
    two = m.encode_path(0.0, "map", np.repeat(mark, 2, axis=0))
    # A Path ends with its poses. The first pose record may carry padding (8-byte alignment of the doubles);
    # the following ones are all alike.
    head, first, record = one[:_COUNT_AT], one[_COUNT_AT + 4:], two[len(one):]
    x_at = record.find(struct.pack("<3d", *mark[0]))
    n = max(2, (nbytes - len(head) - len(first)) // len(record) + 2)
    rows = np.frombuffer(record * (n - 1), dtype=np.uint8).reshape(n - 1, len(record)).copy()
    xyz = np.zeros((n - 1, 3), "<f8")
    xyz[:, 0] = np.arange(1, n) * step
    rows[:, x_at:x_at + 24] = xyz.view(np.uint8).reshape(n - 1, 24)
    return head + struct.pack("<I", n) + first + rows.tobytes()


def cloud_with_fields(nbytes: int) -> bytes:
    """A ``sensor_msgs/PointCloud2`` of at least ``nbytes`` bytes whose size is all PointField entries (and
    one point): the shape that costs a generic decoder one Python object per field."""
    t = typestore().types
    pf = t["sensor_msgs/msg/PointField"]

    def encode(k: int) -> bytes:
        fields = [pf(name="x", offset=0, datatype=7, count=1)] * k
        msg = t[m.POINT_CLOUD2](header=t["std_msgs/msg/Header"](stamp=m.seconds_to_stamp(0.0), frame_id="map"),
                                height=1, width=1, fields=fields, is_bigendian=False, point_step=4, row_step=4,
                                data=np.zeros(4, np.uint8), is_dense=True)
        return m.serialize(msg, m.POINT_CLOUD2)

    one, two = encode(1), encode(2)
    size, at = len(two) - len(one), _COUNT_AT + 8 + 4  # after height, width and the fields' count
    record = one[at:at + size]
    head, tail = one[:at - 4], one[at + size:]
    n = max(1, (nbytes - len(head) - len(tail)) // len(record) + 1)
    return head + struct.pack("<I", n) + record * n + tail
