"""Live RViz2/Foxglove markers of the view plan (``visualization_msgs/MarkerArray``) and the camera TF.

One :class:`MarkerArray` per replan, in the map frame, namespaces:

* ``fov_cone`` (LINE_LIST): the camera's cone at the first waypoint: apex at the camera centre,
  :data:`CONE_GENERATORS` generators at exactly half the full opening ``fov`` from the planned axis,
  each ``range`` m long, and the rim circle joining their ends;
* ``plan`` (ARROW, one per horizon waypoint): from each camera position, ``arrow_length`` m along the
  planned viewing direction;
* ``in_view`` (SPHERE_LIST): landmarks inside the first cone (at most ``max_landmarks``);
* ``reach`` (LINE_LIST): the boundary of the directions the joint limits allow at the first waypoint,
  drawn on the sphere of radius ``range`` around the camera (two circles for a continuous pan).

The array starts with a DELETEALL marker, so markers of a longer previous horizon do not linger.
``geometry_msgs/TransformStamped`` in a ``tf2_msgs/TFMessage`` gives the camera's pose (ROS optical
frame: +z the viewing direction, x right, y down) for robots without another source.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from pivotd.bus.marker_cdr import MarkerSpec, encode_marker_array
from pivotd.bus.messages import encode_transforms, seconds_to_stamp, view_plan_quats
from pivotd.bus.topics import TF_MESSAGE
from pivotd.geometry import optical_frame_from_direction, pan_tilt_to_direction
from pivotd.gimbal.kinematics import JointLimits, Mount, base_from_world

if TYPE_CHECKING:
    from pivotd.bus.pivot_bus import PivotBus

MARKER_ARRAY = "visualization_msgs/msg/MarkerArray"
CONE_GENERATORS = 32
REACH_SAMPLES = 48  # points per edge of the joint-limit boundary
ARROW, LINE_LIST, SPHERE_LIST, DELETEALL, ADD = 0, 5, 7, 3, 0
NAMESPACES = ("fov_cone", "plan", "in_view", "reach")


@dataclass(frozen=True)
class MarkerStyle:
    """Sizes of the markers: ``fov`` full cone opening [rad]; ``range`` cone generator length and reach
    sphere radius [m]; ``arrow_length`` [m]; ``max_landmarks`` highlighted at most; ``lifetime`` [s] (0:
    until replaced)."""

    fov: float
    range: float = 3.0
    arrow_length: float = 1.0
    max_landmarks: int = 200
    lifetime: float = 0.0
    line_width: float = 0.02
    landmark_size: float = 0.08


def cone_lines(apex: np.ndarray, axis: np.ndarray, half_angle: float, length: float,
               generators: int = CONE_GENERATORS) -> np.ndarray:
    """LINE_LIST points (4·generators, 3) [m]: apex→rim generators, then the rim segments."""
    R = optical_frame_from_direction(np.asarray(axis, float))
    phi = np.linspace(0.0, 2.0 * np.pi, generators, endpoint=False)
    radial = np.cos(phi)[:, None] * R[:, 0] + np.sin(phi)[:, None] * R[:, 1]
    rim = apex + length * (np.cos(half_angle) * R[:, 2] + np.sin(half_angle) * radial)
    apexes = np.repeat(np.asarray(apex, float)[None, :], generators, axis=0)
    spokes = np.stack([apexes, rim], axis=1).reshape(-1, 3)
    ring = np.stack([rim, np.roll(rim, -1, axis=0)], axis=1).reshape(-1, 3)
    return np.vstack([spokes, ring])


def reach_directions(body_quat: np.ndarray, mount: Mount, limits: JointLimits,
                     samples: int = REACH_SAMPLES) -> np.ndarray:
    """World unit directions (M, 2, 3) of the segments of the joint-limit boundary for body attitude
    ``body_quat`` (x, y, z, w): the pan/tilt rectangle's edges, or the two tilt circles for a continuous pan."""
    if limits.continuous_pan:
        pan = np.linspace(-np.pi, np.pi, 2 * samples + 1)
        loops = [(pan, np.full_like(pan, limits.tilt_min)), (pan, np.full_like(pan, limits.tilt_max))]
    else:
        p = np.linspace(limits.pan_min, limits.pan_max, samples)
        t = np.linspace(limits.tilt_min, limits.tilt_max, samples)
        pan = np.concatenate([p, np.full(samples, limits.pan_max), p[::-1], np.full(samples, limits.pan_min)])
        tilt = np.concatenate([np.full(samples, limits.tilt_min), t, np.full(samples, limits.tilt_max), t[::-1]])
        loops = [(pan, tilt)]
    world_from_base = base_from_world(np.asarray(body_quat, float), mount).T
    segs = []
    for pan_l, tilt_l in loops:
        d = pan_tilt_to_direction(pan_l, tilt_l) @ world_from_base.T
        segs.append(np.stack([d[:-1], d[1:]], axis=1))
    return np.concatenate(segs, axis=0)


