"""Layered landmark map with immutable snapshots for lock-free readers.

A :class:`MapStore` holds named layers (e.g. ``base`` from the map file, ``targets`` from semantic
detections with their own weight multiplier). Every update builds a new :class:`MapSnapshot`
off to the side — sorted points, grid index, occupancy grid — and swaps one reference, so readers
calling :meth:`MapStore.snapshot` never wait for writers and never see a half-built map. Writers
are serialised by a lock. Each update increments ``version`` so planners can cache per version.

Memory per landmark: points 12 B + weights 4 B (float32) + grid index ≤ 16 B (sorted cell keys and
offsets, typically much less) [+ directions 12 B when known]. A single layer with multiplier 1 is
shared without copies; several layers are concatenated into the snapshot arrays.

Dense cells: with ``cell_cap`` a layer also keeps, fixed at load, an even subsample of at most that many
landmarks of every grid cell that holds more (:meth:`GridIndex.thinned`, 4 B per kept landmark), and the
retained-set queries read only those. A query then touches at most ``cell_cap`` landmarks per cell in range,
however densely the map is packed: its cost and memory follow what the planner keeps, not the density.
The kept landmarks of a thinned cell weigh for the cell's whole count in :attr:`MapSnapshot.query_weights`
(one more float32 per landmark of the snapshot while any cell is thinned), so the planner's objective is the
map's, not the subsample's.
"""

from __future__ import annotations

import logging
import math
import threading
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.maps.filters import RetainedFilter, view_direction_mask
from pivotd.maps.formats import POINT_DTYPE, LandmarkCloud, load_landmarks
from pivotd.maps.grid_index import GridIndex, column_bounds
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.pivot.morton import interleave_bytes

log = logging.getLogger(__name__)

BASE_LAYER = "base"
DEFAULT_INDEX_CELL = 1.0  # m


@dataclass(frozen=True)
class LayerInfo:
    """Where a layer lives in the snapshot arrays: ``rows`` slice, landmark count, weight multiplier."""

    rows: slice
    count: int
    weight_multiplier: float


@dataclass(frozen=True)
class _Thin:
    """The retained-set queries' subsample of a layer's dense cells: ``rows`` (H,) ascending rows of the layer
    (int32 or int64), ``index`` over them (same grid as the layer's; see :meth:`GridIndex.thinned`)."""

    rows: np.ndarray
    index: GridIndex

    @property
    def nbytes(self) -> int:
        return int(self.rows.nbytes + self.index.nbytes)


@dataclass(frozen=True)
class _Layer:
    cloud: LandmarkCloud  # points sorted by grid cell
    index: GridIndex
    weight_multiplier: float
    thin: _Thin | None = None  # None: no cell above the store's cell cap (queries read every landmark)


