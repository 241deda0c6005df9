"""Pan branches along a planned horizon, and the unwind a bounded pan range forces on turning routes.

A world viewing direction fixes the pan angle only modulo 2π. Over a horizon of N waypoints the joint
sequence is chosen as a whole (:func:`unwrap_pans`): among the equivalent values p + 2πk inside the pan
limits, the sequence that minimises the total slew |p₀ − start| + Σ|pᵢ − pᵢ₋₁| (an exact dynamic
programme over the branches; with continuous pan it is the nearest unwrap). On a gimbal whose range
is wider than 2π this picks, at every waypoint, the branch that leaves room for the turns ahead instead
of the one nearest the previous pan.

When the range is narrower than a full turn (e.g. ±170°) a direction has at most one pan value, and a
route that turns the body far enough drives a world-fixed view into the limit: the optimizer's
world-space step across the unreachable sector behind the gimbal becomes a joint step of almost 2π
(:func:`long_slews`). Crossing it slowly, the way the world-space plan interpolates it (and the way an
anchored replan keeps proposing directions next to the camera's current one), leaves the camera
pointing at whatever lies between for seconds. :func:`unwind_targets` turns such a plan into one
decisive slew: the waypoints that cannot be seen from the current side of the range (and the blind
ones leading up to them) take the direction of the first rich waypoint beyond the long step, so the
joint controller slews straight there at its limits.

Where along the horizon to unwind: the slew sweeps the camera across the landmark-free sector of the
surroundings, and how wide that sector is changes along the route (narrow next to a corner of walls,
wide across a room). :func:`pan_profile` counts the landmarks a view at each pan would see at one
waypoint; :func:`sweep` measures the blind arc of an unwind from a pan to the far side of the visible
landmarks; the planner unwinds at the waypoint with the smallest blind arc instead of at the limit.
"""

from __future__ import annotations

import numpy as np

from pivotd.geometry import direction_to_pan_tilt
from pivotd.gimbal.kinematics import JointLimits, Mount, base_from_world

TWO_PI = 2.0 * np.pi
LONG_SLEW = np.pi  # [rad] a joint step longer than this goes the long way round the pan axis
RICH_SHARE = 0.5  # a waypoint is "rich" when it sees at least this share of the best count beyond the slew
PROFILE_STEP = np.radians(5.0)  # [rad] pan resolution of :func:`pan_profile`


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
    layers: list[np.ndarray] = []
    for i in range(n):
        b = pan_branches(float(pans[i]), limits)
        if b.size == 0:  # unreachable sector: the nearer limit, measured around the circle
            wrapped_lo = np.remainder(limits.pan_min - pans[i], TWO_PI)
            wrapped_hi = np.remainder(pans[i] - limits.pan_max, TWO_PI)
            b = np.array([limits.pan_min if wrapped_lo <= wrapped_hi else limits.pan_max])
            clamped[i] = True
        layers.append(b)
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


def long_slews(start: float, joint_pans: np.ndarray) -> np.ndarray:
    """Indices i (ascending) where the joint step into waypoint i (from ``start`` for i = 0) exceeds π [rad]:
    there the world-space turn is short the other way round, through the pan range's unreachable sector."""
    p = np.concatenate([[float(start)], np.asarray(joint_pans, float).reshape(-1)])
    return np.flatnonzero(np.abs(np.diff(p)) > LONG_SLEW)


def base_pan_tilt(directions: np.ndarray, body_quats: np.ndarray, mount: Mount) -> tuple[np.ndarray, np.ndarray]:
    """Primary joint angles (pan ∈ (−π, π], tilt ∈ [−π/2, π/2]) [rad], (N,) each, of world ``directions`` (N, 3)
    for bodies at ``body_quats`` (N, 4)."""
    d = np.einsum("nij,nj->ni", base_from_world(np.asarray(body_quats, float).reshape(-1, 4), mount),
                  np.asarray(directions, float).reshape(-1, 3))
    return direction_to_pan_tilt(d)


def joint_pans(directions: np.ndarray, body_quats: np.ndarray, mount: Mount, limits: JointLimits,
               start: float) -> tuple[np.ndarray, np.ndarray]:
    """Joint pans (N,) [rad] of a plan (directions (N, 3), attitudes (N, 4)) chosen by :func:`unwrap_pans`
    from the commanded pan ``start``, and the clamped mask (N,)."""
    pan, _ = base_pan_tilt(directions, body_quats, mount)
    return unwrap_pans(pan, start, limits)


