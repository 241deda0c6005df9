"""Config loading: shipped files load, every class of error names file, line and key path."""

import math
import re
import textwrap
from dataclasses import replace
from pathlib import Path

import numpy as np
import pytest

from pivotd.bus.topics import BusTopics
from pivotd.config import Config, load_config
from pivotd.errors import ConfigError, InputError

REPO = Path(__file__).resolve().parent.parent
CONFIG_DIR = REPO / "config"

MINIMAL = """\
name: test-node
map:
  allow_empty: true
"""


def write(tmp_path: Path, text: str, name: str = "bad.yaml") -> Path:
    path = tmp_path / name
    path.write_text(textwrap.dedent(text))
    return path


def load_error(tmp_path: Path, text: str) -> str:
    path = write(tmp_path, text)
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "\n" not in message
    assert message.startswith(str(path)), message
    return message


def test_shipped_backend_examples_load():
    mav = load_config(CONFIG_DIR / "gimbal_mavlink.yaml")
    assert (mav.gimbal.backend, mav.gimbal.port, mav.gimbal.mavlink.target_component) == (
        "mavlink", "udpin:0.0.0.0:14550", 1)
    dxl = load_config(CONFIG_DIR / "gimbal_dynamixel.yaml")
    assert (dxl.gimbal.backend, dxl.gimbal.baud, dxl.gimbal.dynamixel.tilt_reversed) == ("dynamixel", 1_000_000, True)
    assert dxl.gimbal.limits.tilt_max == pytest.approx(math.radians(90.0))


def test_shipped_configs_load():
    spot = load_config(CONFIG_DIR / "spot.yaml")
    assert spot.name == "spot" and spot.status_key == "pivot/spot/status"
    assert spot.gimbal.port == "/dev/ttyUSB0"
    assert spot.zenoh.mode == "client" and spot.zenoh.connect == ("tcp/127.0.0.1:7447",)
    assert not spot.zenoh.multicast_scouting
    assert spot.pivot.fov == pytest.approx(math.radians(60.0))
    assert spot.pivot.half_angle == pytest.approx(math.radians(30.0))
    assert spot.gimbal.limits.tilt_min == pytest.approx(math.radians(-45.0))
    assert spot.motion.pan.max_velocity == pytest.approx(math.radians(120.0))
    np.testing.assert_allclose(spot.gimbal.mount.translation, [0.25, 0.0, 0.20])

    demo = load_config(CONFIG_DIR / "demo.yaml")
    assert demo.gimbal.port == "mock://"
    assert demo.zenoh.mode == "peer" and demo.zenoh.listen == ("tcp/127.0.0.1:7457",)
    assert demo.map.file == CONFIG_DIR / "demo_hallway_map.txt"
    assert demo.sim is not None and demo.sim.speed == pytest.approx(0.8)
    assert demo.control.dt == pytest.approx(0.01)


def test_minimal_config_gets_defaults(tmp_path):
    cfg = load_config(write(tmp_path, MINIMAL, "ok.yaml"))
    default = Config(name="test-node")
    assert cfg.name == "test-node"
    assert cfg.topics == default.topics
    assert cfg.pivot == default.pivot
    assert cfg.control == default.control
    assert cfg.gimbal.mount == default.gimbal.mount
    assert cfg.map.file is None and cfg.map.allow_empty
    assert cfg.sim is None
    assert cfg.logging.level == "INFO"


def test_relative_paths_resolve_against_config_directory(tmp_path, monkeypatch):
    sub = tmp_path / "etc"
    sub.mkdir()
    (sub / "maps").mkdir()
    (sub / "maps" / "m.txt").write_text("0 0 0\n1 1 1\n")
    (sub / "zenoh.json5").write_text("{}\n")
    path = write(sub, "map:\n  file: maps/m.txt\nzenoh:\n  config_file: zenoh.json5\n", "pivotd.yaml")
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    cfg = load_config(Path("..") / "etc" / "pivotd.yaml")
    assert cfg.map.file == (sub / "maps" / "m.txt").resolve()
    assert cfg.zenoh.config_file == (sub / "zenoh.json5").resolve()
    assert cfg.source == path.resolve()