@dataclass(frozen=True)
class MapSnapshot:
    """An immutable view of the map.

    points: (M, 3) float32 [m]; weights: (M,) float32 with layer multipliers applied; directions:
    (M, 3) float32 unit landmark→camera directions (zero rows unknown) or None; version: increases on
    every update; layers: name → :class:`LayerInfo`; occupancy: grid for the occlusion filter or None.
    Landmark order is the store's (grouped by layer, sorted by grid cell), not the file's.
    """

    points: np.ndarray
    weights: np.ndarray
    directions: np.ndarray | None
    version: int
    layers: dict[str, LayerInfo]
    occupancy: OccupancyGrid | None = None
    _indexes: tuple[tuple[int, GridIndex], ...] = field(default=(), repr=False)
    _thin: tuple[_Thin | None, ...] = field(default=(), repr=False)  # per entry of _indexes
    _query_weights: np.ndarray | None = field(default=None, repr=False)  # see query_weights (None: the weights)

    @property
    def query_weights(self) -> np.ndarray:
        """Weights (M,) float32 of the landmarks as the retained-set queries return them: ``weights``, with each
        kept landmark of a cell the cell cap thins weighing ``n / kept`` times its own (n landmarks in the cell),
        so that a dense cell counts in the planner's objective as much as it holds, not as much as is read."""
        return self.weights if self._query_weights is None else self._query_weights

    def __len__(self) -> int:
        return int(self.points.shape[0])

    @property
    def index_nbytes(self) -> int:
        """Bytes held by the spatial index (all layers, with the dense cells' subsamples)."""
        return sum(ix.nbytes for _, ix in self._indexes) + sum(t.nbytes for t in self._thin if t is not None)

    @property
    def queried_landmarks(self) -> int:
        """Landmarks the retained-set queries can return: all but those the cell cap leaves out."""
        if not any(t is not None for t in self._thin):
            return len(self)
        return sum(ix.count if t is None else int(t.rows.shape[0])
                   for (_, ix), t in zip(self._indexes, self._thin, strict=True))

    def summary(self) -> dict:
        """JSON-friendly description: landmark count, bounds [m], layers, directions, occupancy, version."""
        out: dict = {
            "landmarks": len(self),
            "queried_landmarks": self.queried_landmarks,
            "version": self.version,
            "layers": {k: {"count": v.count, "weight_multiplier": v.weight_multiplier} for k, v in self.layers.items()},
            "directions": self.directions is not None,
            "bounds_min": None,
            "bounds_max": None,
            "occupancy_voxel": None if self.occupancy is None else self.occupancy.voxel,
            "occupied_voxels": None if self.occupancy is None else self.occupancy.occupied_count,
        }
        if len(self):
            lo, hi = column_bounds(self.points)
            out["bounds_min"], out["bounds_max"] = lo.tolist(), hi.tolist()
        return out

    def retained(self, waypoints: np.ndarray, flt: RetainedFilter) -> list[np.ndarray]:
        """Retained landmark indices for each waypoint (N, 3) [m]: a list of N ascending int64 arrays."""
        w = np.asarray(waypoints, dtype=np.float64).reshape(-1, 3)
        n = w.shape[0]
        if n == 0:
            return []
        if not np.isfinite(w).all():
            raise InputError(f"waypoint {int(np.argmax(~np.isfinite(w).all(axis=1)))} is not finite (NaN or inf)")
        if flt.occlusion and self.occupancy is None:
            raise InputError("occlusion filter requested but the map has no occupancy grid (set an occlusion voxel)")
        if len(self) == 0:
            return [np.zeros(0, np.int64) for _ in range(n)]
        idx, counts = self._in_range(w, flt.min_range, flt.max_range)
        bounds = np.concatenate([[0], np.cumsum(counts)])
        blocks = [idx[bounds[i]:bounds[i + 1]] for i in range(n)]
        if flt.max_view_angle_deg is not None and self.directions is not None:
            blocks = [
                b[view_direction_mask(np.take(self.points, b, axis=0), np.take(self.directions, b, axis=0), w[i],
                                      flt.max_view_angle_deg)] if b.size else b
                for i, b in enumerate(blocks)
            ]
        if flt.occlusion:
            sizes = np.array([b.size for b in blocks])
            flat = np.concatenate(blocks)
            owner = np.repeat(np.arange(n), sizes)
            blocked = self.occupancy.occluded_rays(
                w[owner], np.take(self.points, flat, axis=0).astype(np.float64),
                clearance=flt.occlusion_clearance, step=flt.occlusion_step,
            )
            flat = flat[~blocked]
            kept = np.bincount(owner[~blocked], minlength=n)
            blocks = np.split(flat, np.cumsum(kept)[:-1])
        return blocks

    def _in_range(self, w: np.ndarray, rmin: float, rmax: float) -> tuple[np.ndarray, np.ndarray]:
        n = w.shape[0]
        if not math.isfinite(rmax):
            return self._in_range_brute(w, rmin)
        parts = []
        for (offset, index), thin in zip(self._indexes, self._thin or (None,) * len(self._indexes), strict=True):
            layer = self.points[offset:offset + index.count]
            if thin is None:
                idx, counts = index.query(layer, w, rmin, rmax)
            else:  # the dense cells' subsample only: never a pass over all their landmarks
                idx, counts = thin.index.query(layer, w, rmin, rmax, rows=thin.rows)
                idx = thin.rows.take(idx).astype(np.int64)
            parts.append((idx + offset, counts))
        if len(parts) == 1:
            return parts[0]
        counts = np.sum([c for _, c in parts], axis=0)
        owner = np.concatenate([np.repeat(np.arange(n), c) for _, c in parts])
        idx = np.concatenate([i for i, _ in parts])
        order = np.argsort(owner, kind="stable")  # layers are in row order, so indices stay ascending
        return idx[order], counts

    def _in_range_brute(self, w: np.ndarray, rmin: float) -> tuple[np.ndarray, np.ndarray]:
        """Unbounded max_range: every queried landmark, minus those closer than ``rmin`` (cost O(M) per waypoint)."""
        rows = self._queried_rows()
        m = len(self) if rows is None else int(rows.shape[0])
        if rmin <= 0:
            every = np.arange(m, dtype=np.int64) if rows is None else rows
            return np.tile(every, w.shape[0]), np.full(w.shape[0], m, np.int64)
        pts = self.points if rows is None else self.points.take(rows, axis=0)
        blocks = []
        for wi in w:
            d = pts.astype(np.float64) - wi
            hit = np.flatnonzero(np.einsum("ij,ij->i", d, d) >= rmin * rmin)
            blocks.append(hit if rows is None else rows.take(hit))
        return np.concatenate(blocks), np.array([b.size for b in blocks], np.int64)

    def _queried_rows(self) -> np.ndarray | None:
        """Ascending rows (Q,) the queries read (None: all of them)."""
        if not any(t is not None for t in self._thin):
            return None
        return np.concatenate([np.arange(offset, offset + ix.count, dtype=np.int64) if t is None
                               else t.rows.astype(np.int64) + offset
                               for (offset, ix), t in zip(self._indexes, self._thin, strict=True)])


