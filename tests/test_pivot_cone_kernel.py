"""The cube-map histogram and cone-overlap kernel behind optimize_view's global stage."""

import numpy as np
import pytest

from pivotd.geometry import normalize
from pivotd.pivot.brute import brute_force_view
from pivotd.pivot.cone_kernel import cell_keys, cells_per_face, cone_kernel
from pivotd.pivot.lattice import fibonacci_sphere, sphere_grid
from pivotd.pivot.scenes import hard_scene
from pivotd.pivot.view import ViewOptions, optimize_view


def _histogram(B, kernel):
    BT = np.ascontiguousarray(B.T, dtype=np.float32)
    return np.bincount(cell_keys(BT, kernel.m), minlength=kernel.size).astype(np.float32)


def test_every_direction_falls_in_a_surface_cell_and_each_centre_in_its_own():
    for m in (4, 9, 16):
        kernel = cone_kernel(np.radians(15.0), m)
        assert kernel.keys.size == m**3 - (m - 2) ** 3
        rng = np.random.default_rng(m)
        D = normalize(rng.normal(size=(20000, 3))).astype(np.float32)
        D[:6] = np.vstack([np.eye(3), -np.eye(3)])  # faces' centres, where a coordinate is exactly ±1
        keys = cell_keys(np.ascontiguousarray(D.T), m)
        assert np.isin(keys, kernel.keys).all()
        own = cell_keys(np.ascontiguousarray(kernel.centres.T), m)
        assert np.mean(own == kernel.keys) > 0.99  # a merged corner voxel's mean may sit on an edge
    assert cells_per_face(np.radians(15.0)) == 16
    assert 4 <= cells_per_face(np.radians(89.0)) <= cells_per_face(np.radians(2.0)) <= 24


@pytest.mark.parametrize("half_deg", [8.0, 15.0, 30.0, 60.0])
def test_kernel_counts_follow_the_exact_cone_counts(half_deg):
    alpha = np.radians(half_deg)
    kernel = cone_kernel(alpha)
    rng = np.random.default_rng(int(half_deg))
    centres = normalize(rng.normal(size=(6, 3)))
    spreads, sizes = (0.02, 0.1, 0.3, 0.05, 0.6, 0.2), (900, 2500, 4000, 300, 3000, 1500)
    B = np.concatenate([normalize(c + s * rng.normal(size=(k, 3)))
                        for c, s, k in zip(centres, spreads, sizes, strict=True)])
    approx = kernel.counts(_histogram(B, kernel))
    exact = np.count_nonzero(kernel.centres.astype(float) @ B.T >= np.cos(alpha), axis=1)
    assert np.corrcoef(approx, exact)[0, 1] > 0.98
    # the approximate peak is a near-optimal cone centre
    assert exact[int(np.argmax(approx))] >= 0.95 * exact.max()
    # a whole sphere of landmarks: every cone holds about its share of them
    S = fibonacci_sphere(60000)
    full = kernel.counts(_histogram(S, kernel))
    share = 60000 * (1 - np.cos(alpha)) / 2
    assert np.abs(full / share - 1).max() < 0.1


def test_soft_weights_match_the_kernel_at_the_cell_centres():
    kernel = cone_kernel(np.radians(15.0))
    soft = kernel.soft_weights(kernel.centres[:50] @ kernel.centres.T)  # (50, C)
    dense = np.zeros_like(soft)
    col = {int(k): j for j, k in enumerate(kernel.keys)}
    for i in range(50):
        for p in range(kernel.indptr[i], kernel.indptr[i + 1]):
            dense[i, col[int(kernel.indices[p])]] = kernel.overlap[p]
    assert np.abs(soft - dense).max() < 0.2  # a linear ramp in cos θ against the disc's segment area
    assert np.array_equal(soft > 0.5, dense > 0.5) or np.mean((soft > 0.5) != (dense > 0.5)) < 0.01


def test_optimize_view_takes_a_prebuilt_kernel_and_rejects_one_of_another_angle():
    scene = hard_scene("clusters", seed=1, poses=2, scale=0.2)
    alpha = np.radians(15.0)
    B = normalize(scene.points - scene.path[0])
    assert B.shape[0] > ViewOptions().sample  # the histogram path
    own = optimize_view(B, None, alpha)
    given = optimize_view(B, None, alpha, kernel=cone_kernel(alpha))
    assert given.visible == own.visible and np.allclose(given.direction, own.direction)
    with pytest.raises(ValueError, match="kernel"):
        optimize_view(B, None, alpha, kernel=cone_kernel(np.radians(20.0)))
    with pytest.raises(ValueError, match="kernel"):
        optimize_view(B, None, alpha, options=ViewOptions(cells=12), kernel=cone_kernel(alpha, 16))
    narrow = np.radians(2.0)  # the narrow-cone path ignores the kernel but still refuses a wrong one
    with pytest.raises(ValueError, match="kernel"):
        optimize_view(B, None, narrow, kernel=cone_kernel(alpha))


def test_histogram_candidates_do_not_depend_on_the_landmark_order():
    # integer counts per cell: the global stage sees the same histogram in any order
    alpha = np.radians(15.0)
    kernel = cone_kernel(alpha)
    for family in ("near_far", "twins"):
        scene = hard_scene(family, seed=2, poses=3, scale=0.3)
        rng = np.random.default_rng(1)
        for t in scene.path:
            B = normalize(scene.points - t)
            h = _histogram(B, kernel)
            assert np.array_equal(h, _histogram(B[rng.permutation(B.shape[0])], kernel))
            counts = [optimize_view(B[rng.permutation(B.shape[0])] if k else B, None, alpha, kernel=kernel).visible
                      for k in range(3)]
            assert max(counts) - min(counts) <= 0.005 * max(counts)


def test_brute_force_view_with_a_precomputed_grid_gives_the_same_answer():
    rng = np.random.default_rng(3)
    B = normalize(rng.normal(size=(3000, 3)) + np.array([2.0, 0.0, 0.0]))
    w = rng.uniform(0.5, 2.0, size=B.shape[0])
    for weights in (None, w):
        d0, v0 = brute_force_view(B, weights, np.radians(10.0), 3.0)
        d1, v1 = brute_force_view(B, weights, np.radians(10.0), 3.0, grid=sphere_grid(3.0))
        assert v0 == v1 and np.array_equal(d0, d1)
    # the count is the exact hard count of the chosen direction (float32 cosines, as documented)
    d, v = brute_force_view(B, None, np.radians(10.0), 3.0)
    assert v == np.count_nonzero(B.astype(np.float32) @ d.astype(np.float32) >= np.float32(np.cos(np.radians(10.0))))
