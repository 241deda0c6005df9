"""Vectorised helpers for ragged ranges (no per-range Python loop)."""

from __future__ import annotations

import numpy as np


def expand_ranges(starts: np.ndarray, ends: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Concatenate ``arange(starts[i], ends[i])`` for all i.

    starts, ends: (R,) int64 with ends ≥ starts. Returns (values (T,) int64, owner (T,) int64) where
    owner[t] is the range index i that produced values[t]; T = Σ (ends - starts). Order is preserved.
    """
    counts = ends - starts
    total = int(counts.sum())
    if total == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    owner = np.repeat(np.arange(starts.shape[0], dtype=np.int64), counts)
    first = np.cumsum(counts) - counts  # position of each range's first element in the output
    values = np.arange(total, dtype=np.int64)
    values += (starts - first)[owner]
    return values, owner