class MapStore:
    """Thread-safe layered map; :meth:`snapshot` is wait-free, updates return the new version.

    occupancy_voxel [m]: build an occupancy grid of that voxel size from all map layers on every
    update; occupancy_points (K, 3): build it once from these points instead (needs the voxel size).
    index_cell [m]: grid index cell edge (default 1 m). cell_cap: most landmarks of one index cell the
    retained-set queries read (an even subsample fixed at load; None: all).
    """

    def __init__(
        self,
        occupancy_voxel: float | None = None,
        occupancy_points: np.ndarray | None = None,
        index_cell: float = DEFAULT_INDEX_CELL,
        cell_cap: int | None = None,
    ) -> None:
        if occupancy_voxel is not None and not occupancy_voxel > 0:
            raise InputError(f"occupancy voxel must be > 0 m, got {occupancy_voxel}")
        if occupancy_points is not None and occupancy_voxel is None:
            raise InputError("occupancy points need an occupancy voxel size")
        if not index_cell > 0:
            raise InputError(f"map index cell must be > 0 m, got {index_cell}")
        if cell_cap is not None and not cell_cap >= 1:
            raise InputError(f"landmarks per map cell must be ≥ 1, got {cell_cap}")
        self._cell_cap = cell_cap
        self._voxel = occupancy_voxel
        self._index_cell = float(index_cell)
        self._static_occupancy = (
            OccupancyGrid.from_points(np.asarray(occupancy_points, dtype=np.float64), occupancy_voxel)
            if occupancy_points is not None
            else None
        )
        self._layers: dict[str, _Layer] = {}
        self._write_lock = threading.Lock()
        self._snapshot = MapSnapshot(
            points=np.zeros((0, 3), POINT_DTYPE),
            weights=np.zeros(0, POINT_DTYPE),
            directions=None,
            version=0,
            layers={},
            occupancy=self._static_occupancy,
        )

    def snapshot(self) -> MapSnapshot:
        """The current immutable snapshot (never blocks)."""
        return self._snapshot

    @property
    def version(self) -> int:
        return self._snapshot.version

    def set_layer(self, name: str, cloud: LandmarkCloud, weight_multiplier: float = 1.0) -> int:
        """Create or replace layer ``name``; returns the new version."""
        if not (math.isfinite(weight_multiplier) and weight_multiplier >= 0):
            raise InputError(f"map layer '{name}': weight multiplier must be finite and ≥ 0, got {weight_multiplier}")
        layer = self._build_layer(cloud, weight_multiplier)
        with self._write_lock:
            layers = dict(self._layers)
            layers[name] = layer
            return self._publish(layers)

    def add_to_layer(self, name: str, cloud: LandmarkCloud) -> int:
        """Append landmarks to layer ``name`` (created with multiplier 1 if missing); returns the new version."""
        with self._write_lock:
            old = self._layers.get(name)
            if old is not None:
                cloud = _concat_clouds([old.cloud, cloud])
            layer = self._build_layer(cloud, old.weight_multiplier if old is not None else 1.0)
            layers = dict(self._layers)
            layers[name] = layer
            return self._publish(layers)

    def remove_layer(self, name: str) -> int:
        """Drop layer ``name``; returns the new version. Raises InputError if there is no such layer."""
        with self._write_lock:
            if name not in self._layers:
                raise InputError(f"no map layer '{name}' (layers: {', '.join(self._layers) or 'none'})")
            layers = {k: v for k, v in self._layers.items() if k != name}
            return self._publish(layers)

    def _build_layer(self, cloud: LandmarkCloud, weight_multiplier: float) -> _Layer:
        points = np.ascontiguousarray(cloud.points, dtype=POINT_DTYPE)
        weights = np.ascontiguousarray(cloud.weights, dtype=POINT_DTYPE)
        directions = None if cloud.directions is None else np.ascontiguousarray(cloud.directions, dtype=POINT_DTYPE)
        if points.ndim != 2 or points.shape[1] != 3 or weights.shape != (points.shape[0],) or (
            directions is not None and directions.shape != points.shape
        ):
            raise InputError(f"map layer: inconsistent cloud shapes {points.shape}, {weights.shape}, "
                             f"{None if directions is None else directions.shape}")
        index, order = GridIndex.build(points, self._index_cell)
        order = spatial_cell_order(points, weights, index, order)
        sorted_cloud = LandmarkCloud(
            points=np.take(points, order, axis=0),
            weights=np.take(weights, order),
            directions=None if directions is None else np.take(directions, order, axis=0),
        )
        thin = None
        if self._cell_cap is not None and (sub := index.thinned(self._cell_cap)) is not None:
            thin_index, rows = sub
            thin = _Thin(rows, thin_index)
            log.info("map layer: %d of %d landmarks in cells holding more than %d are left out of the planner's "
                     "queries", len(sorted_cloud) - rows.shape[0], len(sorted_cloud), self._cell_cap)
        return _Layer(sorted_cloud, index, float(weight_multiplier), thin)

    def _publish(self, layers: dict[str, _Layer]) -> int:
        """Build and swap in a snapshot of ``layers`` (caller holds the write lock)."""
        version = self._snapshot.version + 1
        items = list(layers.items())
        infos: dict[str, LayerInfo] = {}
        indexes = []
        thins = []
        row = 0
        for name, layer in items:
            k = len(layer.cloud)
            infos[name] = LayerInfo(slice(row, row + k), k, layer.weight_multiplier)
            indexes.append((row, layer.index))
            thins.append(layer.thin)
            row += k
        if len(items) == 1:
            only = items[0][1]
            points = only.cloud.points
            weights = only.cloud.weights
            if only.weight_multiplier != 1.0:
                weights = (weights * np.float32(only.weight_multiplier)).astype(POINT_DTYPE)
            directions = only.cloud.directions
        elif items:
            points = np.concatenate([ly.cloud.points for _, ly in items])
            weights = np.concatenate([ly.cloud.weights * np.float32(ly.weight_multiplier) for _, ly in items])
            weights = weights.astype(POINT_DTYPE, copy=False)
            if any(ly.cloud.directions is not None for _, ly in items):
                directions = np.concatenate([
                    ly.cloud.directions if ly.cloud.directions is not None
                    else np.zeros((len(ly.cloud), 3), POINT_DTYPE)
                    for _, ly in items
                ])
            else:
                directions = None
        else:
            points, weights, directions = np.zeros((0, 3), POINT_DTYPE), np.zeros(0, POINT_DTYPE), None
        occupancy = self._static_occupancy
        if occupancy is None and self._voxel is not None:
            occupancy = OccupancyGrid.from_points(points, self._voxel)
        for arr in (points, weights, directions):
            if arr is not None:
                arr.flags.writeable = False
        snap = MapSnapshot(points, weights, directions, version, infos, occupancy, tuple(indexes), tuple(thins),
                           _thinned_weights(weights, indexes, thins))
        self._layers = layers
        self._snapshot = snap  # the single reference swap readers observe
        log.debug("map version %d: %d landmarks in %d layers", version, len(snap), len(infos))
        return version


