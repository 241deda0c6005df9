"""The TF tree: composing a pose through a chain of frames, and what it refuses (pure, no bus)."""

import itertools

import numpy as np
import pytest

from pivotd.bus.tf_tree import ComposedPose, Rejection, TfDrop, TfTree, TransformRecord
from pivotd.geometry import matrix_to_quat, quat_to_matrix

ID = np.array([0.0, 0.0, 0.0, 1.0])


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([0.0, 0.0, np.sin(yaw / 2), np.cos(yaw / 2)])


def rec(parent, child, stamp=0.0, xyz=(0.0, 0.0, 0.0), quat=ID, rx=None, static=False, source="a"):
    return TransformRecord(parent, child, stamp, np.asarray(xyz, float), np.asarray(quat, float),
                           stamp if rx is None else rx, static, source)


def pose(tree: TfTree, now: float, timeout: float = 0.5, target="map", source="base_link") -> ComposedPose:
    got = tree.lookup(target, source, now, timeout)
    assert isinstance(got, ComposedPose), got
    return got


def test_two_link_chain_composes_the_map_pose():
    tree = TfTree()
    assert tree.add(rec("map", "odom", 1.0, (10.0, 5.0, 0.0), yaw_quat(np.pi / 2))) is None
    assert tree.add(rec("odom", "base_link", 1.0, (2.0, 0.0, 0.0), yaw_quat(np.pi / 4))) is None
    p = pose(tree, 1.0)
    assert p.frames == ("map", "odom", "base_link")
    np.testing.assert_allclose(p.position, [10.0, 7.0, 0.0], atol=1e-12)  # odom's x is map's y
    np.testing.assert_allclose(quat_to_matrix(p.quat), quat_to_matrix(yaw_quat(3 * np.pi / 4)), atol=1e-12)


def test_chain_through_a_common_ancestor_inverts_the_upper_side():
    """map is not an ancestor of base_link: both hang off 'world'; the pose goes up one side and down the other."""
    tree = TfTree()
    tree.add(rec("world", "map", 0.0, (1.0, 0.0, 0.0), yaw_quat(np.pi)))
    tree.add(rec("world", "odom", 0.0, (0.0, 2.0, 0.0)))
    tree.add(rec("odom", "base_link", 0.0, (0.0, 1.0, 0.0)))
    p = pose(tree, 0.0)
    assert p.frames == ("map", "world", "odom", "base_link")
    # base_link at world (0, 3, 0); map origin at (1, 0, 0) turned by pi: x_map = -(0 - 1) = 1, y_map = -3
    np.testing.assert_allclose(p.position, [1.0, -3.0, 0.0], atol=1e-12)
    np.testing.assert_allclose(quat_to_matrix(p.quat), quat_to_matrix(yaw_quat(-np.pi)), atol=1e-12)


def test_newest_transform_of_each_link_and_the_oldest_stamp():
    tree = TfTree()
    tree.add(rec("map", "odom", 5.0, (1.0, 0.0, 0.0)))
    for k in range(10):
        tree.add(rec("odom", "base_link", 5.0 + 0.01 * k, (0.1 * k, 0.0, 0.0)))
    tree.add(rec("odom", "base_link", 5.02, (99.0, 0.0, 0.0)))  # arrives late and out of order: not the newest
    p = pose(tree, 5.1)
    np.testing.assert_allclose(p.position, [1.9, 0.0, 0.0])
    assert p.stamp == pytest.approx(5.0)  # map -> odom is the oldest link
    assert p.oldest_rx == pytest.approx(5.0)


def test_a_stale_dynamic_link_makes_the_pose_stale_a_static_one_never():
    tree = TfTree()
    tree.add(rec("map", "odom", 1.0))
    tree.add(rec("odom", "base_link", 3.0))
    got = tree.lookup("map", "base_link", 3.0, 0.5)
    assert isinstance(got, Rejection) and got.reason is TfDrop.STALE
    assert "map -> odom" in got.message and tree.counts["stale"] == 1
    tree.add(rec("map", "odom", 1.0, rx=3.0, static=True, source="b"))  # reparent-free: same parent, now static
    p = pose(tree, 100.0, timeout=1000.0)
    assert p.stamp == 3.0  # the static link's stamp is not the oldest: it does not age
    got = tree.lookup("map", "base_link", 100.0, 0.5)
    assert isinstance(got, Rejection) and "odom -> base_link" in got.message


