"""A plain-Python XXH3-128 (seed 0, default secret), written from the algorithm's description, as an
independent reference for the GID tests. Slow (pure Python) and only meant for short keys in tests."""

from __future__ import annotations

M64 = (1 << 64) - 1
P32_1, P32_2, P32_3 = 0x9E3779B1, 0x85EBCA77, 0xC2B2AE3D
P64_1, P64_2, P64_3 = 0x9E3779B185EBCA87, 0xC2B2AE3D27D4EB4F, 0x165667B19E3779F9
P64_4, P64_5 = 0x85EBCA77C2B2AE63, 0x27D4EB2F165667C5
PRIME_MX1, PRIME_MX2 = 0x165667919E3779F9, 0x9FB21C651E98DF25
SECRET = bytes.fromhex(
    "b8fe6c3923a44bbe7c01812cf721ad1cded46de9839097db7240a4a4b7b3671f"
    "cb79e64eccc0e578825ad07dccff7221b8084674f743248ee03590e6813a264c"
    "3c2852bb91c300cb88d0658b1b532ea371644897a20df94e3819ef46a9deacd8"
    "a8fa763fe39c343ff9dcbbc7c70b4f1d8a51e04bcdb45931c89f7ec9d9787364"
    "eac5ac8334d3ebc3c581a0fffa1363eb170ddd51b7f0da49d316552629d4689e"
    "2b16be587d47a1fc8ff8b8d17ad031ce45cb3a8f95160428afd7fbcabb4b407e")
STRIPE, CONSUME, ACC_NB = 64, 8, 8


def _r64(b: bytes, i: int) -> int:
    return int.from_bytes(b[i:i + 8], "little")


def _r32(b: bytes, i: int) -> int:
    return int.from_bytes(b[i:i + 4], "little")


def _avalanche(h: int) -> int:
    h ^= h >> 37
    h = (h * PRIME_MX1) & M64
    return h ^ (h >> 32)


def _avalanche64(h: int) -> int:
    h ^= h >> 33
    h = (h * P64_2) & M64
    h ^= h >> 29
    h = (h * P64_3) & M64
    return h ^ (h >> 32)


def _fold(a: int, b: int) -> int:
    p = a * b
    return (p & M64) ^ (p >> 64)


def _mix16(data: bytes, i: int, s: int) -> int:
    return _fold(_r64(data, i) ^ _r64(SECRET, s), _r64(data, i + 8) ^ _r64(SECRET, s + 8))


def _mix32(lo: int, hi: int, data: bytes, i1: int, i2: int, s: int) -> tuple[int, int]:
    lo = (lo + _mix16(data, i1, s)) & M64
    lo ^= (_r64(data, i2) + _r64(data, i2 + 8)) & M64
    hi = (hi + _mix16(data, i2, s + 16)) & M64
    hi ^= (_r64(data, i1) + _r64(data, i1 + 8)) & M64
    return lo, hi


def _finish(lo: int, hi: int, n: int) -> tuple[int, int]:
    low = _avalanche((lo + hi) & M64)
    high = (-_avalanche((lo * P64_1 + hi * P64_4 + n * P64_2) & M64)) & M64
    return low, high


