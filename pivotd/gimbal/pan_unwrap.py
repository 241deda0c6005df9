"""Pan branches along a planned horizon.

A world viewing direction fixes the pan angle only modulo 2π. Over a horizon of N waypoints the joint
sequence is chosen as a whole (:func:`unwrap_pans`): among the equivalent values p + 2πk inside the pan
limits, the sequence that minimises the total slew |p₀ − start| + Σ|pᵢ − pᵢ₋₁| (an exact dynamic
programme over the branches; with continuous pan it is the nearest unwrap). On a gimbal whose range
is wider than 2π this picks, at every waypoint, the branch that leaves room for the turns ahead instead
of the one nearest the previous pan. When the range is narrower than a full turn (e.g. ±170°) a route that
turns the body far enough drives a world-fixed view into the limit and forces a slew the long way round;
the planner weighs that where it plans (its joint-grid seed and its judge of plans as executed,
pivotd.daemon.planner).
"""

from __future__ import annotations

import numpy as np

from pivotd.geometry import direction_to_pan_tilt
from pivotd.gimbal.kinematics import JointLimits, Mount, base_from_world

TWO_PI = 2.0 * np.pi


def pan_branches(pan: float, limits: JointLimits, reference: float = 0.0) -> np.ndarray:
    """Joint values pan + 2πk [rad] a direction at ``pan`` may take.

    Bounded pan: every such value inside the limits (none when ``pan`` lies in the unreachable sector).
    Continuous pan: the one value nearest ``reference``.
    """
    if limits.continuous_pan:
        return np.array([reference + float(np.remainder(pan - reference + np.pi, TWO_PI) - np.pi)])
    lo, hi = limits.pan_min, limits.pan_max
    k0 = np.ceil((lo - pan) / TWO_PI - 1e-12)
    k1 = np.floor((hi - pan) / TWO_PI + 1e-12)
    return pan + TWO_PI * np.arange(k0, k1 + 1)


def unwrap_pans(pans: np.ndarray, start: float, limits: JointLimits) -> tuple[np.ndarray, np.ndarray]:
    """Joint pans (N,) equivalent to ``pans`` (N,) modulo 2π, inside the limits, with the least total slew.

    ``start``: the pan being commanded now [rad]. Minimises |p₀ − start| + Σ|pᵢ − pᵢ₋₁| over all branch
    choices (dynamic programme; exact). A waypoint whose pan has no value inside the limits takes the
    nearer limit (returned in ``clamped`` (N,) bool); with continuous pan every step is the nearest one.
    """
    pans = np.asarray(pans, float).reshape(-1)
    n = pans.shape[0]
    clamped = np.zeros(n, bool)
    if n == 0:
        return pans.copy(), clamped
    if limits.continuous_pan:
        out = np.empty(n)
        ref = float(start)
        for i in range(n):
            ref = out[i] = float(pan_branches(pans[i], limits, ref)[0])
        return out, clamped
    # every waypoint's branches pan + 2πk, k0 ≤ k ≤ k1 (pan_branches, for all waypoints at once)
    lo, hi = limits.pan_min, limits.pan_max
    k0 = np.ceil((lo - pans) / TWO_PI - 1e-12)
    k1 = np.floor((hi - pans) / TWO_PI + 1e-12)
    counts = (k1 - k0 + 1).astype(np.int64)
    none = counts <= 0
    if none.any():  # unreachable sector: the nearer limit, measured around the circle
        wrapped_lo = np.remainder(lo - pans, TWO_PI)
        wrapped_hi = np.remainder(pans - hi, TWO_PI)
        clamped = none
    if (counts <= 1).all():  # one value per waypoint: nothing to choose
        out = pans + TWO_PI * k0
        if none.any():
            out[none] = np.where(wrapped_lo <= wrapped_hi, lo, hi)[none]
        return out, clamped
    layers: list[np.ndarray] = []
    for i in range(n):
        if none[i]:
            layers.append(np.array([lo if wrapped_lo[i] <= wrapped_hi[i] else hi]))
        else:
            layers.append(pans[i] + TWO_PI * np.arange(k0[i], k1[i] + 1))
    cost = np.abs(layers[0] - start)
    back: list[np.ndarray] = []
    for i in range(1, n):
        step = cost[None, :] + np.abs(layers[i][:, None] - layers[i - 1][None, :])  # (new, old)
        arg = np.argmin(step, axis=1)
        back.append(arg)
        cost = step[np.arange(layers[i].shape[0]), arg]
    out = np.empty(n)
    j = int(np.argmin(cost))
    for i in range(n - 1, -1, -1):
        out[i] = layers[i][j]
        if i:
            j = int(back[i - 1][j])
    return out, clamped


def base_pan_tilt(directions: np.ndarray, body_quats: np.ndarray, mount: Mount) -> tuple[np.ndarray, np.ndarray]:
    """Primary joint angles (pan ∈ (−π, π], tilt ∈ [−π/2, π/2]) [rad], (N,) each, of world ``directions`` (N, 3)
    for bodies at ``body_quats`` (N, 4)."""
    d = np.einsum("nij,nj->ni", base_from_world(np.asarray(body_quats, float).reshape(-1, 4), mount),
                  np.asarray(directions, float).reshape(-1, 3))
    return direction_to_pan_tilt(d)
