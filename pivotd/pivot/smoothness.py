"""The smoothness term's value per pair of consecutive axes, as a function of their cosine.

The paper's term is λκ Σ c_{i+1}·c_i: a step of Δ costs λκ (1 − cos Δ) ≈ λκ Δ²/2, quadratic in the step, so a
turn spread over many waypoints costs less than the same turn made at once (a 100° swing in one step costs as
much as ten steps of 32°). With a knee δ > 0 the cost of a step is the pseudo-Huber function of its chord
|c_{i+1} − c_i| = √(2 (1 − cos Δ)):

    cost(Δ) = δ² (√(1 + chord² / δ²) − 1)

which is (1 − cos Δ) for steps well below δ and grows as δ · chord (linear in the step) above it: small steps
stay smooth, and a turn costs about its size, however fast it is made. Pair values are 1 − cost, so δ = 0 and
steps ≪ δ give the paper's c_{i+1}·c_i. Pure functions of arrays; no state.
"""

from __future__ import annotations

import numpy as np

__all__ = ["pair_slope", "pair_value", "path_value"]


def pair_value(cos: np.ndarray | float, knee: float) -> np.ndarray | float:
    """Value of consecutive axes with cosine ``cos`` (any shape): cos itself for ``knee`` = 0 (the paper's
    term), else 1 − δ² (√(1 + 2 (1 − cos) / δ²) − 1) with δ = ``knee`` (a chord length, ≈ the angle [rad])."""
    if knee <= 0:
        return cos
    chord2 = np.maximum(2.0 * (1.0 - np.asarray(cos)), 0.0)
    k2 = knee * knee
    return 1.0 - k2 * (np.sqrt(1.0 + chord2 / k2) - 1.0)


def pair_slope(cos: np.ndarray, knee: float) -> np.ndarray | float:
    """d pair_value / d cos (same shape as ``cos``): 1 for ``knee`` = 0, else 1 / √(1 + chord² / δ²) ∈ (0, 1]."""
    if knee <= 0:
        return 1.0
    chord2 = np.maximum(2.0 * (1.0 - np.asarray(cos)), 0.0)
    return 1.0 / np.sqrt(1.0 + chord2 / (knee * knee))


def path_value(C: np.ndarray, knee: float) -> float:
    """Σ pair values of consecutive unit axes C (N, 3) (without a knee: Σ c_{i+1}·c_i, summed over all products)."""
    if knee <= 0:
        return float(np.sum(C[1:] * C[:-1]))
    return float(np.sum(pair_value(np.einsum("ij,ij->i", C[1:], C[:-1]), knee)))
