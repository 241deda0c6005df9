"""Hard-count polish of trajectories: monotone in the discrete objective, constraint-aware, wired into the optimizer."""

import numpy as np
import pytest
from viterbi_reference import viterbi_reference

from pivotd.geometry import angle_between, normalize
from pivotd.pivot.polish import polish_trajectory, ring_offsets
from pivotd.pivot.scenes import competing_clusters_path
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory


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


@pytest.mark.parametrize("knee_deg", [0.0, 1.0])
def test_polish_never_lowers_the_hard_objective_and_usually_raises_it(knee_deg):
    alpha = np.radians(15)
    knee = np.radians(knee_deg)
    gains = []
    for seed in range(5):
        rng = np.random.default_rng(seed)
        B, W, C, norm = _scene(rng)
        for smooth in (0.0, 2.0):
            before = _hard_objective(B, W, C, norm, alpha, smooth, knee=knee)
            C2, moves = polish_trajectory(B, W, C, norm, alpha, smooth, np.radians(1.0), np.radians(0.25),
                                          knee=knee)
            after = _hard_objective(B, W, C2, norm, alpha, smooth, knee=knee)
            assert after >= before - 1e-9
            assert np.allclose(np.linalg.norm(C2, axis=1), 1.0)
            assert np.degrees(angle_between(C2, C)).max() <= 4 * 1.0 + 1e-6  # at most one ring step per sweep
            gains.append(after - before)
            assert (moves == 0) == (after == before)
    assert np.mean(np.array(gains) > 0) > 0.5


def test_polish_respects_the_reachable_set():
    rng = np.random.default_rng(7)
    B, W, C, norm = _scene(rng)
    z0 = C[:, 2].copy()

    def reachable(rows, d):  # the axis may not rise above where it started
        return d[..., 2] <= z0[rows, None] + 1e-12

    C2, _ = polish_trajectory(B, W, C, norm, np.radians(15), 1.0, np.radians(1.0), np.radians(0.25),
                              reachable=reachable)
    assert np.all(C2[:, 2] <= z0 + 1e-12)


def test_anchor_enters_the_polish():
    rng = np.random.default_rng(3)
    B, W, C, norm = _scene(rng, n=1)
    anchor = normalize(C[0] + np.array([0.0, 0.0, 0.2]))
    C2, _ = polish_trajectory(B, W, C, norm, np.radians(15), 50.0, np.radians(1.0), np.radians(0.25), anchor=anchor)
    assert angle_between(C2[0], anchor) < angle_between(C[0], anchor)


def test_trajectory_option_polishes_without_losing_smoothness():
    scene = competing_clusters_path()
    alpha = np.radians(30)
    plain = optimize_trajectory(scene.points, scene.path, alpha, 0.6, options=TrajectoryOptions(step_polish_deg=0))
    polished = optimize_trajectory(scene.points, scene.path, alpha, 0.6,
                                   options=TrajectoryOptions(polish_deg=1.0, step_polish_deg=0))
    assert polished.visible.mean() >= plain.visible.mean()
    steps = np.degrees(angle_between(polished.directions[1:], polished.directions[:-1]))
    assert steps.max() < 11.0  # the plain plan's largest step: 10.4° (see test_pivot_trajectory)
    assert np.allclose(np.einsum("nij,j->ni", polished.rotations, [0, 0, 1]), polished.directions, atol=1e-12)


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
