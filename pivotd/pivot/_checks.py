"""Input validation shared by the optimizer entry points (raise ValueError with a clear message)."""

from __future__ import annotations

import numpy as np

__all__ = ["feature_weights", "finite_array", "half_angle", "unit_vector"]


def finite_array(
    name: str, value: np.ndarray, shape_tail: tuple[int, ...] = (3,), *, rows: np.ndarray | None = None
) -> np.ndarray:
    """``value`` as float64 of shape (n, *shape_tail); raises ValueError on a wrong shape or NaN/inf.

    ``rows`` (n,): the row numbers to name in the message when ``value`` is a selection of a larger array.
    """
    arr = np.asarray(value, dtype=float)
    if arr.ndim != 1 + len(shape_tail) or arr.shape[1:] != shape_tail:
        want = "(n, " + ", ".join(map(str, shape_tail)) + ")"
        raise ValueError(f"{name} must have shape {want}, got {arr.shape}")
    if not np.isfinite(arr).all():
        bad = int(np.argmax(~np.isfinite(arr.reshape(arr.shape[0], -1)).all(axis=1)))
        bad = bad if rows is None else int(rows[bad])
        raise ValueError(f"{name} row {bad} is not finite (NaN or inf)")
    return arr


def feature_weights(weights: np.ndarray | None, n: int, *, rows: np.ndarray | None = None) -> np.ndarray:
    """Weights (n,) float64 ≥ 0 (all ones for None); raises ValueError on a wrong shape, NaN/inf or a negative.

    ``rows`` (n,): the row numbers to name in the message when ``weights`` is a selection of a larger array.
    """
    if weights is None:
        return np.ones(n)
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), got {w.shape}")

    def row(k: int) -> int:
        return k if rows is None else int(rows[k])

    if not np.isfinite(w).all():
        raise ValueError(f"weights row {row(int(np.argmax(~np.isfinite(w))))} is not finite (NaN or inf)")
    if (w < 0).any():
        raise ValueError(f"weights row {row(int(np.argmax(w < 0)))} is negative")
    return w


def half_angle(alpha: float) -> float:
    """α as a float in (0, π); raises ValueError otherwise."""
    a = float(alpha)
    if not (np.isfinite(a) and 0.0 < a < np.pi):
        raise ValueError(f"FoV half-angle alpha must be in (0, pi) rad, got {alpha}")
    return a


def unit_vector(name: str, value: np.ndarray) -> np.ndarray:
    """A finite non-zero (3,) vector, normalised; raises ValueError otherwise."""
    v = np.asarray(value, dtype=float)
    if v.shape != (3,) or not np.isfinite(v).all() or np.linalg.norm(v) < 1e-12:
        raise ValueError(f"{name} must be a finite non-zero 3-vector, got {value!r}")
    return v / np.linalg.norm(v)
