"""Voxel occupancy grid and a vectorised line-of-sight test.

A voxel is occupied when at least one occupancy point falls in it. The grid is padded by one empty
voxel on every side; rays are clipped to the padded box, so anything outside counts as free.

Ray test (:meth:`OccupancyGrid.occluded_rays`): each sensor→landmark segment is sampled at points
at most ``step`` voxels apart along every axis (default 0.5), excluding both endpoints. The ray is
occluded when a sample lies in an occupied voxel, except samples

* in the sensor's own voxel (a sensor inside a mapped voxel does not blind itself),
* in the landmark's own voxel, or closer to the landmark than ``clearance`` (default one voxel
  edge): a landmark does not occlude itself, and neither does the surface layer it sits on.

Grazing behaviour: a ray that only clips the corner or edge of an occupied voxel (its chord through
the voxel shorter than the sample spacing) may pass; a ray crossing a wall at least one voxel thick
is always caught, since with ≤ 1 voxel per axis between samples one of them lands in the slab.
Because of the clearance, a landmark seen at grazing incidence along its own surface stays
visible as long as the surface layer it crosses lies within ``clearance`` of the landmark; an
obstacle closer than ``clearance`` to a landmark does not hide it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

_FRAC_BITS = 12  # fixed-point fraction bits of sample coordinates (voxel units)
_CHUNK_RAYS = 2048  # rays per vectorised batch (sorted by sample count to limit padding)
DENSE_LIMIT = 1 << 28  # voxels; above this the grid stores sorted occupied keys instead of a dense array


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
        lo = points.min(axis=0).astype(np.float64)
        hi = points.max(axis=0).astype(np.float64)
        origin = lo - 1.5 * voxel  # ≥ one empty voxel of padding on every side, robust to rounding
        dims = np.floor((hi - origin) / voxel).astype(np.int64) + 2
        ijk = np.floor((points - origin) / voxel).astype(np.int64)
        keys = (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
        total = int(np.prod(dims))
        if total <= DENSE_LIMIT:
            dense = np.zeros(total, dtype=bool)
            dense[keys] = True
            return cls(origin, float(voxel), dims, dense, None)
        return cls(origin, float(voxel), dims, None, np.unique(keys))

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

    def _lookup(self, keys: np.ndarray) -> np.ndarray:
        if self.dense is not None:
            return self.dense[keys]
        pos = np.minimum(np.searchsorted(self.keys, keys), self.keys.size - 1)
        return self.keys[pos] == keys

    def occluded(self, origin: np.ndarray, targets: np.ndarray, *, clearance: float | None = None,
                 step: float = 0.5) -> np.ndarray:
        """(n,) bool: whether the segment from ``origin`` (3,) to each of ``targets`` (n, 3) is blocked."""
        targets = np.asarray(targets, dtype=np.float64).reshape(-1, 3)
        origins = np.broadcast_to(np.asarray(origin, dtype=np.float64).reshape(1, 3), targets.shape)
        return self.occluded_rays(origins, targets, clearance=clearance, step=step)

    def occluded_rays(self, origins: np.ndarray, targets: np.ndarray, *, clearance: float | None = None,
                      step: float = 0.5) -> np.ndarray:
        """(n,) bool for segments ``origins[i] → targets[i]`` (n, 3) [m]; see the module doc for the rules."""
        n = targets.shape[0]
        if n == 0:
            return np.zeros(0, dtype=bool)
        if not 0 < step <= 1:
            raise ValueError(f"ray step must be in (0, 1] voxels, got {step}")
        v = self.voxel
        clear = v if clearance is None else float(clearance)
        o = (np.asarray(origins, dtype=np.float64) - self.origin) / v  # voxel units
        t = (np.asarray(targets, dtype=np.float64) - self.origin) / v
        d = t - o
        length = np.sqrt(np.einsum("ij,ij->i", d, d))  # voxels
        # Sample only up to the clearance point; it is the last sample (j = m), the sensor is j = 0.
        reach = 1.0 - clear / v / np.maximum(length, 1e-12)
        d = d * np.maximum(reach, 0.0)[:, None]
        m = np.maximum(np.ceil(np.abs(d).max(axis=1) / step), 1.0)  # intervals per ray
        # Parameter range inside the padded box [0.5, dims - 0.5] (Liang–Barsky).
        s0 = np.zeros(n)
        s1 = np.where(reach > 0, 1.0, -1.0)
        lo = 0.5
        hi = self.dims.astype(np.float64) - 0.5
        with np.errstate(divide="ignore", invalid="ignore"):
            for k in range(3):
                dk = d[:, k]
                ta = (lo - o[:, k]) / dk
                tb = (hi[k] - o[:, k]) / dk
                inside = (o[:, k] >= lo) & (o[:, k] <= hi[k])
                moving = dk != 0
                s0 = np.maximum(s0, np.where(moving, np.minimum(ta, tb), np.where(inside, -np.inf, np.inf)))
                s1 = np.minimum(s1, np.where(moving, np.maximum(ta, tb), np.where(inside, np.inf, -np.inf)))
        j0 = np.maximum(np.ceil(s0 * m), 1.0).astype(np.int64)
        j1 = np.minimum(np.floor(s1 * m), m).astype(np.int64)  # inclusive
        active = np.flatnonzero(j1 >= j0)
        out = np.zeros(n, dtype=bool)
        if active.size == 0:
            return out
        # Fixed-point voxel coordinates: sample j of ray i is at o_i + j·δ_i, δ = d / m.
        itype = np.int32 if int(self.dims.max()) < (1 << (31 - _FRAC_BITS)) - 1 else np.int64
        scale = float(1 << _FRAC_BITS)
        o_fp = np.floor(o[active] * scale).astype(itype)
        step_fp = np.round(d[active] / m[active, None] * scale).astype(itype)
        j0a, j1a = j0[active].astype(itype), j1[active].astype(itype)
        counts = j1a - j0a + 1
        order = np.argsort(counts, kind="stable")
        ny, nz = int(self.dims[1]), int(self.dims[2])
        strides = (ny * nz, nz, 1)
        for chunk in np.array_split(order, max(1, order.size // _CHUNK_RAYS)):
            if chunk.size == 0:
                continue
            width = int(counts[chunk].max())
            jj = np.minimum(j0a[chunk, None] + np.arange(width, dtype=itype)[None, :], j1a[chunk, None])
            key = np.zeros(jj.shape, dtype=np.int64 if itype is np.int64 or int(np.prod(self.dims)) >= 1 << 31
                           else np.int32)
            for k in range(3):
                c = jj * step_fp[chunk, k, None]
                c += o_fp[chunk, k, None]
                c >>= _FRAC_BITS
                if strides[k] != 1:
                    c *= strides[k]
                key += c
            hit_r, hit_c = np.nonzero(self._lookup(key))
            if hit_r.size == 0:
                continue
            rays = active[chunk[hit_r]]
            hk = key[hit_r, hit_c].astype(np.int64)
            own = (hk == _keys_of(o[rays], self.dims)) | (hk == _keys_of(t[rays], self.dims))
            out[rays[~own]] = True
        return out


def _keys_of(cells: np.ndarray, dims: np.ndarray) -> np.ndarray:
    ijk = np.floor(cells).astype(np.int64)
    return (ijk[:, 0] * dims[1] + ijk[:, 1]) * dims[2] + ijk[:, 2]