def _thinned_weights(weights: np.ndarray, indexes: list[tuple[int, GridIndex]],
                     thins: list[_Thin | None]) -> np.ndarray | None:
    """``weights`` (M,) with the kept rows of every thinned cell scaled by its landmarks over those kept (a copy,
    read-only); None when no layer is thinned. Cost O(M) per map update, none per query."""
    if not any(t is not None for t in thins):
        return None
    out = weights.copy()
    for (offset, index), thin in zip(indexes, thins, strict=True):
        if thin is None:
            continue
        kept = np.diff(thin.index.starts)
        scale = (np.diff(index.starts) / np.maximum(kept, 1)).astype(POINT_DTYPE)
        rows = thin.rows.astype(np.int64) + offset
        out[rows] *= np.repeat(scale, kept)
    out.flags.writeable = False
    return out


_CHUNK = 1 << 20  # rows per block of spatial_cell_order's temporaries


def spatial_cell_order(points: np.ndarray, weights: np.ndarray, index: GridIndex, order: np.ndarray) -> np.ndarray:
    """The grid's cell order ``order`` (M,) of ``points`` (M, 3) [m] (from :meth:`GridIndex.build`) refined
    within each cell by the Z-order (pivotd.pivot.morton) of each landmark's position inside its cell, 8 bits
    per axis (cell / 256); ties by coordinates, then weight (``weights`` (M,)).

    The result depends on the landmarks only, not on their order in the file: every retained set read off
    the index (ascending rows) is then in an order fixed by the landmarks and spread over space, so the
    strided subsamples of the planner and the optimizer need no per-call sort. Cost O(M log M), at load:
    sequential passes over the points, one gather of an (M,) uint32 key in cell order, and a stable sort
    of keys that are already sorted by cell.
    Memory besides ``order``: the (M,) uint64 key, an (M,) uint32 of positions in the cells, the (M,) int64
    permutation, and temporaries of blocks of 2²⁰ rows.
    """
    m = order.shape[0]
    if m < 2:
        return order
    starts = index.starts  # first row of every cell in cell order (repeated for empty cells), then m
    key = np.zeros(m, np.uint64)
    key[starts[(starts > 0) & (starts < m)]] = 1
    np.cumsum(key, out=key)  # the cell's rank among the occupied cells, per sorted row
    key <<= np.uint64(24)
    inv = np.float32(1.0 / index.cell)
    fine = np.empty(m, np.uint32)
    for a in range(0, m, _CHUNK):  # a block of rows at a time: the temporaries stay block-sized
        q = []
        for k in range(3):  # position inside the cell (cells lie on a fixed lattice), quantised, in file order
            u = points[a:a + _CHUNK, k] * inv
            u -= np.floor(u)
            u *= np.float32(256.0)
            q.append(np.minimum(u, np.float32(255.0)).astype(np.uint8))
        fine[a:a + _CHUNK] = interleave_bytes(tuple(q))
    for a in range(0, m, _CHUNK):
        key[a:a + _CHUNK] |= fine.take(order[a:a + _CHUNK])
    del fine
    sub = np.argsort(key, kind="stable")  # already sorted by cell: a nearly sorted pass
    key.sort(kind="stable")  # in place (the same order as key.take(sub), without a second (M,) copy)
    dup = np.flatnonzero(key[1:] == key[:-1])
    if dup.size:  # (nearly) coincident landmarks: by coordinates, then weight, within their groups
        sel = np.union1d(dup, dup + 1)
        rows = order.take(sub[sel])
        p = points.take(rows, axis=0)
        sub[sel] = sub[sel][np.lexsort((weights.take(rows), p[:, 2], p[:, 1], p[:, 0], key[sel]))]
    del key
    return order.take(sub)


