"""Hostile configs: bounded YAML, clear errors, and validation against what the gimbal protocol carries."""

from __future__ import annotations

import math
import re
import tracemalloc
from pathlib import Path

import numpy as np
import pytest
import yaml
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from test_config_doc import BASE as BASE_DOC
from test_config_doc import DOCUMENTED, _with

from pivotd.cli import main
from pivotd.config import load_config
from pivotd.config.settings import wire_config
from pivotd.errors import ConfigError
from pivotd.firmware_proto.device import validate_config
from pivotd.firmware_proto.messages import Config as ConfigMessage

BASE = "map:\n  allow_empty: true\n"


def _write(tmp_path: Path, text: str, name: str = "c.yaml") -> Path:
    f = tmp_path / name
    f.write_text(text)
    return f


def _error(path: Path) -> str:
    with pytest.raises(ConfigError) as info:
        load_config(path)
    message = str(info.value)
    assert "\n" not in message and message.startswith(str(path))
    return message


BOMB = "a0: &a0 [x, x, x, x, x, x, x, x, x, x]\n" + "".join(
    f"a{i}: &a{i} [{', '.join([f'*a{i - 1}'] * 10)}]\n" for i in range(1, 9))


@pytest.mark.parametrize(("text", "expected"), [
    ("a: &x [*x]\n", ":1: YAML refused: recursive alias"),
    ("a: &x {b: {c: *x}}\n", ":1: YAML refused: recursive alias"),
    ("a: " + "[" * 5000 + "]" * 5000 + "\n", ":1: YAML refused: nesting deeper than 64 levels"),
    ("".join("  " * i + f"k{i}:\n" for i in range(300)), ":64: YAML refused: nesting deeper than 64 levels"),
    (BOMB, "YAML refused: more than 100000 values after expanding aliases"),
    ("? [a, b]\n: 1\n", ":1: key (sequence) is not a string"),
    ("name: 2001-13-45\n", "YAML value cannot be read"),
])
def test_hostile_yaml_is_refused_with_one_line_and_bounded_memory(tmp_path, text, expected):
    f = _write(tmp_path, text)
    tracemalloc.start()
    try:
        message = _error(f)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert expected in message
    assert peak < 64 << 20  # the 2 KB bomb formerly grew past 850 MB


def test_oversized_config_file_is_refused(tmp_path):
    f = _write(tmp_path, "# " + "x" * (1 << 20) + "\n")
    assert "more than the 1048576 a config may have" in _error(f)


def test_aliases_within_budget_still_work(tmp_path):
    f = _write(tmp_path, BASE + "motion:\n  pan: &axis {max_velocity_deg_s: 45, max_acceleration_deg_s2: 90}\n"
                                "  tilt: *axis\n")
    cfg = load_config(f)
    assert cfg.motion.tilt.max_velocity == pytest.approx(math.radians(45))


def test_unknown_user_in_a_path_is_a_config_error(tmp_path):
    f = _write(tmp_path, "map:\n  file: ~nouser_pivotd/x.npy\n")
    assert _error(f).endswith(":2: map.file: cannot expand '~nouser_pivotd': no such user or home directory")


# The configs the protocol cannot carry (each formerly passed `check`) and the key the error names.
WIRE_CASES = [
    ("gimbal:\n  watchdog_ms: 20000\n", "gimbal.watchdog_ms: 20000 cannot be sent to the gimbal: 20000 ms is outside"),
    ("gimbal:\n  watchdog_ms: 10001\n", "gimbal.watchdog_ms"),
    ("gimbal:\n  limits: {pan_min_deg: -400, pan_max_deg: 400}\n", "gimbal.limits.pan_min_deg: -400 cannot be sent"),
    ("gimbal:\n  limits: {pan_min_deg: -90, pan_max_deg: 361}\n", "gimbal.limits.pan_max_deg: 361"),
    ("gimbal:\n  limits: {pan_min_deg: -720, pan_max_deg: 720, continuous_pan: true}\n", "pan_min_deg"),
    ("gimbal:\n  limits: {tilt_min_deg: 1, tilt_max_deg: 1.00000001}\n  park: {tilt_deg: 1}\n",
     "gimbal.limits.tilt_max_deg: 1 cannot be sent to the gimbal: tilt_max must exceed tilt_min on the wire"),
    ("gimbal:\n  limits: {pan_min_deg: 0, pan_max_deg: 0.00002}\n", "pan_max must exceed pan_min"),
    ("motion:\n  pan: {max_velocity_deg_s: 0.00001}\n",
     "motion.pan.max_velocity_deg_s: 1e-05 cannot be sent to the gimbal: 1.74533e-07 rounds to 0 micro-units"),
    ("motion:\n  tilt: {max_velocity_deg_s: 0.00002}\n", "motion.tilt.max_velocity_deg_s"),
    ("motion:\n  pan: {max_acceleration_deg_s2: 0.00001}\n", "motion.pan.max_acceleration_deg_s2"),
    ("motion:\n  tilt: {max_acceleration_deg_s2: 1e9}\n",
     "motion.tilt.max_acceleration_deg_s2: 1e+09 cannot be sent to the gimbal: 1.74533e+07 does not fit"),
    ("motion:\n  pan: {max_velocity_deg_s: 200000}\n", "motion.pan.max_velocity_deg_s: 200000"),
]


