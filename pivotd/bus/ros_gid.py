"""The 16-byte entity GID exactly as rmw_zenoh computes it.

rmw_zenoh hashes an entity's complete liveliness key expression (``@ros2_lv/...``, see
:func:`pivotd.bus.ros.entity_token_key`) with XXH3-128 (seed 0, default secret) and stores the
result as the low 64 bits then the high 64 bits, each in little-endian byte order. The same GID is in
every message's attachment, so tools that group samples per publisher or report per-publisher
sequence gaps see pivotd's publishers as they see any rmw_zenoh publisher.
"""

from __future__ import annotations

import xxhash

GID_SIZE = 16
_MASK64 = (1 << 64) - 1


def rmw_zenoh_gid(liveliness_key: str) -> bytes:
    """GID (16 bytes) of the entity whose liveliness key expression is ``liveliness_key``."""
    h = xxhash.xxh3_128_intdigest(liveliness_key.encode())
    return (h & _MASK64).to_bytes(8, "little") + (h >> 64).to_bytes(8, "little")


def gid_hex(gid: bytes) -> str:
    """The GID as ``ros2 topic info -v`` prints it: dot-separated hex bytes (``01.0f.…``)."""
    return ".".join(f"{b:02x}" for b in gid)
