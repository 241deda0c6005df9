"""Client mode without a router: open_session_waiting says once what it waits for, backs off, and gives up only
when the caller stops; bad settings still fail at once."""

from __future__ import annotations

import json
import logging

import pytest
import zenoh
from bus_support import free_port

from pivotd.bus.session import RouterUnreachableError, open_session, open_session_waiting
from pivotd.errors import ConfigError


def test_no_router_is_its_own_error_and_bad_settings_are_not():
    with pytest.raises(RouterUnreachableError, match=r"connect tcp/127\.0\.0\.1"):
        open_session(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"], connect_timeout_s=0.05)
    with pytest.raises(ConfigError) as info:
        open_session(listen=["tcp/192.0.2.1:7447"])  # TEST-NET address: cannot be bound
    assert not isinstance(info.value, RouterUnreachableError)


def test_waiting_logs_once_backs_off_and_stops_when_told(caplog):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    delays: list[float] = []

    def wait(seconds: float) -> bool:  # the caller's wait: True = stopping
        delays.append(seconds)
        return len(delays) == 6

    with caplog.at_level(logging.INFO, logger="pivotd.bus.session"):
        session = open_session_waiting(wait, mode="client", connect=[endpoint], attempt_s=0.05, backoff_s=(0.5, 4.0))
    assert session is None
    assert delays == [0.5, 1.0, 2.0, 4.0, 4.0, 4.0]
    waiting = [r.getMessage() for r in caplog.records if "waiting for the Zenoh router" in r.getMessage()]
    assert len(waiting) == 1 and waiting[0].startswith(f"waiting for the Zenoh router at {endpoint} ")


@pytest.mark.slow
def test_a_router_that_comes_up_while_waiting_is_reached(caplog):
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    routers: list[zenoh.Session] = []

    def wait(_seconds: float) -> bool:  # the router comes up during the first wait
        if not routers:
            conf = zenoh.Config()
            conf.insert_json5("mode", json.dumps("router"))
            conf.insert_json5("listen/endpoints", json.dumps([endpoint]))
            conf.insert_json5("scouting/multicast/enabled", "false")
            routers.append(zenoh.open(conf))
        return False

    try:
        with caplog.at_level(logging.INFO, logger="pivotd.bus.session"):
            session = open_session_waiting(wait, mode="client", connect=[endpoint], attempt_s=2.0)
        assert session is not None
        try:
            assert str(routers[0].info.zid()) in {str(z) for z in session.info.routers_zid()}
        finally:
            session.close()
        assert f"Zenoh router at {endpoint} reached after" in caplog.text
    finally:
        for r in routers:
            r.close()


def test_peer_mode_opens_at_once_without_waiting():
    calls: list[float] = []
    session = open_session_waiting(lambda s: calls.append(s) or False, mode="peer",
                                   connect=[f"tcp/127.0.0.1:{free_port()}"])
    assert session is not None and calls == []
    session.close()