def plan_marker_specs(style: MarkerStyle, positions: np.ndarray, directions: np.ndarray,
                      in_view: np.ndarray | None = None, reach: np.ndarray | None = None) -> list[MarkerSpec]:
    """The markers of a view plan (see the module docstring): camera positions (N, 3) [m], unit directions
    (N, 3), landmarks in the first cone (K, 3) [m] (the first ``style.max_landmarks`` are drawn), reach
    segments (M, 2, 3) unit world directions (:func:`reach_directions`) or None."""
    positions = np.asarray(positions, float).reshape(-1, 3)
    directions = np.asarray(directions, float).reshape(-1, 3)
    if positions.shape != directions.shape or positions.shape[0] == 0:
        raise ValueError(f"markers need as many directions as positions (≥ 1): {positions.shape} vs {directions.shape}")
    w, life = style.line_width, style.lifetime
    cam, axis = positions[0], directions[0]
    specs = [MarkerSpec("", 0, ARROW, DELETEALL, (1.0, 1.0, 1.0), (0.0, 0.0, 0.0, 0.0), np.zeros((0, 3))),
             MarkerSpec("fov_cone", 0, LINE_LIST, ADD, (w, 0.0, 0.0), (0.1, 0.9, 0.2, 0.8),
                        cone_lines(cam, axis, 0.5 * style.fov, style.range), life)]
    shaft = 2.0 * w
    last = max(1, positions.shape[0] - 1)
    for i, (p, d) in enumerate(zip(positions, directions, strict=True)):
        specs.append(MarkerSpec("plan", i, ARROW, ADD, (shaft, 2.0 * shaft, 3.0 * shaft),
                                (0.2, 0.4 + 0.4 * i / last, 1.0, 0.9), np.stack([p, p + style.arrow_length * d]), life))
    if in_view is not None:
        pts = np.asarray(in_view, float).reshape(-1, 3)[: style.max_landmarks]
        s = style.landmark_size
        specs.append(MarkerSpec("in_view", 0, SPHERE_LIST, ADD, (s, s, s), (1.0, 0.85, 0.1, 1.0), pts, life))
    if reach is not None:
        seg = cam + style.range * np.asarray(reach, float).reshape(-1, 3)
        specs.append(MarkerSpec("reach", 0, LINE_LIST, ADD, (w, 0.0, 0.0), (0.6, 0.6, 0.6, 0.6), seg, life))
    return specs


def encode_plan_markers(stamp: float, frame_id: str, style: MarkerStyle, positions: np.ndarray,
                        directions: np.ndarray, in_view: np.ndarray | None = None,
                        reach: np.ndarray | None = None) -> bytes:
    """MarkerArray CDR of a view plan (:func:`plan_marker_specs`), stamped ``stamp`` [s] in ``frame_id``."""
    t = seconds_to_stamp(stamp)
    return encode_marker_array(t.sec, t.nanosec, frame_id, plan_marker_specs(style, positions, directions, in_view,
                                                                             reach))


def encode_camera_tf(stamp: float, parent_frame: str, child_frame: str, position: np.ndarray,
                     direction: np.ndarray) -> bytes:
    """tf2_msgs/TFMessage CDR with one TransformStamped: camera centre ``position`` (3,) [m] in the parent frame,
    orientation whose +z is ``direction`` (3,) (ROS optical frame, image up kept near world +z)."""
    q = view_plan_quats(np.asarray(direction, float).reshape(1, 3))[0]
    return encode_transforms([(stamp, parent_frame, child_frame, np.asarray(position, float).reshape(3), q)])


class PlanVisuals:
    """Publishes each plan's markers (and, when enabled, the camera TF) through a :class:`PivotBus`."""

    def __init__(self, bus: PivotBus, style: MarkerStyle, mount: Mount, limits: JointLimits, frame_id: str,
                 markers_topic: str | None, tf_topic: str | None, camera_frame: str) -> None:
        self.bus, self.style, self.mount, self.limits = bus, style, mount, limits
        self.frame_id, self.camera_frame = frame_id, camera_frame
        qos = bus.qos
        self.marker_publisher = bus.add_publisher(markers_topic, MARKER_ARRAY, qos.markers) if markers_topic else None
        self.tf_publisher = bus.add_publisher(tf_topic, TF_MESSAGE, qos.tf) if tf_topic else None

    def publish(self, stamp: float, positions: np.ndarray, directions: np.ndarray, body_quat: np.ndarray,
                in_view: np.ndarray | None = None, camera_direction: np.ndarray | None = None) -> None:
        """Markers of a plan (camera positions (N, 3) [m], unit directions (N, 3), body attitude (4,) (x, y, z, w)
        at the first waypoint, landmarks in the first cone (K, 3) [m]); the TF of the camera at the first
        position looking along ``camera_direction`` (world unit (3,), e.g. the measured one) or the first
        planned direction."""
        if self.marker_publisher is not None:
            reach = reach_directions(body_quat, self.mount, self.limits)
            self.bus.put(self.marker_publisher, encode_plan_markers(
                stamp, self.frame_id, self.style, positions, directions, in_view, reach))
        if self.tf_publisher is not None:
            direction = np.asarray(directions, float).reshape(-1, 3)[0] if camera_direction is None else (
                camera_direction)
            self.bus.put(self.tf_publisher, encode_camera_tf(stamp, self.frame_id, self.camera_frame,
                                                             np.asarray(positions, float).reshape(-1, 3)[0],
                                                             direction))
