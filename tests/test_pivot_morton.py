"""Morton keys: bit interleaving and the order they give."""

import numpy as np

from pivotd.pivot.morton import interleave, interleave_bytes, morton_keys


def test_interleave_puts_bit_b_of_axis_k_at_3b_plus_k():
    rng = np.random.default_rng(0)
    q = tuple(rng.integers(0, 2**16, 500) for _ in range(3))
    key = interleave(q)
    for b in (0, 7, 8, 15):
        for k in range(3):
            np.testing.assert_array_equal((key >> np.uint64(3 * b + k)) & np.uint64(1), (q[k] >> b) & 1)
    assert int(key.max()) < 2**48
    small = tuple(x.astype(np.uint8) for x in q)
    np.testing.assert_array_equal(interleave_bytes(small), interleave(small).astype(np.uint32))


def test_keys_follow_octants():
    # the top bits split the box into octants: every point of the lower-z half comes before the upper half
    rng = np.random.default_rng(1)
    P = rng.uniform(0, 1, (2000, 3))
    order = np.argsort(morton_keys(P, np.zeros(3), np.ones(3)))
    upper = P[order, 2] >= 0.5
    assert np.all(np.diff(upper.astype(int)) >= 0)