@pytest.mark.parametrize(("text", "expected"), WIRE_CASES)
def test_configs_the_protocol_cannot_carry_fail_check(tmp_path, text, expected, capsys):
    f = _write(tmp_path, BASE + text)
    assert expected in _error(f)
    assert main(["check", "--config", str(f)]) == 2
    assert expected in capsys.readouterr().err


def test_tiny_occlusion_voxel_is_refused(tmp_path):
    f = _write(tmp_path, "map:\n  allow_empty: true\n  filters:\n    max_range: 20\n    occlusion_voxel: 1e-6\n")
    assert ":5: map.filters.occlusion_voxel: 1e-06 m makes a 20 m ray 2e+07 voxels long, more than 4096" in _error(f)


def test_check_builds_the_occupancy_grid_the_daemon_builds(tmp_path, capsys):
    # 0.01 m passes the ray bound (20 m / 4096) but a 2 km map is 200 000 voxels across.
    (tmp_path / "m.txt").write_text("0 0 0\n2000 0 0\n")
    f = _write(tmp_path, "map:\n  file: m.txt\n  filters:\n    occlusion_voxel: 0.01\n")
    load_config(f)
    assert main(["check", "--config", str(f)]) == 2
    err = capsys.readouterr().err.strip()
    assert "\n" not in err and f"{f}: map.filters.occlusion_voxel: occlusion voxel 0.01 m is too small" in err


@pytest.mark.parametrize("content", ["garbage {{{", "{mode: 'peer', bogus_key: 3}", "{listen: {endpoints: 5}}"])
def test_garbage_zenoh_config_file_fails_check(tmp_path, content):
    (tmp_path / "z.json5").write_text(content)
    f = _write(tmp_path, BASE + "zenoh:\n  config_file: z.json5\n")
    assert ":4: zenoh.config_file: " in _error(f) and "invalid Zenoh config" in _error(f)


def test_valid_zenoh_config_file_passes(tmp_path):
    (tmp_path / "z.json5").write_text("{mode: 'peer', scouting: {multicast: {enabled: false}}}")
    cfg = load_config(_write(tmp_path, BASE + "zenoh:\n  config_file: z.json5\n"))
    assert cfg.zenoh.config_file == tmp_path / "z.json5"


_deg = st.floats(-400.0, 400.0, allow_nan=False)
_rate = st.one_of(st.floats(1e-7, 1e-3), st.floats(1e-3, 1e6))


