"""Landmark maps: file formats, spatial index, per-waypoint retained sets.

Public entry points: :func:`load_landmarks` (one call for every format), :class:`MapStore` /
:func:`load_map_store` (layered map with lock-free snapshots), :class:`RetainedFilter` and
:func:`retained_for_path` (the landmark set V_i kept at each waypoint).
"""

from pivotd.maps.filters import RetainedFilter, retained_for_path
from pivotd.maps.formats import LandmarkCloud, load_landmarks
from pivotd.maps.occlusion import OccupancyGrid
from pivotd.maps.store import MapSnapshot, MapStore, load_map_store

__all__ = [
    "LandmarkCloud",
    "MapSnapshot",
    "MapStore",
    "OccupancyGrid",
    "RetainedFilter",
    "load_landmarks",
    "load_map_store",
    "retained_for_path",
]
