"""Rescue of blind warm starts: where a plan sees a small share of what one cone could see there.

A warm-started trajectory ascent only follows gradients, and a cone that holds no landmark has none: a plan
that settled on a blank view stays there even when a dense one is far away. :func:`blind_waypoints` finds
the waypoints whose plan sees less than a fraction of their attainable count (the most landmarks one cone
holds there, e.g. :func:`pivotd.pivot.normalise.attainable_weights`), and :func:`rescue_init` builds a second
starting plan where those waypoints look at their best single-cone axis and a short neighbourhood on either
side turns towards it (slerp). The caller solves from both starts and keeps the higher objective.

Pure numpy: no I/O, no threads, no globals.
"""

from __future__ import annotations

import numpy as np

from pivotd.geometry import normalize, slerp

__all__ = ["blind_waypoints", "rescue_init"]


def blind_waypoints(visible: np.ndarray, attainable: np.ndarray, fraction: float) -> np.ndarray:
    """Indices (B,) of the waypoints whose ``visible`` count (N,) is below ``fraction`` × their ``attainable``
    count (N,) (0 < fraction ≤ 1). A waypoint where one cone sees nothing is never blind."""
    visible = np.asarray(visible, float)
    attainable = np.asarray(attainable, float)
    return np.flatnonzero((attainable > 0) & (visible < fraction * attainable))


def rescue_init(directions: np.ndarray, blind: np.ndarray, axes: np.ndarray, reach: int) -> np.ndarray:
    """Starting directions (N, 3): ``directions`` (N, 3) with each waypoint of ``blind`` (B,) on its axis
    (``axes`` (B, 3) unit) and the ``reach`` waypoints before and after a run of consecutive blind waypoints
    turned towards the run's end axis by the share (reach + 1 − d)/(reach + 1) at distance d (slerp)."""
    out = normalize(np.asarray(directions, float)).copy()
    N = out.shape[0]
    blind = np.asarray(blind, np.int64)
    if blind.size == 0:
        return out
    axes = normalize(np.asarray(axes, float))
    target = np.full(N, -1)
    target[blind] = np.arange(blind.size)
    out[blind] = axes
    # run boundaries: each blind waypoint without a blind neighbour on that side pulls its neighbourhood
    for k, i in enumerate(blind):
        for side in (-1, 1):
            j0 = i + side
            if 0 <= j0 < N and target[j0] >= 0:
                continue
            for d in range(1, reach + 1):
                j = i + side * d
                if not 0 <= j < N or target[j] >= 0:
                    break
                t = (reach + 1 - d) / (reach + 1)
                out[j] = slerp(out[j], axes[k], t)
    return out