def test_static_chain_only_is_never_stale():
    tree = TfTree()
    tree.add(rec("map", "base_link", 7.0, (1.0, 2.0, 3.0), static=True))
    p = pose(tree, 1e6)
    assert p.stamp == 7.0 and p.oldest_rx == float("inf")


def test_missing_link_names_the_frames():
    tree = TfTree()
    tree.add(rec("odom", "base_link", 0.0))
    got = tree.lookup("map", "base_link", 0.0, 1.0)
    assert isinstance(got, Rejection) and got.reason is TfDrop.MISSING_LINK
    assert "'base_link' reaches up to 'odom'" in got.message and tree.counts["missing_link"] == 1


def test_loop_is_dropped():
    tree = TfTree()
    tree.add(rec("map", "odom"))
    tree.add(rec("odom", "base_link"))
    got = tree.add(rec("base_link", "map"))
    assert isinstance(got, Rejection) and got.reason is TfDrop.LOOP
    assert "'base_link' -> 'map'" in got.message
    assert tree.add(rec("odom", "odom")).reason is TfDrop.LOOP  # a frame its own parent
    assert tree.counts["loop"] == 2 and tree.parent_of("map") is None
    np.testing.assert_allclose(pose(tree, 0.0).position, 0.0)


def test_reparenting_onto_a_descendant_is_a_loop():
    tree = TfTree()
    tree.add(rec("map", "odom"))
    tree.add(rec("odom", "base_link"))
    assert tree.add(rec("base_link", "odom")).reason is TfDrop.LOOP  # same publisher, but a loop
    assert tree.parent_of("odom") == "map"


def test_two_parents_from_different_publishers_is_an_error():
    tree = TfTree()
    tree.add(rec("map", "odom", 0.0, (1.0, 0.0, 0.0), source="slam"))
    tree.add(rec("odom", "base_link", 0.0, source="odometry"))
    got = tree.add(rec("world", "odom", 0.1, (5.0, 0.0, 0.0), source="other"))
    assert isinstance(got, Rejection) and got.reason is TfDrop.TWO_PARENTS
    assert "'odom' has two parents: 'map' and 'world'" in got.message
    assert tree.parent_of("odom") == "map" and tree.counts["two_parents"] == 1
    np.testing.assert_allclose(pose(tree, 0.1).position, [1.0, 0.0, 0.0])


def test_reparenting_by_the_same_publisher_or_after_the_old_link_went_quiet():
    tree = TfTree(parent_timeout=1.0)
    tree.add(rec("map", "odom", 0.0, (1.0, 0.0, 0.0), source="slam"))
    tree.add(rec("odom", "base_link", 0.0, source="odo"))
    # the same publisher re-attaches odom: accepted, the old link is gone
    assert tree.add(rec("world", "odom", 0.5, (2.0, 0.0, 0.0), source="slam")) is None
    assert tree.parent_of("odom") == "world" and tree.counts["reparented"] == 1
    assert isinstance(tree.lookup("map", "base_link", 0.5, 1.0), Rejection)
    # another publisher takes odom over once the link has been quiet for longer than parent_timeout
    assert tree.add(rec("map", "odom", 1.2, (3.0, 0.0, 0.0), source="amcl")).reason is TfDrop.TWO_PARENTS
    assert tree.add(rec("map", "odom", 1.6, (3.0, 0.0, 0.0), source="amcl")) is None
    assert tree.parent_of("odom") == "map" and tree.counts["reparented"] == 2
    tree.add(rec("odom", "base_link", 1.6, source="odo"))
    np.testing.assert_allclose(pose(tree, 1.6).position, [3.0, 0.0, 0.0])


def test_a_static_parent_is_never_taken_over_by_another_publisher():
    tree = TfTree(parent_timeout=1.0)
    tree.add(rec("base_link", "camera", 0.0, static=True, source="rsp"))
    assert tree.add(rec("map", "camera", 100.0, source="other")).reason is TfDrop.TWO_PARENTS


