"""Live markers and camera TF, decoded from a real Zenoh subscriber on loopback and checked geometrically.

The plan comes from the real receding-horizon planner on a hallway scene, with a tilted mount so the
reach boundary and the TF are not trivially axis-aligned.
"""

import math
import queue
from dataclasses import replace

import numpy as np
import pytest
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.markers import (
    MARKER_ARRAY,
    TF_MESSAGE,
    MarkerStyle,
    cone_lines,
    encode_plan_markers,
    reach_directions,
)
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import BusTopics
from pivotd.config import Config
from pivotd.daemon.planner import PlannerSettings, RecedingHorizonPlanner
from pivotd.daemon.visuals import build_plan_visuals
from pivotd.geometry import angle_between, normalize, quat_to_matrix
from pivotd.gimbal.kinematics import JointLimits, Mount, base_from_world, rpy_to_matrix
from pivotd.maps.filters import RetainedFilter
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import MapStore
from pivotd.pivot.scenes import hallway

FOV = math.radians(50.0)
LIMITS = JointLimits(math.radians(-120), math.radians(150), math.radians(-40), math.radians(70), False)
MOUNT = Mount(rotation=rpy_to_matrix(np.array([0.0, math.radians(10), math.radians(5)])),
              translation=np.array([0.2, 0.0, 0.4]))
YAWED = np.array([0.0, 0.0, math.sin(0.15), math.cos(0.15)])


@pytest.fixture(scope="module")
def scene_plan():
    sc = hallway()
    store = MapStore()
    store.set_layer("base", LandmarkCloud(points=sc.points, weights=sc.weights))
    settings = PlannerSettings(fov=FOV, spacing=0.5, horizon=12,
                               retained_filter=RetainedFilter(min_range=0.3, max_range=10.0))
    pl = RecedingHorizonPlanner(settings, MOUNT, LIMITS)
    pl.set_path(sc.path, None, 1)
    return sc, pl.replan(store.snapshot(), sc.path[0], YAWED, None)


def _points(marker) -> np.ndarray:
    return np.array([[p.x, p.y, p.z] for p in marker.points]).reshape(-1, 3)


def _receive(topic: str, msgtype: str, publish) -> list:
    """Publish through a PivotBus with visuals on one session; decode what a plain subscriber on another gets."""
    got: queue.Queue = queue.Queue()
    with session_pair() as (a, b, _):
        bus = PivotBus(a, BusTopics())
        sub = b.declare_subscriber(ros.topic_key(0, topic, msgtype, "*"), lambda s: got.put(s.payload.to_bytes()))
        try:
            visuals = publish(bus)
            pub = visuals.marker_publisher if msgtype == MARKER_ARRAY else visuals.tf_publisher
            assert wait_for(pub.matched)
            visuals.publish(*visuals.args)
            return [ros.typestore().deserialize_cdr(p, msgtype) for p in drain(got, 1)]
        finally:
            sub.undeclare()
            bus.close()


def _visuals(scene_plan, tf: bool = False, max_landmarks: int = 200, camera_direction=None):
    _, plan = scene_plan

    def make(bus):
        cfg = replace(Config(), ros=replace(Config().ros, tf=tf, marker_landmarks=max_landmarks, marker_range=2.5),
                      pivot=replace(Config().pivot, fov=FOV),
                      gimbal=replace(Config().gimbal, mount=MOUNT, limits=LIMITS))
        v = build_plan_visuals(bus, cfg)
        v.args = (12.5, plan.positions, plan.directions, plan.body_quats[0], plan.in_view, camera_direction)
        return v

    return make


