"""The batched ascent (pivotd.pivot._ascent): resting waypoints."""

import numpy as np

from pivotd.geometry import normalize
from pivotd.pivot import _ascent
from pivotd.pivot.scenes import competing_clusters_path
from pivotd.pivot.trajectory import TrajectoryOptions, optimize_trajectory


def _rows_geometry(rng, K=6, L=900):
    B = normalize(np.array([0.0, 0.0, 1.0]) + 0.6 * rng.normal(size=(K, L, 3))).astype(np.float32)
    W = rng.uniform(0.5, 2.0, (K, L)).astype(np.float32)
    W[:, L - 50:] = 0.0  # padding
    return _ascent.Geometry(B, np.zeros((K, 3), np.float32), None, W, lambda r, c, C: None)


def test_resting_waypoints_leave_the_plan_within_the_tolerance():
    # waypoints whose step bound fell below tol rest until a neighbour moves: the plan sees as much and reaches
    # the same objective as the ascent that keeps stepping every waypoint
    cc = competing_clusters_path()
    alpha = np.radians(30.0)
    base = dict(distance_weights=False, step_polish_deg=0.0)
    rest = optimize_trajectory(cc.points, cc.path, alpha, 0.6, options=TrajectoryOptions(rest_settled=True, **base))
    full = optimize_trajectory(cc.points, cc.path, alpha, 0.6, options=TrajectoryOptions(rest_settled=False, **base))
    assert abs(rest.visible.sum() - full.visible.sum()) <= 0.005 * full.visible.sum()
    assert abs(rest.objective - full.objective) <= 1e-3 * abs(full.objective)


def test_resting_rows_are_not_evaluated():
    # uncoupled rows (λ = 0) with very different curvature: once a row rests its axis never changes again
    rng = np.random.default_rng(2)
    geom = _rows_geometry(rng, K=8, L=600)
    C0 = normalize(np.array([0.0, 0.0, 1.0]) + 0.3 * rng.normal(size=(geom.rows, 3)))
    settings = _ascent.AscentSettings(
        stages=[np.radians(20.0)], width=np.radians(3.0), wide_width_ratio=0.25, stage_iters=6, final_iters=60,
        step_init=np.radians(4.0), step_max=np.radians(10.0), tol=np.radians(0.1), active_cap=256,
        final_cap=256, drift=np.radians(12.0), settle_frac=0.0, freeze_settled=True,
    )
    seen = []

    def project(C):  # records the axes after every step (unit rows are returned unchanged)
        seen.append(C.copy())
        return C

    _ascent.ascend(geom, _ascent._turn_to(np.tile(np.eye(3), (geom.rows, 1, 1)), C0),
                   np.ones(geom.rows), settings, project=project)
    steps = np.stack(seen)  # (iterations, K, 3)
    moved = np.any(np.abs(np.diff(steps, axis=0)) > 0, axis=2)  # (iterations − 1, K)
    for k in range(geom.rows):
        still = np.flatnonzero(~moved[:, k])
        if still.size:  # from the first iteration a row stays put, it never moves again
            assert not moved[still[0]:, k].any()
    assert (~moved[-1]).any()  # some rows rested before the end
