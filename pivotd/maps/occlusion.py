"""Voxel occupancy grid and a vectorised line-of-sight test.

A voxel is occupied when at least one occupancy point falls in it; obstacles are therefore
voxel-sized (a wall reaches up to one voxel beyond its last point). The grid is padded by one empty
voxel on every side and rays are clipped to it, so anything outside counts as free. Small grids are
a dense bool array; grids above DENSE_LIMIT voxels keep sorted occupied keys instead.

Ray test (:meth:`OccupancyGrid.occluded_rays`): each sensor→landmark segment is sampled at points
``step`` voxels apart along its dominant axis (default 1, so at most one voxel apart along every
axis). The ray is blocked when a sample lies in an occupied voxel, except samples

* in the sensor's own voxel (a sensor inside a mapped voxel does not blind itself),
* in the landmark's own voxel, or closer to the landmark than ``clearance`` (default one voxel
  edge): a landmark does not occlude itself, nor does the surface layer right around it.

Guarantee and grazing behaviour: any stretch of the sight line at least one sample spacing long
that lies in occupied voxels is caught — in particular every crossing of a hole-free wall at least
one voxel thick. A ray that only clips the corner or edge of occupied voxels (a stretch shorter than
the spacing) may pass. Obstacles closer than ``clearance`` to the landmark, or wholly inside the
sensor's or landmark's voxel, never hide it. ``step=0.5`` halves the spacing at twice the cost.

Samples use fixed-point integer coordinates (12 fraction bits) processed in batches of rays sorted
by sample count, so there is no per-ray or per-sample Python loop.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from pivotd.errors import InputError
from pivotd.maps.grid_index import cell_keys, column_bounds, grid_dims
from pivotd.progress import Progress

_FRAC_BITS = 12  # fixed-point fraction bits of sample coordinates (voxel units)
_CHUNK_RAYS = 2048  # rays per vectorised batch (sorted by sample count to limit padding)
_OWN_MARGIN = 0.01  # voxels
_BUILD_CHUNK = 1 << 20  # points per step while building the grid
DENSE_LIMIT = 1 << 28  # voxels; above this the grid stores sorted occupied keys instead of a dense array
MAX_AXIS_VOXELS = 1 << 16  # voxels along one axis of the grid (bounds the samples of any ray)
MAX_RAY_VOXELS = 4096  # max_range / voxel accepted in a configuration (samples per ray ≤ this)
_BATCH_SAMPLES = 1 << 21  # samples per vectorised batch (work buffers ≈ 13 B per sample)


def voxel_problem(voxel: float, max_range: float) -> str | None:
    """Why an occlusion ``voxel`` [m] is unusable with rays up to ``max_range`` [m] long (None when fine)."""
    if not (math.isfinite(voxel) and voxel > 0):
        return f"must be a finite size > 0 m, got {voxel!r}"
    if math.isfinite(max_range) and max_range / voxel > MAX_RAY_VOXELS:
        return (f"{voxel:g} m makes a {max_range:g} m ray {max_range / voxel:.3g} voxels long, more than "
                f"{MAX_RAY_VOXELS}; use a voxel ≥ {max_range / MAX_RAY_VOXELS:.3g} m")
    return None


@dataclass(frozen=True)
class OccupancyGrid:
    """origin: (3,) float64 corner [m]; voxel: edge [m]; dims: (3,) int64 voxel counts (incl. padding);
    dense: flat (nx·ny·nz,) bool or None; keys: sorted occupied voxel keys (K,) int64 (when not dense)."""

    origin: np.ndarray
    voxel: float
    dims: np.ndarray
    dense: np.ndarray | None
    keys: np.ndarray | None

    @classmethod
    def from_points(cls, points: np.ndarray, voxel: float) -> OccupancyGrid:
        """Grid whose occupied voxels are those holding at least one of ``points`` (K, 3) [m]."""
        if not voxel > 0:
            raise ValueError(f"occupancy voxel must be > 0, got {voxel}")
        points = np.asarray(points)
        if points.shape[0] == 0:
            return cls(np.zeros(3), float(voxel), np.full(3, 3, np.int64), np.zeros(27, bool), None)
        lo, hi = column_bounds(points)
        origin = lo - 1.5 * voxel  # ≥ one empty voxel of padding on every side, robust to rounding
        extent = float(np.max(hi - lo))
        if extent / voxel > MAX_AXIS_VOXELS - 4:  # before any integer conversion: the ratio may be astronomic
            raise InputError(
                f"occlusion voxel {voxel:g} m is too small for the occupancy extent of {extent:.4g} m: "
                f"{extent / voxel:.3g} voxels along an axis, at most {MAX_AXIS_VOXELS - 4} (use a voxel ≥ "
                f"{extent / (MAX_AXIS_VOXELS - 4):.3g} m)"
            )
        dims = grid_dims(origin, hi, voxel)
        total = math.prod(int(d) for d in dims)
        dense = np.zeros(total, dtype=bool) if total <= DENSE_LIMIT else None
        parts = []
        n = points.shape[0]
        with Progress("occupancy grid", n, "points") as progress:
            for start in range(0, n, _BUILD_CHUNK):  # chunks bound the temporaries and report progress
                keys = cell_keys(points[start:start + _BUILD_CHUNK], origin, voxel, dims)
                if dense is not None:
                    dense[keys] = True
                else:
                    parts.append(np.unique(keys))
                progress.update(min(n, start + _BUILD_CHUNK))
        if dense is not None:
            return cls(origin, float(voxel), dims, dense, None)
        return cls(origin, float(voxel), dims, None, np.unique(np.concatenate(parts)).astype(np.int64))

    @property
    def occupied_count(self) -> int:
        return int(self.dense.sum()) if self.dense is not None else int(self.keys.size)

    def is_occupied(self, points: np.ndarray) -> np.ndarray:
        """Occupancy (n,) bool of the voxels holding ``points`` (n, 3); outside the grid is free."""
        ijk = np.floor((np.asarray(points, dtype=np.float64) - self.origin) / self.voxel).astype(np.int64)
        inside = ((ijk >= 0) & (ijk < self.dims)).all(axis=1)
        out = np.zeros(ijk.shape[0], dtype=bool)
        k = (ijk[inside, 0] * self.dims[1] + ijk[inside, 1]) * self.dims[2] + ijk[inside, 2]
        out[inside] = self._lookup(k)
        return out

    def _lookup(self, keys: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        if self.dense is not None:
            return np.take(self.dense, keys, out=out)
        pos = np.minimum(np.searchsorted(self.keys, keys), self.keys.size - 1)
        found = self.keys[pos] == keys
        if out is None:
            return found
        out[...] = found
        return out

    def occluded(self, origin: np.ndarray, targets: np.ndarray, *, clearance: float | None = None,
                 step: float = 1.0) -> np.ndarray:
        """(n,) bool: whether the segment from ``origin`` (3,) to each of ``targets`` (n, 3) is blocked."""
        targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        origins = np.broadcast_to(np.asarray(origin, dtype=np.float64).reshape(1, 3), targets.shape)
        return self.occluded_rays(origins, targets, clearance=clearance, step=step)

    def occluded_rays(self, origins: np.ndarray, targets: np.ndarray, *, clearance: float | None = None,
                      step: float = 1.0) -> np.ndarray:
        """(n,) bool for segments ``origins[i] → targets[i]`` (n, 3) [m]; see the module doc for the rules."""
        n = targets.shape[0]
        if n == 0:
            return np.zeros(0, dtype=bool)
        if not 0 < step <= 1:
            raise ValueError(f"ray step must be in (0, 1] voxels, got {step}")
        v = self.voxel
        clear = v if clearance is None else float(clearance)
        with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
            return self._occluded_rays(origins, targets, clear, step)

    def _occluded_rays(self, origins: np.ndarray, targets: np.ndarray, clear: float, step: float) -> np.ndarray:
        n = targets.shape[0]
        v = self.voxel
        o = (np.asarray(origins, dtype=np.float64) - self.origin) / v  # voxel units
        t = (np.asarray(targets, dtype=np.float64) - self.origin) / v
        d = t - o
        # Column-wise arithmetic throughout: reductions over a length-3 axis are slow in numpy.
        ox, oy, oz = o[:, 0], o[:, 1], o[:, 2]
        dx, dy, dz = _nonzero(d[:, 0]), _nonzero(d[:, 1]), _nonzero(d[:, 2])
        length = np.sqrt(dx * dx + dy * dy + dz * dz)  # voxels
        # Leave the sensor's voxel / enter the landmark's (parameters in [0, 1] of o → t).
        s_out, s_in = _own_voxel_params((ox, oy, oz), (t[:, 0], t[:, 1], t[:, 2]), (dx, dy, dz))
        # Sample only up to the clearance point; it is the last sample (j = m), the sensor is j = 0.
        reach = 1.0 - clear / v / np.maximum(length, 1e-12)
        scale_r = np.where(reach > 0, reach, 1.0)
        r = np.maximum(reach, 1e-12)
        dx, dy, dz = dx * r, dy * r, dz * r
        d = np.stack([dx, dy, dz], axis=1)
        extent = np.maximum(np.maximum(np.abs(dx), np.abs(dy)), np.abs(dz))
        m = np.maximum(np.ceil(extent / step), 1.0)  # intervals per ray
        # Parameter range outside both own voxels and inside the padded box [0.5, dims - 0.5] (Liang–Barsky;
        # a zero component is a tiny positive one, which yields ±huge bounds with the right meaning).
        s0 = s_out / scale_r
        s1 = np.where(reach > 0, np.minimum(1.0, s_in / scale_r), -1.0)
        for ok_, dk, hk in ((ox, dx, self.dims[0]), (oy, dy, self.dims[1]), (oz, dz, self.dims[2])):
            ta = (0.5 - ok_) / dk
            tb = (float(hk) - 0.5 - ok_) / dk
            s0 = np.maximum(s0, np.minimum(ta, tb))
            s1 = np.minimum(s1, np.maximum(ta, tb))
        # Finite, bounded parameters (degenerate or non-finite rays end up with no samples).
        s0 = np.clip(np.nan_to_num(s0, nan=2.0), 0.0, 2.0)
        s1 = np.clip(np.nan_to_num(s1, nan=-1.0), -1.0, 1.0)
        j0 = np.maximum(np.ceil(s0 * m), 1.0).astype(np.int64)
        j1 = np.minimum(np.floor(s1 * m), m).astype(np.int64)  # inclusive
        bad = ~(np.isfinite(length) & np.isfinite(o).all(axis=1))
        j0[bad], j1[bad] = 1, 0
        active = np.flatnonzero(j1 >= j0)
        out = np.zeros(n, dtype=bool)
        if active.size == 0:
            return out
        # Fixed-point voxel coordinates: sample j of ray i is at o_i + j·δ_i, δ = d / m.
        small = int(self.dims.max()) < (1 << (31 - _FRAC_BITS)) - 1 and math.prod(int(d) for d in self.dims) < (1 << 31)
        itype = np.int32 if small else np.int64  # fixed-point coordinates and keys share one width
        scale = float(1 << _FRAC_BITS)
        o_fp = np.floor(o[active] * scale).astype(itype)
        step_fp = np.round(d[active] / m[active, None] * scale).astype(itype)
        j0a, j1a = j0[active].astype(itype), j1[active].astype(itype)
        counts = j1a - j0a + 1
        order = np.argsort(counts, kind="stable")
        ny, nz = int(self.dims[1]), int(self.dims[2])
        strides = (ny * nz, nz, 1)
        ktype = itype
        # Work buffers reused across batches (fresh large arrays would cost page faults every time); batches of
        # long rays hold fewer rays, so a batch never exceeds _BATCH_SAMPLES samples (or one ray).
        cap = max(min(min(order.size, _CHUNK_RAYS) * int(counts.max()), _BATCH_SAMPLES), int(counts.max()))
        jj_buf = np.empty(cap, dtype=itype)
        c_buf = np.empty(cap, dtype=itype)
        key_buf = np.empty(cap, dtype=ktype)
        occ_buf = np.empty(cap, dtype=bool)
        lane = np.arange(int(counts.max()), dtype=itype)
        lo_ = 0
        while lo_ < order.size:
            chunk = order[lo_:lo_ + _CHUNK_RAYS]
            width = int(counts[chunk[-1]])  # sorted by count: the last ray is the longest
            if chunk.size * width > cap:
                chunk = chunk[:max(1, cap // width)]
                width = int(counts[chunk[-1]])
            lo_ += chunk.size
            shape = (chunk.size, width)
            size = chunk.size * width
            jj = jj_buf[:size].reshape(shape)
            c = c_buf[:size].reshape(shape)
            key = key_buf[:size].reshape(shape)
            np.add(j0a[chunk, None], lane[None, :width], out=jj)
            np.minimum(jj, j1a[chunk, None], out=jj)
            for k in range(3):
                np.multiply(jj, step_fp[chunk, k, None], out=c)
                c += o_fp[chunk, k, None]
                c >>= _FRAC_BITS
                if k == 0:
                    np.multiply(c, strides[0], out=key)
                else:
                    if strides[k] != 1:
                        c *= strides[k]
                    key += c
            occ = occ_buf[:size].reshape(shape)
            self._lookup(key, out=occ)
            out[active[chunk]] = occ.any(axis=1)
        return out


def _nonzero(x: np.ndarray) -> np.ndarray:
    """``x`` with exact zeros replaced by a tiny positive value (keeps divisions finite and signed)."""
    return np.where(x == 0, 1e-300, x)


def _own_voxel_params(o: tuple, t: tuple, d: tuple) -> tuple[np.ndarray, np.ndarray]:
    """Ray parameters (n,) where segments o → t leave o's voxel and enter t's.

    o, t, d: per-axis (n,) columns in voxel units, d = t − o with no exact zeros. A small margin
    (_OWN_MARGIN voxels) widens both so rounding never counts an own voxel as a hit.
    """
    s_out = s_in = None
    for ok_, tk, dk in zip(o, t, d, strict=True):
        pos = dk > 0
        # Leaving o's voxel: its upper face (+margin) when moving up, its lower face (−margin) when moving down.
        leave = (np.floor(ok_) + np.where(pos, 1.0 + _OWN_MARGIN, -_OWN_MARGIN) - ok_) / dk
        # Entering t's voxel: its lower face (−margin) when moving up, its upper face (+margin) when moving down.
        enter = (np.floor(tk) + np.where(pos, -_OWN_MARGIN, 1.0 + _OWN_MARGIN) - ok_) / dk
        s_out = leave if s_out is None else np.minimum(s_out, leave)
        s_in = enter if s_in is None else np.maximum(s_in, enter)
    return s_out, s_in
