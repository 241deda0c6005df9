"""Every gimbal implementation offers the whole GimbalInterface with compatible signatures."""

from __future__ import annotations

import inspect

import pytest
from gimbal_fakes import FakeGimbal

from pivotd.gimbal.dynamixel_link import DynamixelGimbal
from pivotd.gimbal.interface import GimbalInterface, LinkState
from pivotd.gimbal.link import GimbalLink
from pivotd.gimbal.mavlink_link import MavlinkGimbal

MEMBERS = [name for name in vars(GimbalInterface) if not name.startswith("_")]


def test_the_interface_is_what_the_daemon_uses():
    assert set(MEMBERS) == {"link_state", "state", "last_error", "start", "stop", "send_setpoint", "send_heartbeat",
                            "set_enabled", "clear_fault", "counters"}


@pytest.mark.parametrize("implementation", [GimbalLink, MavlinkGimbal, DynamixelGimbal, FakeGimbal])
def test_implementation_has_every_member_with_a_compatible_signature(implementation):
    for name in MEMBERS:
        spec = getattr(GimbalInterface, name)
        if isinstance(spec, property):
            continue  # an attribute or a property; checked on instances below
        impl = getattr(implementation, name)
        expected = list(inspect.signature(spec).parameters.values())
        got = inspect.signature(impl).parameters
        for p in expected:
            assert p.name in got, f"{implementation.__name__}.{name} lacks parameter {p.name}"
            if p.default is not inspect.Parameter.empty:
                assert got[p.name].default == p.default, f"{implementation.__name__}.{name}({p.name}=…)"


def test_a_stopped_link_reports_its_state_as_the_enum():
    from pivotd.config import Config
    from pivotd.daemon.wiring import build_link_config

    link = GimbalLink("mock://", build_link_config(Config()))
    assert link.link_state is LinkState.STOPPED and link.link_state == "stopped"
    assert link.state is None and link.last_error is None
    assert link.send_setpoint(0.0, 0.0) is None and link.set_enabled(True) is False
    assert isinstance(link.counters(), dict)


def test_a_stopped_mavlink_gimbal_sends_nothing():
    from pivotd.config import Config
    from pivotd.daemon.wiring import build_mavlink_settings

    g = MavlinkGimbal("udpout:127.0.0.1:9", build_mavlink_settings(Config()))
    assert g.link_state is LinkState.STOPPED and g.state is None and g.last_error is None
    assert g.send_setpoint(0.0, 0.0) is None and g.set_enabled(True) is False and g.clear_fault() is False
    assert g.counters()["setpoints_sent"] == 0
