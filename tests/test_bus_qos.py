"""QoS settings: names <-> rmw values, the config's ``ros`` section, one-line errors naming the key."""

import pytest
import yaml

from pivotd.bus import qos as q
from pivotd.bus.ros import qos_to_keyexpr
from pivotd.config import load_config
from pivotd.errors import ConfigError


def _load(tmp_path, ros: dict):
    path = tmp_path / "p.yaml"
    path.write_text(yaml.safe_dump({"map": {"allow_empty": True}, "ros": ros}))
    return load_config(path)


def test_named_profiles_round_trip_and_give_rmw_values():
    p = q.QoS.named("best_effort", "transient_local", 5)
    assert (p.reliability, p.durability, p.history, p.depth) == (2, 1, 1, 5)
    assert p.transient_local and not p.reliable
    assert p.names() == ("best_effort", "transient_local", 5)
    assert qos_to_keyexpr(p) == "2:1:,5:,:,:,,"
    with pytest.raises(ConfigError, match="durability"):
        q.QoS.named(durability="transient")
    with pytest.raises(ConfigError, match="depth"):
        q.QoS.named(depth=0)


def test_ros_section_sets_per_topic_qos(tmp_path):
    cfg = _load(tmp_path, {"tf": True, "camera_frame": "cam_optical",
                           "qos": {"landmarks": {"durability": "volatile", "depth": 3},
                                   "pose": {"reliability": "best_effort"}}})
    assert cfg.ros.tf and cfg.ros.camera_frame == "cam_optical"
    assert cfg.ros.qos.landmarks == q.QoS(depth=3)
    assert cfg.ros.qos.pose == q.QoS(reliability=q.RELIABILITY_BEST_EFFORT, depth=10)
    assert cfg.ros.qos.path.transient_local  # untouched topics keep their defaults


@pytest.mark.parametrize(("ros", "key"), [
    ({"qos": {"path": {"durability": "latched"}}}, "ros.qos.path.durability"),
    ({"qos": {"view_plan": {"depth": 0}}}, "ros.qos.view_plan.depth"),
    ({"qos": {"odometry": {}}}, "ros.qos.odometry"),
    ({"qos": {"tf": {"history": "keep_all"}}}, "ros.qos.tf.history"),
    ({"marker_landmarks": 501}, "ros.marker_landmarks"),
    ({"markers_topic": "pivot markers"}, "ros.markers_topic"),
    ({"tf": "yes"}, "ros.tf"),
])
def test_bad_ros_settings_name_file_line_and_key(tmp_path, ros, key):
    with pytest.raises(ConfigError) as err:
        _load(tmp_path, ros)
    text = str(err.value)
    assert "p.yaml:" in text and key in text and "\n" not in text
