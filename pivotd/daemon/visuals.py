"""The daemon's live markers and camera TF (``ros`` config section) on its bus."""

from __future__ import annotations

from pivotd.bus.markers import MarkerStyle, PlanVisuals
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import resolve_topic
from pivotd.config import Config


def build_plan_visuals(bus: PivotBus, cfg: Config) -> PlanVisuals | None:
    """The visuals ``cfg.ros`` asks for on ``bus`` (None when markers and TF are both off)."""
    r = cfg.ros
    if not r.markers and not r.tf:
        return None
    style = MarkerStyle(fov=cfg.pivot.fov, range=r.marker_range, arrow_length=r.marker_arrow_length,
                        max_landmarks=r.marker_landmarks)
    ns = cfg.topics.namespace
    return PlanVisuals(bus, style, cfg.gimbal.mount, cfg.gimbal.limits, cfg.topics.frame_id or "map",
                       resolve_topic(r.markers_topic, ns) if r.markers else None,
                       resolve_topic(r.tf_topic, ns) if r.tf else None, r.camera_frame)