def test_two_parents_in_one_message_drops_both():
    tree = TfTree()
    out = tree.add_all([rec("map", "odom"), rec("world", "odom"), rec("odom", "base_link")])
    assert [r.reason for r in out] == [TfDrop.TWO_PARENTS, TfDrop.TWO_PARENTS]
    assert tree.parent_of("odom") is None and tree.parent_of("base_link") == "odom"


@pytest.mark.parametrize("xyz, quat, reason", [
    ((np.nan, 0.0, 0.0), ID, TfDrop.NONFINITE),
    ((0.0, 0.0, 0.0), (0.0, 0.0, np.inf, 1.0), TfDrop.NONFINITE),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 1.02), TfDrop.NON_UNIT_QUATERNION),
    ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0, 0.0), TfDrop.NON_UNIT_QUATERNION),
    ((2e7, 0.0, 0.0), ID, TfDrop.OUT_OF_RANGE),
])
def test_bad_values_are_dropped(xyz, quat, reason):
    tree = TfTree()
    got = tree.add(rec("map", "base_link", 0.0, xyz, quat))
    assert isinstance(got, Rejection) and got.reason is reason and "'map' -> 'base_link'" in got.message
    assert tree.counts[reason.value] == 1 and tree.frames() == 0


def test_nearly_unit_quaternion_is_normalised():
    tree = TfTree()
    assert tree.add(rec("map", "base_link", 0.0, quat=(0.0, 0.0, 0.0, 1.004))) is None
    np.testing.assert_allclose(pose(tree, 0.0).quat, ID)


def test_empty_frame_and_leading_slash():
    tree = TfTree()
    assert tree.add(rec("", "base_link")).reason is TfDrop.EMPTY_FRAME
    assert tree.add(rec("/map", "/base_link", xyz=(1.0, 0.0, 0.0))) is None
    np.testing.assert_allclose(pose(tree, 0.0).position, [1.0, 0.0, 0.0])


def test_memory_is_bounded_frames_and_buffer():
    tree = TfTree(max_frames=3, depth=4, forget_after=10.0)
    for k in range(100):
        tree.add(rec("odom", "base_link", 0.01 * k))
    assert tree.buffered("base_link") == 4
    tree.add(rec("map", "odom", 0.0))
    tree.add(rec("base_link", "a", 0.0, rx=0.0))
    assert tree.add(rec("base_link", "b", 1.0, rx=1.0)).reason is TfDrop.TOO_MANY_FRAMES
    assert tree.frames() == 3 and tree.counts["too_many_frames"] == 1
    # once a dynamic link has been quiet for forget_after, a new frame takes its place
    tree.add(rec("map", "odom", 20.0, rx=20.0))
    tree.add(rec("odom", "base_link", 20.0, rx=20.0))
    assert tree.add(rec("base_link", "b", 20.0, rx=20.0)) is None
    assert tree.parent_of("a") is None and tree.counts["evicted"] == 1 and tree.frames() == 3


def test_clock_jump_back_restarts_the_link():
    tree = TfTree()
    tree.add(rec("map", "base_link", 100.0, (1.0, 0.0, 0.0)))
    tree.add(rec("map", "base_link", 2.0, (2.0, 0.0, 0.0), rx=101.0))  # a restarted simulation
    np.testing.assert_allclose(pose(tree, 101.0).position, [2.0, 0.0, 0.0])
    assert tree.counts["jump_back"] == 1


def test_random_chains_match_the_product_of_transforms():
    rng = np.random.default_rng(3)
    for _ in range(20):
        tree = TfTree()
        frames = ["map", "a", "b", "c", "base_link"]
        R, p = np.eye(3), np.zeros(3)
        for parent, child in itertools.pairwise(frames):
            q = rng.normal(size=4)
            q /= np.linalg.norm(q)
            t = rng.normal(size=3)
            tree.add(rec(parent, child, 0.0, t, q))
            Rl = quat_to_matrix(q)
            R, p = R @ Rl, R @ t + p
        got = pose(tree, 0.0)
        np.testing.assert_allclose(got.position, p, atol=1e-9)
        np.testing.assert_allclose(quat_to_matrix(got.quat), R, atol=1e-9)
        assert abs(abs(got.quat @ matrix_to_quat(R)) - 1.0) < 1e-9
