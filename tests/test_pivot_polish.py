"""Step-limited polish of trajectories: its rings, its exact DP and the band it scores."""

import numpy as np
from viterbi_reference import viterbi_reference

from pivotd.geometry import normalize
from pivotd.pivot.polish import ring_offsets


def _pair(a, b, knee):
    """The smoothness term's pair value: a·b, or with a knee 1 − the pseudo-Huber cost of the chord |a − b|."""
    if knee <= 0:
        return np.sum(a * b, axis=-1)
    return 1.0 - knee**2 * (np.sqrt(1.0 + np.sum((a - b) ** 2, axis=-1) / knee**2) - 1.0)


def _hard_objective(B, W, C, norm, alpha, smooth, anchor=None, knee=0.0):
    vis = ((np.einsum("nlj,nj->nl", B.astype(float), C) >= np.cos(alpha)) * W).sum(axis=1)
    phi = float(np.sum(vis / norm)) + smooth * float(np.sum(_pair(C[1:], C[:-1], knee)))
    if anchor is not None:
        phi += smooth * float(_pair(anchor, C[0], knee))
    return phi


def _scene(rng, n=12, L=300):
    centres = normalize(np.array([1.0, 0.2, 0.1]) + 0.3 * rng.normal(size=(n, 3)))
    B = normalize(centres[:, None, :] + 0.35 * rng.normal(size=(n, L, 3))).astype(np.float32)
    W = np.ones((n, L), np.float32)
    C = normalize(centres + 0.05 * rng.normal(size=(n, 3)))
    return B, W, C, W.sum(axis=1).astype(float)


def test_ring_offsets_cover_each_radius_with_eight_directions():
    cos_r, sin_r, ca, sa = ring_offsets(np.radians(1.0), np.radians(0.25))
    assert cos_r.shape == (24, 1)
    assert np.allclose(np.degrees(np.arcsin(sin_r[::8, 0])), [1.0, 0.5, 0.25])
    assert np.allclose(ca**2 + sa**2, 1.0)


def test_step_limited_dp_equals_the_textbook_viterbi_exactly():
    from pivotd.pivot.polish import _best_sequence

    rng = np.random.default_rng(7)
    for trial in range(60):
        N, K = int(rng.integers(1, 40)), int(rng.choice([1, 2, 5, 17]))
        if trial % 3 == 0:  # small integers: many exact ties, which must go to the same (lowest) index
            val = rng.integers(0, 3, (N, K)).astype(float)
            pen = rng.integers(-2, 1, (max(N - 1, 0), K, K)).astype(float)
        else:
            val = rng.random((N, K))
            pen = rng.normal(size=(max(N - 1, 0), K, K))
        pen[rng.random(pen.shape) < 0.3] = -np.inf  # forbidden steps
        if N > 1:
            pen[:, 0, 0] = 0.0  # as in the polish: staying on the current plan is always allowed
        if trial % 5 == 0:
            val[rng.random(val.shape) < 0.2] = -np.inf  # unreachable candidates
            val[:, 0] = 0.0
        assert np.array_equal(_best_sequence(val, pen), viterbi_reference(val, pen))


def test_polish_scores_only_the_landmarks_a_move_can_change():
    # on the landmarks within α ± 1.01 r of the axes (packed by _take) every candidate of a waypoint scores the
    # full band's value minus the same constant: the DP's choice cannot change
    from pivotd.pivot.polish import _ring_candidates, _score, _take, _within

    rng = np.random.default_rng(5)
    B, W, C, _ = _scene(rng, n=10, L=400)
    alpha, cos_a = np.radians(20.0), np.float32(np.cos(np.radians(20.0)) - 1e-7)
    for r in np.radians([4.0, 1.0, 0.25]):
        x = np.matmul(B, C.astype(np.float32)[:, :, None])[..., 0]
        mask = _within(x, alpha, 1.01 * r)
        Bs, Ws = _take(B, W, mask)
        assert Bs.shape[1] == max(int(mask.sum(axis=1).max()), 1)
        for k in range(B.shape[0]):  # packed in order, padding weighs nothing
            n = int(mask[k].sum())
            assert np.array_equal(Bs[k, :n], B[k, mask[k]]) and not Ws[k, n:].any()
        cand = _ring_candidates(C, r)
        assert np.allclose(np.linalg.norm(cand, axis=2), 1.0) and np.allclose(cand[:, 0], C)
        assert np.allclose(np.degrees(np.arccos(np.clip(np.sum(cand[:, 1:] * C[:, None], axis=2), -1, 1))),
                           np.degrees(np.repeat([r, r / 2], 8)), atol=1e-6)
        diff = _score(cand, B, W, cos_a) - _score(cand, Bs, Ws, cos_a)
        assert np.array_equal(diff, np.repeat(diff[:, :1], diff.shape[1], axis=1))