def test_marker_array_geometry_matches_the_plan(scene_plan):
    sc, plan = scene_plan
    [msg] = _receive("/pivot/markers", MARKER_ARRAY, _visuals(scene_plan))
    by_ns: dict[str, list] = {}
    for mk in msg.markers:
        by_ns.setdefault(mk.ns, []).append(mk)
    assert msg.markers[0].action == 3  # DELETEALL first
    assert all(mk.header.frame_id == "map" and mk.header.stamp.sec == 12 for mk in msg.markers)

    # The cone: apex at the camera, every generator at exactly half the opening from the planned axis.
    [cone] = by_ns["fov_cone"]
    pts = _points(cone)
    spokes = pts[: pts.shape[0] // 2].reshape(-1, 2, 3)
    cam, axis = plan.positions[0], plan.directions[0]
    np.testing.assert_allclose(spokes[:, 0], np.repeat(cam[None], spokes.shape[0], 0), atol=1e-12)
    gen = spokes[:, 1] - cam
    np.testing.assert_allclose(angle_between(gen, np.repeat(axis[None], gen.shape[0], 0)), FOV / 2, atol=1e-9)
    np.testing.assert_allclose(np.linalg.norm(gen, axis=1), 2.5, atol=1e-9)
    # generators spread all around the axis (not a fan on one side)
    assert np.linalg.norm(normalize(gen).mean(axis=0) - math.cos(FOV / 2) * axis) < 1e-9

    # Arrows: one per waypoint, from the camera position along the planned direction.
    arrows = sorted(by_ns["plan"], key=lambda mk: mk.id)
    assert len(arrows) == plan.positions.shape[0] == 12
    for mk, p, d in zip(arrows, plan.positions, plan.directions, strict=True):
        a, b = _points(mk)
        np.testing.assert_allclose(a, p, atol=1e-12)
        np.testing.assert_allclose(b - a, 1.0 * d, atol=1e-12)

    # Highlighted landmarks: inside the first cone; the bounded count of in-cone landmarks within the retained
    # range nearest the axis (brute force over the whole map).
    [hl] = by_ns["in_view"]
    shown = _points(hl)
    shown_angle = angle_between(shown - cam, np.repeat(axis[None], shown.shape[0], 0))
    assert np.all(shown_angle <= FOV / 2 + 1e-9)
    rel = sc.points - cam
    dist = np.linalg.norm(rel, axis=1)
    angle = angle_between(rel, np.repeat(axis[None], rel.shape[0], 0))
    inside = (angle <= FOV / 2) & (dist >= 0.3) & (dist <= 10.0)
    assert int(plan.visible[0]) == int(inside.sum()) > 200  # the plan's hard count is the brute-force count
    assert shown.shape[0] == 200
    assert shown_angle.max() <= np.sort(angle[inside])[199] + 1e-6  # float32 bearings: ties within 1e-7 rad
    nearest = np.linalg.norm(shown[:, None, :] - sc.points[inside][None, :, :], axis=2).min(axis=1)
    assert nearest.max() < 1e-5  # map landmarks (stored as float32), not made-up points

    # Reach: on the sphere of the marker range; in the gimbal base frame every point is on the limit rectangle.
    [reach] = by_ns["reach"]
    r = _points(reach) - cam
    np.testing.assert_allclose(np.linalg.norm(r, axis=1), 2.5, atol=1e-9)
    d_base = normalize(r) @ base_from_world(plan.body_quats[0], MOUNT).T
    pan, tilt = np.arctan2(d_base[:, 1], d_base[:, 0]), -np.arcsin(np.clip(d_base[:, 2], -1, 1))
    on_pan = np.isclose(pan, LIMITS.pan_min, atol=1e-9) | np.isclose(pan, LIMITS.pan_max, atol=1e-9)
    on_tilt = np.isclose(tilt, LIMITS.tilt_min, atol=1e-9) | np.isclose(tilt, LIMITS.tilt_max, atol=1e-9)
    assert np.all(on_pan | on_tilt)
    assert on_pan.any() and on_tilt.any()
    assert np.all((pan >= LIMITS.pan_min - 1e-9) & (pan <= LIMITS.pan_max + 1e-9))


def test_highlighted_landmarks_are_bounded_and_nearest_the_axis_first(scene_plan):
    _, plan = scene_plan
    [msg] = _receive("/pivot/markers", MARKER_ARRAY, _visuals(scene_plan, max_landmarks=4))
    [hl] = [mk for mk in msg.markers if mk.ns == "in_view"]
    shown = _points(hl)
    cam, axis = plan.positions[0], plan.directions[0]
    assert shown.shape[0] == 4
    ang_all = angle_between(plan.in_view - cam, np.repeat(axis[None], plan.in_view.shape[0], 0))
    ang = angle_between(shown - cam, np.repeat(axis[None], 4, 0))
    assert np.all(np.diff(ang) >= -1e-12) and ang[-1] <= np.sort(ang_all)[3] + 1e-12


def test_camera_tf_is_off_by_default_and_points_the_optical_axis(scene_plan):
    assert Config().ros.tf is False
    _, plan = scene_plan
    measured = normalize(np.array([0.3, 0.9, -0.1]))
    [msg] = _receive("/tf", TF_MESSAGE, _visuals(scene_plan, tf=True, camera_direction=measured))
    [tf] = msg.transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("map", "pivot_camera")
    t, q = tf.transform.translation, tf.transform.rotation
    np.testing.assert_allclose([t.x, t.y, t.z], plan.positions[0], atol=1e-12)
    R = quat_to_matrix(np.array([q.x, q.y, q.z, q.w]))
    np.testing.assert_allclose(R[:, 2], measured, atol=1e-9)  # optical +z along the viewing direction
    assert R[2, 1] < 0  # image down (+y) points down in the world


def test_cone_lines_and_reach_for_a_continuous_pan():
    pts = cone_lines(np.zeros(3), np.array([0, 0, 1.0]), math.radians(30), 1.0, generators=8)
    assert pts.shape == (32, 3)
    np.testing.assert_allclose(pts[1::2][:8, 2], math.cos(math.radians(30)), atol=1e-12)
    cont = JointLimits(tilt_min=math.radians(-20), tilt_max=math.radians(45), continuous_pan=True)
    segs = reach_directions(np.array([0, 0, 0, 1.0]), Mount(), cont)
    tilt = -np.degrees(np.arcsin(segs.reshape(-1, 3)[:, 2]))
    assert set(np.round(tilt, 9)) == {-20.0, 45.0}


def test_encoder_refuses_mismatched_plans():
    with pytest.raises(ValueError, match="directions"):
        encode_plan_markers(0.0, "map", MarkerStyle(fov=1.0), np.zeros((2, 3)), np.zeros((3, 3)))


def test_markers_can_be_turned_off():
    with session_pair() as (a, _, __):
        bus = PivotBus(a, BusTopics())
        try:
            cfg = replace(Config(), ros=replace(Config().ros, markers=False))
            assert build_plan_visuals(bus, cfg) is None
            v = build_plan_visuals(bus, replace(cfg, ros=replace(cfg.ros, tf=True)))
            assert v.marker_publisher is None and v.tf_publisher is not None
        finally:
            bus.close()


def test_view_plan_path_and_markers_agree(scene_plan):
    """The Path's orientations (+z) and the arrows show the same directions (one source of truth)."""
    _, plan = scene_plan
    path = ros.typestore().deserialize_cdr(m.encode_view_plan(1.0, "map", plan.positions, plan.directions), m.PATH)
    z = np.array([quat_to_matrix(np.array([p.pose.orientation.x, p.pose.orientation.y, p.pose.orientation.z,
                                           p.pose.orientation.w]))[:, 2] for p in path.poses])
    np.testing.assert_allclose(z, plan.directions, atol=1e-9)


def test_in_cone_selection_matches_brute_force():
    from pivotd.pivot.visibility import hard_count, in_cone

    rng = np.random.default_rng(3)
    for _ in range(50):
        b = normalize(rng.normal(size=(int(rng.integers(0, 300)), 3)))
        c = normalize(rng.normal(size=3))
        alpha = float(rng.uniform(0.05, 1.5))
        limit = int(rng.integers(0, 40))
        idx = in_cone(c, b, alpha, limit)
        cos = b @ c if b.size else np.zeros(0)
        ref = np.argsort(-cos, kind="stable")[: min(limit, hard_count(c, b, alpha))]
        assert len(idx) == len(ref) == min(limit, hard_count(c, b, alpha))
        np.testing.assert_allclose(cos[idx], cos[ref], atol=0)


def test_fast_marker_encoder_is_byte_identical_to_rosbags(scene_plan):
    from pivotd.bus.marker_cdr import MarkerSpec, encode_marker_array, encode_marker_array_reference
    from pivotd.bus.markers import plan_marker_specs

    _, plan = scene_plan
    specs = plan_marker_specs(MarkerStyle(fov=FOV, lifetime=0.75), plan.positions, plan.directions, plan.in_view,
                              reach_directions(plan.body_quats[0], MOUNT, LIMITS))
    assert encode_marker_array(12, 5, "map", specs) == encode_marker_array_reference(12, 5, "map", specs)
    rng = np.random.default_rng(11)
    for trial in range(30):  # odd string lengths and point counts exercise every alignment case
        specs = [MarkerSpec("n" * int(rng.integers(0, 7)), int(rng.integers(-5, 5)), int(rng.integers(0, 12)),
                            int(rng.integers(0, 4)), tuple(rng.normal(size=3)), tuple(rng.uniform(size=4)),
                            rng.normal(size=(int(rng.integers(0, 5)), 3)), float(rng.uniform(0, 3)))
                 for _ in range(int(rng.integers(0, 4)))]
        frame = "f" * int(rng.integers(0, 6))
        fast = encode_marker_array(trial, 7 * trial, frame, specs)
        assert fast == encode_marker_array_reference(trial, 7 * trial, frame, specs), trial