@pytest.mark.parametrize(
    ("text", "pattern"),
    [
        # unknown keys, with the line and a suggestion
        (MINIMAL + "pivott:\n  fov_deg: 30\n", r":4: pivott: unknown key; did you mean pivot\?"),
        (
            MINIMAL + "gimbal:\n  limits:\n    pan_maxdeg: 90\n",
            r":6: gimbal\.limits\.pan_maxdeg: unknown key; did you mean pan_max_deg",
        ),
        # wrong types
        (MINIMAL + "pivot:\n  fov_deg: wide\n", r":5: pivot\.fov_deg: must be a number, got str 'wide'"),
        (MINIMAL + "control:\n  rate_hz: true\n", r":5: control\.rate_hz: must be a number, got bool"),
        (MINIMAL + "planner:\n  horizon: 2.5\n", r":5: planner\.horizon: must be an integer"),
        (MINIMAL + "gimbal: [1, 2]\n", r":4: gimbal: must be a mapping, got a list"),
        (MINIMAL + "zenoh:\n  multicast_scouting: 'no'\n", r":5: zenoh\.multicast_scouting: must be true or false"),
        (MINIMAL + "gimbal:\n  mount:\n    xyz: [0, 1]\n", r":6: gimbal\.mount\.xyz: must be a list of 3 numbers"),
        (MINIMAL + "topics:\n  pose: 'odom topic'\n", r":5: topics\.pose: 'odom topic' is not valid"),
        # out of range
        (MINIMAL + "pivot:\n  fov_deg: 180\n", r":5: pivot\.fov_deg: must be < 180, got 180"),
        (MINIMAL + "pivot:\n  lambda: -0.1\n", r":5: pivot\.lambda: must be ≥ 0, got -0\.1"),
        (MINIMAL + "pivot:\n  smooth_knee_deg: 200\n", r":5: pivot\.smooth_knee_deg: must be ≤ 180, got 200"),
        (MINIMAL + "control:\n  rate_hz: 50\n", r":5: control\.rate_hz: must be ≥ 100, got 50"),
        (MINIMAL + "control:\n  tracking_error_deg: 0\n", r":5: control\.tracking_error_deg: must be > 0"),
        (MINIMAL + "control:\n  tracking_error_s: 0.01\n", r":5: control\.tracking_error_s: must be ≥ 0\.02"),
        (MINIMAL + "pivot:\n  fov_deg: .nan\n", r":5: pivot\.fov_deg: must be finite"),
        (MINIMAL + "motion:\n  tilt:\n    max_jerk_deg_s3: 0\n", r":6: motion\.tilt\.max_jerk_deg_s3: must be > 0"),
        (MINIMAL + "topics:\n  pose_type: nav_msgs/msg/Path\n", r":5: topics\.pose_type: must be one of"),
        (MINIMAL + "topics:\n  max_cloud_points: 0\n", r":5: topics\.max_cloud_points: must be ≥ 1, got 0"),
        (MINIMAL + "logging:\n  level: LOUD\n", r":5: logging\.level: must be one of DEBUG"),
        # cross-field rules
        (
            MINIMAL + "gimbal:\n  limits:\n    tilt_min_deg: 10\n    tilt_max_deg: -10\n",
            r":7: gimbal\.limits\.tilt_max_deg: must be > tilt_min_deg \(10\)",
        ),
        (MINIMAL + "gimbal:\n  park:\n    tilt_deg: 95\n", r":6: gimbal\.park\.tilt_deg: must lie within the tilt"),
        (MINIMAL + "gimbal:\n  watchdog_ms: 20\n", r":5: gimbal\.watchdog_ms: must be ≥ 3 control periods \(30 ms"),
        (
            MINIMAL + "map:\n  filters:\n    min_range: 5\n    max_range: 2\n",
            r"duplicate key",
        ),
        (
            "map:\n  allow_empty: true\n  filters:\n    min_range: 5\n    max_range: 2\n",
            r":5: map\.filters\.max_range: must be > min_range \(5\)",
        ),
        (MINIMAL + "zenoh:\n  mode: client\n", r":4: zenoh\.connect: client mode needs a router endpoint"),
        (MINIMAL + "zenoh:\n  connect: [127.0.0.1:7447]\n", r":5: zenoh\.connect\[0\]: expected <protocol>/<address>"),
        (MINIMAL + "zenoh:\n  listen:\n    - tcp/127.0.0.1:99999\n", r":6: zenoh\.listen\[0\]: port must be 0\.\."),
        # missing things
        ("name: x\n", r"bad\.yaml: map\.file: required key is missing \(or set map\.allow_empty: true\)"),
        ("map:\n  file: nowhere.txt\n", r":2: map\.file: file not found: .*nowhere\.txt"),
        # YAML problems
        (MINIMAL + "pivot:\n  fov_deg: [30\n", r":\d+: YAML syntax error"),
        ("- just\n- a list\n", r":1: \(top level\): must be a mapping, got a list"),
        ("name: bad/name\nmap: {allow_empty: true}\n", r":1: name: 'bad/name' is not valid"),
    ],
)
def test_errors_name_file_line_and_key(tmp_path, text, pattern):
    message = load_error(tmp_path, text)
    assert re.search(pattern, message), message