@settings(max_examples=300, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(pan=st.tuples(_deg, _deg), tilt=st.tuples(_deg, _deg), rates=st.tuples(_rate, _rate, _rate, _rate),
       watchdog=st.integers(30, 70000))
def test_check_passing_means_the_device_accepts_the_config(tmp_path, pan, tilt, rates, watchdog):
    """Any config `load_config` accepts yields a CONFIG the (simulated) device ACKs, byte for byte."""
    (pmin, pmax), (tmin, tmax) = sorted(pan), sorted(tilt)
    text = (BASE + f"gimbal:\n  watchdog_ms: {watchdog}\n  limits: {{pan_min_deg: {pmin!r}, pan_max_deg: {pmax!r}, "
            f"tilt_min_deg: {tmin!r}, tilt_max_deg: {tmax!r}}}\n  park: {{pan_deg: {pmin!r}, tilt_deg: {tmin!r}}}\n"
            f"motion:\n  pan: {{max_velocity_deg_s: {rates[0]!r}, max_acceleration_deg_s2: {rates[1]!r}}}\n"
            f"  tilt: {{max_velocity_deg_s: {rates[2]!r}, max_acceleration_deg_s2: {rates[3]!r}}}\n")
    f = _write(tmp_path, text)
    try:
        cfg = load_config(f)
    except ConfigError:
        return
    msg = wire_config(cfg.gimbal, cfg.motion)
    received = ConfigMessage.unpack(msg.pack())
    assert validate_config(received) is None
    assert received.watchdog_ms == watchdog
    for name in ("vmax_pan", "vmax_tilt", "amax_pan", "amax_tilt"):
        assert getattr(received, name) == pytest.approx(getattr(msg, name), rel=0.5, abs=1e-6)


def test_wire_config_is_what_the_daemon_sends(tmp_path):
    from pivotd.daemon.wiring import build_link_config

    cfg = load_config(_write(tmp_path, BASE))
    assert build_link_config(cfg).limits == wire_config(cfg.gimbal, cfg.motion)


# Every documented numeric key (tests/test_config_doc.py reads them off docs/CONFIG.md) and values no number
# key may take: an integer beyond the float range (it once ended in "OverflowError: int too large to convert to
# float"), infinities and nan.
NUMERIC_KEYS = [k for k, v in DOCUMENTED if isinstance(v, int | float) and not isinstance(v, bool)]
HUGE = int("9" * 400)


def _doc_with(key: str, value: object) -> str:
    return yaml.safe_dump(_with(dict(BASE_DOC), key, value))


def test_the_numeric_keys_are_found():
    assert len(NUMERIC_KEYS) >= 60 and {"control.rate_hz", "planner.horizon", "topics.max_pose_bytes"} <= set(
        NUMERIC_KEYS)


@pytest.mark.parametrize("key", NUMERIC_KEYS)
@pytest.mark.parametrize("value", [HUGE, -HUGE, math.inf, -math.inf, math.nan], ids=["huge", "-huge", "inf", "-inf",
                                                                                  "nan"])
def test_every_numeric_key_refuses_values_beyond_the_finite_floats_in_one_line(tmp_path, key, value):
    text = _doc_with(key, value)
    line = next(i for i, row in enumerate(text.splitlines(), 1) if row.lstrip().startswith(key.split(".")[-1] + ":"))
    message = _error(_write(tmp_path, text))
    assert re.search(rf":{line}: {re.escape(key)}: must be (finite|an integer), got ", message), message
    assert len(message) < 300  # the 400 digits are not repeated


def test_a_huge_integer_is_shown_shortened(tmp_path):
    f = _write(tmp_path, BASE + "control:\n  rate_hz: " + "9" * 400 + "\n")
    assert _error(f) == f"{f}:4: control.rate_hz: must be finite, got 999…999 (400 digits)"


@pytest.mark.parametrize("value", [str(HUGE), ".inf", ".nan", "1e999"])
def test_a_vector_refuses_values_beyond_the_finite_floats(tmp_path, value):
    f = _write(tmp_path, BASE + f"gimbal:\n  mount:\n    xyz: [0, {value}, 0]\n")
    assert re.fullmatch(rf"{re.escape(str(f))}:5: gimbal\.mount\.xyz: must be a list of 3 finite numbers, got "
                        r"\[0, (999…999 \(400 digits\)|inf|nan|'1e999'), 0\]", _error(f))


def test_a_vector_reads_exponent_numbers_as_numbers(tmp_path):
    cfg = load_config(_write(tmp_path, BASE + "gimbal:\n  mount:\n    xyz: [0, 1e-3, 2E2]\n"))
    assert tuple(cfg.gimbal.mount.translation) == (0.0, 0.001, 200.0)


def test_an_integer_too_long_to_read_names_its_line_and_key(tmp_path):
    f = _write(tmp_path, BASE + "planner:\n  horizon: " + "9" * 5000 + "\n")
    assert _error(f).startswith(f"{f}:4: planner.horizon: YAML value cannot be read (ValueError: ")


@pytest.mark.parametrize(("name", "write", "problem"), [
    ("plain.txt", lambda p: p.write_text("0 0 0 1\n1 2 3 1\n"), "needs a header row naming the columns"),
    ("m.npy", lambda p: np.save(p, np.zeros((2, 3))), "applies to PLY and PCD maps and text maps with a header row"),
])
def test_a_weight_property_the_map_cannot_have_names_the_map_and_the_key(tmp_path, name, write, problem):
    write(tmp_path / name)
    f = _write(tmp_path, f"map:\n  file: {name}\n  weight_property: w\n")
    message = _error(f)
    assert message.startswith(f"{f}:3: map.weight_property: {tmp_path / name}: weight property 'w' "), message
    assert problem in message


def test_a_weight_property_a_header_row_names_is_accepted(tmp_path):
    (tmp_path / "named.txt").write_text("x y z w\n0 0 0 1\n")
    cfg = load_config(_write(tmp_path, "map:\n  file: named.txt\n  weight_property: w\n"))
    assert cfg.map.weight_property == "w"
