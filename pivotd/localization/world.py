"""What every policy of one run shares: the daemon config, the scene's map and occupancy, the timed route.

The map is loaded into a :class:`MapStore` exactly as the daemon holds it, with the scene's occupancy
and, when the scene knows surface normals, those as observation directions so the planner's view-angle
filter matches the camera's incidence limit. The body pose at any time comes from the route.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, replace

import numpy as np

from pivotd.localization.camera import CameraModel, line_of_sight
from pivotd.localization.scenes import LocScene
from pivotd.localization.stack import (
    BASE_LAYER,
    Config,
    JointLimits,
    LandmarkCloud,
    MapStore,
    Mount,
    OccupancyGrid,
    Polyline,
    camera_position,
)


def bench_config(cfg: Config, scene: LocScene, camera: CameraModel) -> Config:
    """``cfg`` with the map filters set for ``scene``: the camera's depth range, occlusion on at the scene's
    voxel, and the incidence limit as the view-angle filter when the scene knows normals."""
    f = cfg.map.filters
    view = (math.radians(camera.max_incidence_deg)
            if scene.normals is not None and camera.max_incidence_deg is not None else None)
    filters = replace(f, min_range=camera.min_depth, max_range=camera.max_depth, max_view_angle=view,
                      occlusion_voxel=scene.voxel, occupancy_file=None)
    return replace(cfg, map=replace(cfg.map, file=None, allow_empty=True, filters=filters))


@dataclass
class World:
    """Scene, camera and config of one run, with the map store, the occupancy grid and the route."""

    cfg: Config
    scene: LocScene
    camera: CameraModel

    def __post_init__(self) -> None:
        sc = self.scene
        self.cfg = bench_config(self.cfg, sc, self.camera)
        self.grid = OccupancyGrid.from_points(sc.occupancy, sc.voxel)
        self.store = MapStore(occupancy_voxel=sc.voxel, occupancy_points=sc.occupancy)
        pts = sc.landmarks.astype(np.float32)
        dirs = None if sc.normals is None else sc.normals.astype(np.float32)
        self.store.set_layer(BASE_LAYER, LandmarkCloud(pts, np.ones(len(pts), np.float32), dirs))
        self.route = Polyline(sc.route, sc.route_quats)
        self._route_arc = sc.arc
        self._sight: dict[object, np.ndarray] = {}

    @property
    def mount(self) -> Mount:
        """Gimbal base pose on the body (config ``gimbal.mount``)."""
        return self.cfg.gimbal.mount

    @property
    def limits(self) -> JointLimits:
        """Joint ranges (config ``gimbal.limits``)."""
        return self.cfg.gimbal.limits

    def body_poses(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Body positions (K, 3) [m] and attitudes (K, 4) (x, y, z, w) at times ``t`` (K,) [s]."""
        s = np.interp(np.asarray(t, float), self.scene.stamps, self._route_arc)
        return self.route.sample(s)

    def camera_centres(self, positions: np.ndarray, quats: np.ndarray) -> np.ndarray:
        """Camera centres (K, 3) for body poses (K, 3), (K, 4)."""
        return np.array([camera_position(p, q, self.mount) for p, q in zip(positions, quats, strict=True)])

    def sight(self, key: object, centre: np.ndarray) -> np.ndarray:
        """Landmarks in line of sight of ``centre`` (see :func:`camera.line_of_sight`), cached under ``key``
        (the frame number: the camera centre of a frame does not depend on the policy)."""
        out = self._sight.get(key)
        if out is None:
            out = line_of_sight(self.camera, self.grid, centre, self.scene.landmarks, self.scene.normals)
            self._sight[key] = out
        return out
