"""Smooth conical visibility (paper eqs. 5–6, 10–12) and hard visible counts.

Notation: ``c`` (3,) unit optical axis in the world frame; ``bearings`` (n, 3) unit vectors k_j from the
sensor to each landmark; ``weights`` (n,) feature weights s_j ≥ 0 (None: all 1); ``alpha`` the FoV
half-angle [rad]; ``ks`` the sigmoid sharpness k_s [1/cos units].
"""

from __future__ import annotations

import numpy as np

__all__ = ["gradient", "hard_count", "in_cone", "ks_from_width", "objective", "smooth_visibility"]

#: Logit of the transition band edges: v rises from 1/(1+e²) ≈ 12 % to 88 % across the width.
_BAND_LOGIT = 2.0


def ks_from_width(alpha: float, width: float) -> float:
    """Sharpness k_s for which v(θ) goes from 12 % to 88 % over an angular band ``width`` [rad] centred on α.

    Near θ = α, d cos θ / dθ = −sin α, so k_s = 2·2 / (sin α · width). The width is capped at α and at
    π − α so that the band never crosses the optical axis or its antipode (α near 0° or 180°).
    """
    if not (np.isfinite(alpha) and np.isfinite(width)) or width <= 0:
        raise ValueError(f"ks_from_width: need finite alpha and width > 0, got alpha={alpha}, width={width}")
    w = min(float(width), max(float(alpha), 1e-6), max(np.pi - float(alpha), 1e-6))
    return 2.0 * _BAND_LOGIT / (max(np.sin(alpha), 1e-9) * w)


def smooth_visibility(cos_theta: np.ndarray, alpha: float, ks: float) -> np.ndarray:
    """v(θ) = 1 / (1 + exp(−k_s (cos θ − cos α))) (eq. 5), evaluated overflow-free via tanh; same shape as input."""
    x = np.asarray(cos_theta) - np.cos(alpha)
    return 0.5 + 0.5 * np.tanh((0.5 * ks) * x)


def _weights(weights: np.ndarray | None, n: int) -> np.ndarray | None:
    if weights is None:
        return None
    w = np.asarray(weights, dtype=float)
    if w.shape != (n,):
        raise ValueError(f"weights must have shape ({n},), got {w.shape}")
    return w


def objective(c: np.ndarray, bearings: np.ndarray, weights: np.ndarray | None, alpha: float, ks: float) -> float:
    """F(c) = Σ_j s_j v(θ_j) (eq. 6) for bearings (n, 3) and axis c (3,)."""
    bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)
    v = smooth_visibility(bearings @ np.asarray(c, dtype=float), alpha, ks)
    w = _weights(weights, bearings.shape[0])
    return float(v.sum() if w is None else v @ w)


def gradient(
    c: np.ndarray, bearings: np.ndarray, weights: np.ndarray | None, alpha: float, ks: float
) -> np.ndarray:
    """J_vis = Σ_j s_j k_s e^{a_j}/(1+e^{a_j})² (c × k_j) (eqs. 10–12), a tangent vector (3,) at c.

    Evaluated without a per-landmark cross product: Σ g_j (c × k_j) = c × Σ g_j k_j, and
    e^a/(1+e^a)² = v(1 − v). J is the derivative of F along a left perturbation exp(ω^) R, so J·c = 0.
    """
    c = np.asarray(c, dtype=float)
    bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)
    v = smooth_visibility(bearings @ c, alpha, ks)
    g = ks * v * (1.0 - v)
    w = _weights(weights, bearings.shape[0])
    if w is not None:
        g = g * w
    return np.cross(c, g @ bearings)


def hard_count(c: np.ndarray, bearings: np.ndarray, alpha: float) -> int:
    """Number of bearings whose angle to the axis c is ≤ α (the paper's hard visible count)."""
    bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)
    return int(np.count_nonzero(bearings @ np.asarray(c, dtype=float) >= np.cos(alpha) - 1e-12))


def in_cone(c: np.ndarray, bearings: np.ndarray, alpha: float, limit: int) -> np.ndarray:
    """Indices of at most ``limit`` bearings (K, 3) inside the cone of axis c and half-angle α (the
    :func:`hard_count` test), those nearest the axis first. Cost O(K) plus O(limit log limit)."""
    bearings = np.asarray(bearings, dtype=float).reshape(-1, 3)
    cos = bearings @ np.asarray(c, dtype=float)
    inside = np.flatnonzero(cos >= np.cos(alpha) - 1e-12)
    if inside.size > limit:
        inside = inside[np.argpartition(-cos[inside], limit - 1)[:limit]] if limit > 0 else inside[:0]
    return inside[np.argsort(-cos[inside], kind="stable")]