def _concat_clouds(clouds: list[LandmarkCloud]) -> LandmarkCloud:
    points = np.concatenate([c.points for c in clouds])
    weights = np.concatenate([c.weights for c in clouds])
    directions = None
    if any(c.directions is not None for c in clouds):
        directions = np.concatenate([
            c.directions if c.directions is not None else np.zeros((len(c), 3), POINT_DTYPE) for c in clouds
        ])
    return LandmarkCloud(points, weights, directions)


def load_map_store(
    path: str | Path,
    *,
    weight_property: str | None = None,
    occlusion_voxel: float | None = None,
    occupancy_file: str | Path | None = None,
    allow_empty: bool = False,
    index_cell: float = DEFAULT_INDEX_CELL,
    cell_cap: int | None = None,
) -> MapStore:
    """Load a map file into the ``base`` layer of a new :class:`MapStore`.

    occlusion_voxel [m] enables the occupancy grid, built from ``occupancy_file`` (any landmark map
    format) when given, else from the map itself. cell_cap: see :class:`MapStore`.
    """
    if occupancy_file is not None and occlusion_voxel is None:
        raise InputError(f"{occupancy_file}: an occupancy file needs an occlusion voxel size")
    if occlusion_voxel is not None and not occlusion_voxel > 0:
        raise InputError(f"occlusion voxel must be > 0 m, got {occlusion_voxel}")
    occ_points = None
    if occupancy_file is not None:
        occ_points = load_landmarks(occupancy_file).points
    cloud = load_landmarks(path, weight_property=weight_property, allow_empty=allow_empty)
    store = MapStore(occupancy_voxel=occlusion_voxel, occupancy_points=occ_points, index_cell=index_cell,
                     cell_cap=cell_cap)
    store.set_layer(BASE_LAYER, cloud)
    return store