def test_missing_config_file(tmp_path):
    with pytest.raises(ConfigError, match=r"missing\.yaml: no such config file"):
        load_config(tmp_path / "missing.yaml")
    with pytest.raises(ConfigError, match="is a directory"):
        load_config(tmp_path)


def test_empty_file_needs_a_map(tmp_path):
    message = load_error(tmp_path, "")
    assert "map.file: required key is missing" in message


def test_continuous_pan_allows_any_park_pan(tmp_path):
    cfg = load_config(
        write(tmp_path, MINIMAL + "gimbal:\n  limits: {continuous_pan: true}\n  park: {pan_deg: 400}\n", "ok.yaml")
    )
    assert cfg.gimbal.limits.continuous_pan
    assert cfg.gimbal.park_pan == pytest.approx(math.radians(400))


def test_command_line_overrides():
    cfg = load_config(CONFIG_DIR / "spot.yaml")
    out = cfg.with_overrides(port="socket://127.0.0.1:5000", connect=["tcp/10.0.0.2:7447"], listen=["tcp/0.0.0.0:0"])
    assert out.gimbal.port == "socket://127.0.0.1:5000"
    assert out.zenoh.connect == ("tcp/10.0.0.2:7447",) and out.zenoh.listen == ("tcp/0.0.0.0:0",)
    assert cfg.gimbal.port == "/dev/ttyUSB0"  # the original is untouched
    assert cfg.with_overrides() == cfg
    with pytest.raises(InputError, match=r"--connect: 'localhost': expected <protocol>/<address>"):
        cfg.with_overrides(connect=["localhost"])


def test_configs_are_comparable_for_reload():
    a = load_config(CONFIG_DIR / "demo.yaml")
    b = load_config(CONFIG_DIR / "demo.yaml")
    assert a == b
    assert a != load_config(CONFIG_DIR / "spot.yaml")


def test_exponent_numbers_are_numbers(tmp_path):
    """PyYAML (YAML 1.1) reads 1e3 as a string; the config accepts it as YAML 1.2 does."""
    text = MINIMAL + "motion:\n  pan: {max_jerk_deg_s3: 1e3}\ntopics: {max_cloud_points: 2e5}\n"
    cfg = load_config(write(tmp_path, text, "ok.yaml"))
    assert cfg.motion.pan.max_jerk == pytest.approx(math.radians(1000.0))
    assert cfg.topics.max_cloud_points == 200000


TOPICS = """\
topics:
  domain_id: 5
  pose: /robot/pose
  pose_type: geometry_msgs/msg/PoseStamped
  path: /robot/plan
  landmarks: /robot/landmarks
  targets: /robot/targets
  joint_states: /robot/joints
  view_plan: /robot/view_plan
  frame_id: world
  max_cloud_points: 1000
"""


def test_topics_section_is_the_bus_settings(tmp_path):
    cfg = load_config(write(tmp_path, MINIMAL + TOPICS, "ok.yaml"))
    assert cfg.topics == BusTopics(domain_id=5, pose="/robot/pose", pose_type="geometry_msgs/msg/PoseStamped",
                                   path="/robot/plan", landmarks="/robot/landmarks", targets="/robot/targets",
                                   joint_states="/robot/joints", view_plan="/robot/view_plan", frame_id="world",
                                   max_cloud_points=1000, status_key="pivot/test-node/status")
    # Settings the file has no key for keep the bus's defaults.
    assert (cfg.topics.accept_empty_frame, cfg.topics.namespace, cfg.topics.humble) == (True, "/", False)
    # The status key follows the name, however the config is built or copied.
    assert Config(name="robot7").topics.status_key == "pivot/robot7/status"
    renamed = replace(cfg, name="other")
    assert renamed.status_key == renamed.topics.status_key == "pivot/other/status"
    assert renamed.topics.pose == "/robot/pose"


@pytest.mark.parametrize(
    ("section", "pattern"),
    [
        ("topics:\n  posee: /odom\n", r":5: topics\.posee: unknown key; did you mean pose\?"),
        ("topics:\n  domain_id: '0'\n", r":5: topics\.domain_id: must be an integer, got str '0'"),
        ("topics:\n  domain_id: 233\n", r":5: topics\.domain_id: must be ≤ 232, got 233"),
        ("topics:\n  max_cloud_points: 10.5\n", r":5: topics\.max_cloud_points: must be an integer"),
        ("topics:\n  frame_id: [map]\n", r":5: topics\.frame_id: must be a string, got a list"),
        ("topics:\n  landmarks: 12\n", r":5: topics\.landmarks: must be a string, got int 12"),
    ],
)
def test_topics_section_errors_are_one_line_with_file_line_and_key(tmp_path, section, pattern):
    message = load_error(tmp_path, MINIMAL + section)
    assert re.search(r"bad\.yaml" + pattern, message), message


