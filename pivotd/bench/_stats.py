"""Small timing and statistics helpers shared by the benchmarks."""

from __future__ import annotations

import math
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


def quality_stats(prefix: str, pct: Sequence[float]) -> dict[str, float]:
    """``{prefix}_mean_pct``, ``_p5_pct`` and ``_min_pct`` of per-pose percentages of a reference."""
    return {f"{prefix}_mean_pct": float(np.mean(pct)), f"{prefix}_p5_pct": percentile(pct, 5),
            f"{prefix}_min_pct": float(np.min(pct))}


def best_of(fn: Callable[[], Any], repeats: int) -> tuple[Any, list[float]]:
    """Run ``fn`` ``repeats`` times; return the last result and every duration [s]."""
    times = []
    out = None
    for _ in range(max(1, repeats)):
        out, dt = timed(fn)
        times.append(dt)
    return out, times


#: glibc mallopt parameters (malloc.h)
_M_TRIM_THRESHOLD, _M_MMAP_THRESHOLD = -1, -3


def steady_heap(mmap_threshold: int = 32 << 20, trim_threshold: int = 256 << 20) -> bool:
    """Keep freed memory in the process heap between timed calls (glibc only; returns False elsewhere).

    By default glibc serves each allocation above its (adaptive) mmap threshold with a fresh mmap and
    trims the heap top when more than the trim threshold is free, so a numpy temporary of a few hundred
    kB can cost page faults on every call, depending on what ran before: the same single-pose solve
    measured 0.9 ms or 1.45 ms per pose in one process. Fixing both thresholds (32 MB is glibc's largest
    mmap threshold) makes repeated calls reuse warm heap pages, as a long-running process would; it
    applies to every method timed in the process alike.
    """
    import contextlib
    import ctypes

    with contextlib.suppress(OSError, AttributeError):
        libc = ctypes.CDLL("libc.so.6")
        return bool(libc.mallopt(_M_MMAP_THRESHOLD, mmap_threshold)) and bool(
            libc.mallopt(_M_TRIM_THRESHOLD, trim_threshold)
        )
    return False


def json_safe(x: Any) -> Any:
    """JSON-safe copy: inf/NaN become null, numpy scalars plain numbers."""
    if isinstance(x, dict):
        return {k: json_safe(v) for k, v in x.items()}
    if isinstance(x, list | tuple):
        return [json_safe(v) for v in x]
    if isinstance(x, np.generic):
        x = x.item()
    if isinstance(x, float):
        return x if math.isfinite(x) else None
    return x
