"""Small timing and statistics helpers shared by the benchmarks."""

from __future__ import annotations

import time
from collections.abc import Callable, Sequence
from typing import Any

import numpy as np


def timed(fn: Callable[..., Any], *args: Any, **kwargs: Any) -> tuple[Any, float]:
    """Call ``fn`` once; return (result, wall-clock seconds) measured with perf_counter."""
    t0 = time.perf_counter()
    out = fn(*args, **kwargs)
    return out, time.perf_counter() - t0


def median(values: Sequence[float]) -> float:
    """Median of a non-empty sequence (nan when empty)."""
    return float(np.median(values)) if len(values) else float("nan")


def percentile(values: Sequence[float], q: float) -> float:
    """q-th percentile (0–100), linear interpolation (nan when empty)."""
    return float(np.percentile(values, q)) if len(values) else float("nan")


def best_of(fn: Callable[[], Any], repeats: int) -> tuple[Any, list[float]]:
    """Run ``fn`` ``repeats`` times; return the last result and every duration [s]."""
    times = []
    out = None
    for _ in range(max(1, repeats)):
        out, dt = timed(fn)
        times.append(dt)
    return out, times