# ---------------------------------------------------------------- gimbal.backend
def _gimbal_doc(tmp_path, text: str):
    path = tmp_path / "backend.yaml"
    path.write_text("map:\n  allow_empty: true\ngimbal:\n" + text)
    return path


def test_backend_defaults_to_pivot_and_builds_the_serial_link(tmp_path):
    from pivotd.daemon.wiring import build_gimbal
    from pivotd.gimbal.link import GimbalLink

    cfg = load_config(_gimbal_doc(tmp_path, "  backend: pivot\n"))
    assert cfg.gimbal.backend == "pivot"
    assert isinstance(build_gimbal(cfg), GimbalLink)


@pytest.mark.parametrize(("text", "line", "needle"), [
    ("  port: mock://\n  backend: canbus\n", 5, "gimbal.backend: must be one of pivot, mavlink, dynamixel"),
    ("  backend: dynamixel\n  port: socket://h:1\n", 5, "gimbal.port: 'socket://h:1': the dynamixel backend opens"),
    ("  mavlink:\n    system_id: 0\n", 5, "gimbal.mavlink.system_id"),
    ("  mavlink:\n    sysid: 3\n", 5, "gimbal.mavlink.sysid"),
])
def test_bad_backend_settings_are_one_line_errors_naming_file_line_and_key(tmp_path, text, line, needle):
    path = _gimbal_doc(tmp_path, text)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert "\n" not in msg and needle in msg and f"{path.name}:{line}:" in msg, msg


def test_the_mavlink_backend_needs_a_mavlink_connection_and_builds_its_gimbal(tmp_path):
    from pivotd.daemon.wiring import build_gimbal
    from pivotd.gimbal.mavlink_link import MavlinkGimbal

    path = _gimbal_doc(tmp_path, "  backend: mavlink\n  port: mock://\n")
    with pytest.raises(ConfigError, match=r"backend\.yaml:5: gimbal\.port: 'mock://' is not a MAVLink connection"):
        load_config(path)
    cfg = load_config(_gimbal_doc(tmp_path, "  backend: mavlink\n  port: udpin:0.0.0.0:14550\n"
                                            "  mavlink: {system_id: 2, target_component: 1}\n"))
    assert (cfg.gimbal.mavlink.system_id, cfg.gimbal.mavlink.component_id, cfg.gimbal.mavlink.target_component) == (
        2, 191, 1)
    g = build_gimbal(cfg)
    assert isinstance(g, MavlinkGimbal) and g.settings.system_id == 2 and g.settings.limits == cfg.gimbal.limits
    with pytest.raises(InputError, match="--port: 'socket://x:1' is not a MAVLink connection"):
        cfg.with_overrides(port="socket://x:1")


@pytest.mark.parametrize("key", ["spread_cell_deg", "spread_saturation", "spread_depth_ratio"])
def test_a_removed_key_is_an_unknown_key_that_says_why_it_went(tmp_path, key):
    message = load_error(tmp_path, MINIMAL + f"planner:\n  horizon: 10\n  {key}: 3\n")
    assert re.search(rf":6: planner\.{key}: unknown key \(removed: measured and not kept, see "
                     r"docs/experiments/spread-weights\.md\)$", message), message


def test_a_removed_key_elsewhere_than_its_section_is_only_unknown(tmp_path):
    message = load_error(tmp_path, MINIMAL + "pivot:\n  spread_cell_deg: 3\n")
    assert re.search(r":5: pivot\.spread_cell_deg: unknown key", message) and "(removed:" not in message, message


def test_every_removed_key_is_gone_from_the_docs_keys_and_the_shipped_configs():
    from pivotd.config.yaml_reader import REMOVED_KEYS

    config_doc = (REPO / "docs" / "CONFIG.md").read_text()
    for dotted in REMOVED_KEYS:
        assert f"`{dotted}`" in config_doc, f"docs/CONFIG.md lists no removed key {dotted}"
        leaf = dotted.rsplit(".", 1)[1]
        assert f"| `{leaf}` |" not in config_doc, f"docs/CONFIG.md still documents {dotted} as a key"
        for yaml_file in CONFIG_DIR.glob("*.yaml"):
            assert f"{leaf}:" not in yaml_file.read_text(), f"{yaml_file} still sets {dotted}"


def test_humble_key_form_is_a_topics_key(tmp_path):
    on = load_config(write(tmp_path, "map: {allow_empty: true}\ntopics: {humble: true}\n", "humble.yaml"))
    assert on.topics.humble is True
    assert load_config(write(tmp_path, "map: {allow_empty: true}\n", "jazzy.yaml")).topics.humble is False
    message = load_error(tmp_path, "map: {allow_empty: true}\ntopics: {humble: 3}\n")
    assert re.search(r"bad\.yaml:2: topics\.humble: must be true or false", message)
