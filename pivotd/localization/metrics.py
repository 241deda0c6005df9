"""Localization metrics per run and their aggregation over seeds with bootstrap intervals.

Per run (one scene instance, one seed, one policy): the share of frames within each (translation,
rotation) threshold of the visual-localization literature, median errors (a frame without a pose counts
as an infinite error), the share of frames without a pose, the longest run of consecutive frames outside
the (0.25 m, 2°) threshold in seconds, the share of frames outside it while the camera turns faster than
``TURNING_DEG_S`` (a slew between views, which a policy bound by the gimbal's speed pays and a teleporting one
does not), and the policy's compute time per frame.

Across seeds: the mean of the per-run values with a 95 % percentile bootstrap interval that resamples
whole runs (frames of one run are correlated, runs are independent).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

THRESHOLDS: tuple[tuple[float, float], ...] = ((0.05, 0.4), (0.25, 2.0), (0.5, 5.0))  # (m, deg)
PRIMARY = 1  # index of (0.25 m, 2°), the threshold the goals use
TURNING_DEG_S = 45.0  # [deg/s] a frame whose camera axis turns faster than this is in a slew
BOOTSTRAP_RESAMPLES = 2000


def threshold_label(i: int) -> str:
    m, deg = THRESHOLDS[i]
    return f"{m:g}m/{deg:g}deg"


@dataclass(frozen=True)
class RunMetrics:
    """success (len(THRESHOLDS),) shares; median_t [m]; median_r [deg]; no_pose share; longest_failure [s];
    compute_ms per frame; compute_ms_decision per decision (a replan, one orientation search); frames."""

    success: tuple[float, ...]
    median_t: float
    median_r: float
    no_pose: float
    longest_failure: float
    compute_ms: float
    frames: int
    compute_ms_decision: float = float("nan")
    failure_turning: float = float("nan")  # share of frames outside the primary threshold while in a slew

    @property
    def failure(self) -> float:
        """Share of frames outside the primary threshold."""
        return 1.0 - self.success[PRIMARY]


def longest_streak(mask: np.ndarray) -> int:
    """Length of the longest run of True in ``mask`` (F,)."""
    best = run = 0
    for m in np.asarray(mask, bool):
        run = run + 1 if m else 0
        best = max(best, run)
    return best


def turning_frames(times: np.ndarray, directions: np.ndarray, deg_s: float = TURNING_DEG_S) -> np.ndarray:
    """Frames (F,) bool whose camera axis turns faster than ``deg_s`` [deg/s] towards the frame before or after
    it; times (F,) [s], directions (F, 3) unit optical axes."""
    d = np.asarray(directions, float)
    t = np.asarray(times, float)
    n = d.shape[0]
    if n < 2:
        return np.zeros(n, bool)
    ang = np.degrees(np.arccos(np.clip(np.einsum("ij,ij->i", d[1:], d[:-1]), -1.0, 1.0)))
    fast = ang > deg_s * np.maximum(np.diff(t), 1e-9)
    out = np.zeros(n, bool)
    out[1:] |= fast
    out[:-1] |= fast
    return out


def run_metrics(translation: np.ndarray, rotation: np.ndarray, frame_dt: float, compute_s: float,
                decisions: int = 0, turning: np.ndarray | None = None) -> RunMetrics:
    """Metrics of one run from per-frame errors (F,) [m], (F,) [deg], frame period [s], policy compute [s],
    the number of decisions it took and the frames in a slew (F,) bool (:func:`turning_frames`; None: not
    known)."""
    t = np.asarray(translation, float)
    r = np.asarray(rotation, float)
    n = t.shape[0]
    success = tuple(float(np.mean((t <= m) & (r <= d))) if n else 0.0 for m, d in THRESHOLDS)
    m, d = THRESHOLDS[PRIMARY]
    fail = ~((t <= m) & (r <= d))
    return RunMetrics(
        success=success,
        median_t=float(np.median(t)) if n else float("inf"),
        median_r=float(np.median(r)) if n else float("inf"),
        no_pose=float(np.mean(~np.isfinite(t))) if n else 1.0,
        longest_failure=longest_streak(fail) * frame_dt,
        compute_ms=1e3 * compute_s / max(n, 1),
        frames=n,
        compute_ms_decision=1e3 * compute_s / decisions if decisions else float("nan"),
        failure_turning=float(np.mean(fail & np.asarray(turning, bool))) if turning is not None and n else float("nan"),
    )


@dataclass(frozen=True)
class Interval:
    """Mean over runs and its 95 % bootstrap interval [lo, hi]."""

    mean: float
    lo: float
    hi: float

    def as_dict(self) -> dict:
        return {"mean": self.mean, "lo": self.lo, "hi": self.hi}


def bootstrap(values: Sequence[float], rng: np.random.Generator, resamples: int = BOOTSTRAP_RESAMPLES) -> Interval:
    """Mean of ``values`` (one per run) with a 95 % percentile bootstrap interval over runs.

    Infinite values (a median error of a run that mostly failed) make the mean infinite; the interval
    then uses the median of each resample instead of the mean so it stays informative.
    """
    v = np.asarray(values, float)
    if v.size == 0:
        return Interval(float("nan"), float("nan"), float("nan"))
    stat = np.mean if np.all(np.isfinite(v)) else np.median
    idx = rng.integers(0, v.size, (resamples, v.size))
    boots = stat(v[idx], axis=1)
    lo, hi = np.percentile(boots, [2.5, 97.5], method="nearest")  # exact order statistics: inf-safe
    return Interval(float(stat(v)), float(lo), float(hi))


def aggregate(runs: Sequence[RunMetrics], seed: int = 0) -> dict[str, Interval]:
    """Bootstrap intervals of every metric over ``runs`` (one per seed)."""
    rng = np.random.default_rng([seed, 99])
    out: dict[str, Interval] = {}
    for i in range(len(THRESHOLDS)):
        out[f"success_{threshold_label(i)}"] = bootstrap([r.success[i] for r in runs], rng)
    out["failure"] = bootstrap([r.failure for r in runs], rng)
    out["failure_turning"] = bootstrap([r.failure_turning for r in runs], rng)
    out["median_t_m"] = bootstrap([r.median_t for r in runs], rng)
    out["median_r_deg"] = bootstrap([r.median_r for r in runs], rng)
    out["no_pose"] = bootstrap([r.no_pose for r in runs], rng)
    out["longest_failure_s"] = bootstrap([r.longest_failure for r in runs], rng)
    out["compute_ms_per_frame"] = bootstrap([r.compute_ms for r in runs], rng)
    out["compute_ms_per_decision"] = bootstrap([r.compute_ms_decision for r in runs], rng)
    return out
