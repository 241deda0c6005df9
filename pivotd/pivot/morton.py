"""Z-order (Morton) keys: three quantised coordinates interleaved bit by bit into one uint64.

Sorting points by these keys lays them out along a space-filling curve, so that any strided subsample
of them is spread evenly over space.
"""

from __future__ import annotations

import numpy as np

__all__ = ["interleave", "interleave_bytes", "morton_keys"]


def _spread_table() -> np.ndarray:
    """(256,) uint64: the bits of each byte moved to every third bit (bit b to bit 3b)."""
    v = np.arange(256, dtype=np.uint64)
    out = np.zeros(256, np.uint64)
    for b in range(8):
        out |= ((v >> np.uint64(b)) & np.uint64(1)) << np.uint64(3 * b)
    out.flags.writeable = False
    return out


_SPREAD = _spread_table()


def interleave(q: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Morton keys (M,) uint64 of three integer arrays (M,) with values in [0, 2¹⁶): bit b of q[k] goes to
    bit 3b + k. Two table look-ups per axis (bytes spread to every third bit)."""
    key = np.zeros(q[0].shape[0], np.uint64)
    for k, qk in enumerate(q):
        qk = qk.astype(np.uint32, copy=False)
        key |= (_SPREAD.take(qk & 255) | (_SPREAD.take(qk >> 8) << np.uint64(24))) << np.uint64(k)
    return key


def interleave_bytes(q: tuple[np.ndarray, np.ndarray, np.ndarray]) -> np.ndarray:
    """Morton keys (M,) uint32 (24 bits) of three uint8 arrays (M,): bit b of q[k] goes to bit 3b + k."""
    spread = _SPREAD.astype(np.uint32)
    key = spread.take(q[0])
    for k in (1, 2):
        part = spread.take(q[k])
        part <<= np.uint32(k)
        key |= part
    return key


def morton_keys(P: np.ndarray, lo: np.ndarray, hi: np.ndarray) -> np.ndarray:
    """Morton keys (M,) uint64 of points P (M, 3) [m] in the box [lo, hi] (16 bits per axis)."""
    lo = np.asarray(lo, float)
    span = np.maximum(np.asarray(hi, float) - lo, 1e-12)
    return interleave(tuple(
        ((P[:, k] - lo[k]) * ((2**16 - 1) / span[k])).clip(0, 2**16 - 1).astype(np.uint32) for k in range(3)
    ))
