"""ROS conventions an integrator relies on: URDF joint names in the JointState, ROS_DOMAIN_ID from the
environment, the loaded map latched on the landmarks topic, /diagnostics."""

from __future__ import annotations

import queue
import re
import textwrap
from pathlib import Path

import numpy as np
import pytest
from bus_support import drain, session_pair, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.topics import BusTopics
from pivotd.config import load_config
from pivotd.errors import ConfigError

MINIMAL = "name: ros-node\nmap:\n  allow_empty: true\n"


def write(tmp_path: Path, text: str) -> Path:
    path = tmp_path / "ros.yaml"
    path.write_text(textwrap.dedent(text))
    return path


def load_error(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "\n" not in message
    return message


@pytest.fixture(scope="module")
def sessions():
    with session_pair() as (a, b, _):
        yield a, b


# ---------------------------------------------------------------- joint names
def test_joint_names_default_to_pan_tilt_and_take_the_urdf_names(tmp_path):
    assert load_config(write(tmp_path, MINIMAL)).topics.joint_names == ("pan", "tilt")
    cfg = load_config(write(tmp_path, MINIMAL + "topics:\n  joint_names: [pan_joint, tilt_joint]\n"))
    assert cfg.topics.joint_names == ("pan_joint", "tilt_joint")


@pytest.mark.parametrize(("value", "needle"), [
    ("[pan_joint]", "must be a list of two joint names"),
    ("[a, b, c]", "must be a list of two joint names"),
    ("[pan_joint, pan_joint]", "the two joint names must differ, both are 'pan_joint'"),
    ("['', tilt]", "must be a non-empty joint name"),
    ("[pan, 3]", "must be a string"),
    ("{pan: tilt}", "must be a list of strings"),
])
def test_bad_joint_names_are_one_line_errors_naming_file_line_and_key(tmp_path, value, needle):
    path = write(tmp_path, MINIMAL + f"topics:\n  frame_id: map\n  joint_names: {value}\n")
    message = load_error(path)
    assert re.match(rf"{re.escape(str(path))}:6: topics\.joint_names(\[\d\])?: ", message), message
    assert needle in message, message


def test_joint_states_carry_the_configured_names_over_zenoh(sessions):
    bus = PivotBus(sessions[0], BusTopics(joint_names=("pan_joint", "tilt_joint")))
    got: queue.Queue = queue.Queue()
    sub = sessions[1].declare_subscriber("0/pivot/joint_states/sensor_msgs::msg::dds_::JointState_/*",
                                         lambda s: got.put(s.payload.to_bytes()))
    try:
        assert wait_for(bus.joint_state_publisher.matched)
        bus.publish_joint_state(12.5, 0.25, -0.5, 0.1, 0.0)
        js = ros.typestore().deserialize_cdr(drain(got, 1)[0], m.JOINT_STATE)
        assert list(js.name) == ["pan_joint", "tilt_joint"]
        np.testing.assert_allclose(js.position, [0.25, -0.5])
    finally:
        sub.undeclare()
        bus.close()


# ---------------------------------------------------------------- ROS_DOMAIN_ID
def test_domain_id_unset_takes_ros_domain_id_from_the_environment(tmp_path, monkeypatch):
    path = write(tmp_path, MINIMAL)
    assert load_config(path).topics.domain_id == 0
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert load_config(path).topics.domain_id == 42
    monkeypatch.setenv("ROS_DOMAIN_ID", " 7 ")
    assert load_config(path).topics.domain_id == 7
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id:\n")).topics.domain_id == 7  # null: unset
    monkeypatch.setenv("ROS_DOMAIN_ID", "")  # empty is unset, as for ROS nodes
    assert load_config(path).topics.domain_id == 0


def test_an_explicit_domain_id_wins_over_the_environment(tmp_path, monkeypatch):
    monkeypatch.setenv("ROS_DOMAIN_ID", "42")
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id: 3\n")).topics.domain_id == 3
    monkeypatch.setenv("ROS_DOMAIN_ID", "not-a-number")  # not consulted when the key is set
    assert load_config(write(tmp_path, MINIMAL + "topics:\n  domain_id: 0\n")).topics.domain_id == 0


@pytest.mark.parametrize("value", ["abc", "233", "-1", "1.5", "0x10", "²"])
def test_a_bad_ros_domain_id_is_an_error_naming_the_variable(tmp_path, monkeypatch, value):
    monkeypatch.setenv("ROS_DOMAIN_ID", value)
    path = write(tmp_path, MINIMAL)
    message = load_error(path)
    assert message.startswith(f"{path}: ROS_DOMAIN_ID={value!r} in the environment"), message
    assert "must be an integer in 0..232" in message and "topics.domain_id" in message, message
