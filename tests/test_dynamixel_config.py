"""``gimbal.dynamixel`` settings: zero ticks, the joint limits they must fit, the backend's default baud."""

from __future__ import annotations

import math
from pathlib import Path

import pytest

from pivotd.config import load_config
from pivotd.errors import ConfigError


def doc(tmp_path: Path, gimbal: str, name: str = "dxl.yaml") -> Path:
    path = tmp_path / name
    path.write_text("map:\n  allow_empty: true\ngimbal:\n" + gimbal)
    return path


def test_zero_ticks_default_to_the_centre_and_reach_the_link(tmp_path):
    from pivotd.daemon.wiring import build_gimbal

    cfg = load_config(doc(tmp_path, "  backend: dynamixel\n  port: /dev/ttyUSB0\n"))
    assert (cfg.gimbal.dynamixel.pan_zero_tick, cfg.gimbal.dynamixel.tilt_zero_tick) == (2048, 2048)
    cfg = load_config(doc(tmp_path, "  backend: dynamixel\n  port: /dev/ttyUSB0\n"
                                    "  dynamixel: {pan_zero_tick: 1000, tilt_zero_tick: 3000, tilt_reversed: true}\n"
                                    "  limits: {pan_min_deg: -60, pan_max_deg: 90, tilt_min_deg: -30,"
                                    " tilt_max_deg: 45}\n"))
    g = build_gimbal(cfg)
    assert (g.settings.pan_zero_tick, g.settings.tilt_zero_tick, g.settings.tilt_reversed) == (1000, 3000, True)


@pytest.mark.parametrize(("gimbal", "line", "needle"), [
    ("  dynamixel:\n    pan_zero_tick: 4096\n", 7, "gimbal.dynamixel.pan_zero_tick: must be ≤ 4095"),
    ("  dynamixel:\n    tilt_zero_tick: 1.5\n", 7, "gimbal.dynamixel.tilt_zero_tick"),
    # 1000 ticks below the zero tick is 87.9°: -90° does not fit; blamed on the zero tick that was set
    ("  dynamixel:\n    pan_zero_tick: 1000\n  limits: {pan_min_deg: -90, pan_max_deg: 90}\n", 7,
     "gimbal.dynamixel.pan_zero_tick: pan limits [-90, 90]° are ticks [-24, 2024] around zero tick 1000"),
    # no zero tick set: the limit that does not fit at 2048 is blamed
    ("  limits:\n    pan_min_deg: -90\n    pan_max_deg: 185\n", 8,
     "gimbal.limits.pan_max_deg: pan limits [-90, 185]° are ticks [1024, 4152] around zero tick 2048"),
    ("  dynamixel: {pan_reversed: true}\n  limits:\n    pan_min_deg: -181\n    pan_max_deg: 90\n", 8,
     "gimbal.limits.pan_min_deg: pan limits [-181, 90]°"),
    ("  limits:\n    continuous_pan: true\n", 7, "gimbal.limits.continuous_pan: the dynamixel backend"),
])
def test_limits_and_zero_ticks_that_do_not_fit_the_servos_are_errors_naming_file_line_and_key(
        tmp_path, gimbal, line, needle):
    path = doc(tmp_path, "  backend: dynamixel\n  port: /dev/ttyUSB0\n" + gimbal)
    with pytest.raises(ConfigError) as err:
        load_config(path)
    msg = str(err.value)
    assert "\n" not in msg and f"{path.name}:{line}: {needle}" in msg, msg


def test_the_servo_range_binds_only_the_dynamixel_backend(tmp_path):
    cfg = load_config(doc(tmp_path, "  limits: {tilt_min_deg: -90, tilt_max_deg: 180}\n"
                                    "  dynamixel: {tilt_zero_tick: 10}\n"))
    assert cfg.gimbal.backend == "pivot" and cfg.gimbal.limits.tilt_max == pytest.approx(math.pi)


@pytest.mark.parametrize(("gimbal", "baud"), [
    ("  backend: dynamixel\n  port: /dev/ttyUSB0\n", 57600),  # the X-series factory Baud Rate
    ("  backend: dynamixel\n  port: /dev/ttyUSB0\n  baud: 1000000\n", 1_000_000),
    ("  backend: pivot\n", 115200),
    ("  backend: mavlink\n  port: /dev/ttyACM0\n", 115200),
    ("  backend: mavlink\n  port: /dev/ttyACM0\n  baud: 921600\n", 921600),
])
def test_the_default_baud_is_the_backends(tmp_path, gimbal, baud):
    cfg = load_config(doc(tmp_path, gimbal))
    assert cfg.gimbal.baud == baud