def _short(d: bytes) -> tuple[int, int]:
    n = len(d)
    if n == 0:
        return (_avalanche64(_r64(SECRET, 64) ^ _r64(SECRET, 72)), _avalanche64(_r64(SECRET, 80) ^ _r64(SECRET, 88)))
    if n <= 3:
        cl = (d[0] << 16) | (d[n >> 1] << 24) | d[n - 1] | (n << 8)
        sw = int.from_bytes(cl.to_bytes(4, "little"), "big")
        ch = ((sw << 13) | (sw >> 19)) & 0xFFFFFFFF
        return (_avalanche64(cl ^ (_r32(SECRET, 0) ^ _r32(SECRET, 4))),
                _avalanche64(ch ^ (_r32(SECRET, 8) ^ _r32(SECRET, 12))))
    if n <= 8:
        v = _r32(d, 0) + (_r32(d, n - 4) << 32)
        keyed = v ^ (_r64(SECRET, 16) ^ _r64(SECRET, 24))
        p = keyed * ((P64_1 + (n << 2)) & M64)
        lo, hi = p & M64, p >> 64
        hi = (hi + (lo << 1)) & M64
        lo ^= hi >> 3
        lo ^= lo >> 35
        lo = (lo * PRIME_MX2) & M64
        lo ^= lo >> 28
        return lo, _avalanche(hi)
    flip_l = _r64(SECRET, 32) ^ _r64(SECRET, 40)
    flip_h = _r64(SECRET, 48) ^ _r64(SECRET, 56)
    in_lo, in_hi = _r64(d, 0), _r64(d, n - 8)
    p = (in_lo ^ in_hi ^ flip_l) * P64_1
    lo, hi = p & M64, p >> 64
    lo = (lo + ((n - 1) << 54)) & M64
    in_hi ^= flip_h
    hi = (hi + in_hi + (in_hi & 0xFFFFFFFF) * (P32_2 - 1)) & M64
    lo ^= int.from_bytes(hi.to_bytes(8, "little"), "big")
    p = lo * P64_2
    h_lo, h_hi = p & M64, ((p >> 64) + hi * P64_2) & M64
    return _avalanche(h_lo), _avalanche(h_hi)


def _long(d: bytes) -> tuple[int, int]:
    n = len(d)
    acc = [P32_3, P64_1, P64_2, P64_3, P64_4, P32_2, P64_5, P32_1]

    def stripe(i: int, s: int) -> None:
        for lane in range(ACC_NB):
            v = _r64(d, i + 8 * lane)
            k = v ^ _r64(SECRET, s + 8 * lane)
            acc[lane ^ 1] = (acc[lane ^ 1] + v) & M64
            acc[lane] = (acc[lane] + (k & 0xFFFFFFFF) * (k >> 32)) & M64

    per_block = (len(SECRET) - STRIPE) // CONSUME
    block = STRIPE * per_block
    blocks = (n - 1) // block
    for b in range(blocks):
        for s in range(per_block):
            stripe(b * block + s * STRIPE, s * CONSUME)
        for lane in range(ACC_NB):
            a = acc[lane]
            a ^= a >> 47
            a ^= _r64(SECRET, len(SECRET) - STRIPE + 8 * lane)
            acc[lane] = (a * P32_1) & M64
    for s in range(((n - 1) - block * blocks) // STRIPE):
        stripe(blocks * block + s * STRIPE, s * CONSUME)
    stripe(n - STRIPE, len(SECRET) - STRIPE - 7)

    def merge(s: int, start: int) -> int:
        r = start
        for i in range(4):
            r = (r + _fold(acc[2 * i] ^ _r64(SECRET, s + 16 * i), acc[2 * i + 1] ^ _r64(SECRET, s + 16 * i + 8))) & M64
        return _avalanche(r)

    return merge(11, (n * P64_1) & M64), merge(len(SECRET) - 64 - 11, (~(n * P64_2)) & M64)


def xxh3_128(data: bytes) -> tuple[int, int]:
    """(low64, high64) of XXH3-128 of ``data``."""
    n = len(data)
    if n <= 16:
        return _short(data)
    lo, hi = n * P64_1 & M64, 0
    if n <= 128:
        if n > 32:
            if n > 64:
                if n > 96:
                    lo, hi = _mix32(lo, hi, data, 48, n - 64, 96)
                lo, hi = _mix32(lo, hi, data, 32, n - 48, 64)
            lo, hi = _mix32(lo, hi, data, 16, n - 32, 32)
        lo, hi = _mix32(lo, hi, data, 0, n - 16, 0)
        return _finish(lo, hi, n)
    if n <= 240:
        for i in range(32, 160, 32):
            lo, hi = _mix32(lo, hi, data, i - 32, i - 16, i - 32)
        lo, hi = _avalanche(lo), _avalanche(hi)
        for i in range(160, n + 1, 32):
            lo, hi = _mix32(lo, hi, data, i - 32, i - 16, 3 + i - 160)
        lo, hi = _mix32(lo, hi, data, n - 16, n - 32, 136 - 17 - 16)
        return _finish(lo, hi, n)
    return _long(data)