def unwind_targets(counts: np.ndarray, first_long: int) -> np.ndarray:
    """For a plan whose joint sequence takes the long way into waypoint ``first_long``: for each waypoint
    (N,), the index of the direction it should take (itself when unchanged).

    ``counts`` (N,): landmarks each planned direction sees. The target is the first waypoint at or after
    ``first_long`` that sees at least RICH_SHARE of the best count there. Waypoints from ``first_long`` up to
    the target, and the blind waypoints (count 0) just before ``first_long`` (the slow world-space crossing
    an anchored replan proposes), take the target's direction, so the slew starts now and goes straight.
    """
    counts = np.asarray(counts, float).reshape(-1)
    n = counts.shape[0]
    out = np.arange(n)
    if not 0 <= first_long < n:
        return out
    beyond = counts[first_long:]
    best = float(beyond.max())
    if best <= 0:
        return out
    target = first_long + int(np.flatnonzero(beyond >= RICH_SHARE * best)[0])
    lead = first_long
    while lead > 0 and counts[lead - 1] <= 0:
        lead -= 1
    out[lead:target] = target
    return out


def pan_profile(bearings: np.ndarray, half_fov: float,
                limits: JointLimits) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Pan grid (G,) [rad] every PROFILE_STEP over the pan range, the landmarks (G,) the best view at each pan
    would see, and that view's tilt (G,) [rad] (tilts every 2·PROFILE_STEP inside the tilt limits).

    ``bearings`` (M, 3): landmark bearings from the camera in the gimbal base frame (any length); a view
    sees the bearings within ``half_fov`` [rad] of it in pan and in tilt. Cost O(T·(M + G)): a histogram
    of the landmarks' pans per tilt band, summed over a sliding window.
    """
    lo, hi = (-np.pi, np.pi) if limits.continuous_pan else (limits.pan_min, limits.pan_max)
    grid = np.arange(lo, hi + 1e-9, PROFILE_STEP)
    tilts = np.arange(max(limits.tilt_min, -np.pi / 2), min(limits.tilt_max, np.pi / 2) + 1e-9, 2 * PROFILE_STEP)
    b = np.asarray(bearings, float).reshape(-1, 3)
    if b.shape[0] == 0 or tilts.shape[0] == 0:
        return grid, np.zeros(grid.shape[0]), np.zeros(grid.shape[0])
    pan, tl = direction_to_pan_tilt(b)
    bins = round(TWO_PI / PROFILE_STEP)
    cell = np.floor(np.remainder(pan + np.pi, TWO_PI) / PROFILE_STEP).astype(np.int64) % bins
    w = int(np.floor(half_fov / PROFILE_STEP))
    cells = np.floor(np.remainder(grid + np.pi, TWO_PI) / PROFILE_STEP).astype(np.int64) % bins
    T = tilts.shape[0]
    rows, cols = np.nonzero(np.abs(tl[None, :] - tilts[:, None]) <= half_fov)  # (band, landmark) memberships
    hist = np.bincount(rows * bins + cell[cols], minlength=T * bins).reshape(T, bins).astype(float)
    # the window of pan cells c − w … c + w (circular) of every band: differences of a running sum over the
    # histogram wrapped by w cells on both sides (integer counts: the same sums as adding the shifted copies)
    wrapped = np.concatenate([hist[:, bins - w:], hist, hist[:, :w]], axis=1) if w else hist
    run = np.concatenate([np.zeros((T, 1)), np.cumsum(wrapped, axis=1)], axis=1)
    window = run[:, 2 * w + 1:2 * w + 1 + bins] - run[:, :bins]
    table = window[:, cells]
    best = np.argmax(table, axis=0)
    return grid, table[best, np.arange(grid.shape[0])], tilts[best]


def sweep(grid: np.ndarray, counts: np.ndarray, start: float, up: bool) -> tuple[float, float | None]:
    """Blind arc [rad] and target pan [rad] of an unwind from pan ``start`` toward the upper (``up``) or lower
    end of the range, over a profile (grid (G,), counts (G,)) from :func:`pan_profile`.

    The sweep leaves the landmarks in view at ``start``, crosses the landmark-free stretch (its length is
    the blind arc) and ends in the far-side stretch of landmarks, at its farthest pan that sees at least
    RICH_SHARE of that stretch's best count (the most room for the turn ahead). (inf, None) when no
    far side lies inside the range.
    """
    i0 = int(np.clip(np.searchsorted(grid, start), 0, grid.shape[0] - 1))
    order = np.arange(i0, grid.shape[0]) if up else np.arange(i0, -1, -1)
    seen = counts[order] > 0
    blind_start = int(np.argmin(seen)) if not seen.all() else seen.shape[0]
    rest = seen[blind_start:]
    if rest.shape[0] == 0 or not rest.any():
        return np.inf, None
    far = blind_start + int(np.argmax(rest))
    end = far + (int(np.argmin(seen[far:])) if not seen[far:].all() else seen.shape[0] - far)
    region = order[far:end]
    c = counts[region]
    rich = region[c >= RICH_SHARE * c.max()]
    return (far - blind_start) * PROFILE_STEP, float(grid[rich[-1]])
