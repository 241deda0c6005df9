"""Opening Zenoh sessions: settings validation and one-line ConfigErrors."""

import json
import queue

import pytest
from bus_support import drain, free_port, wait_connected

from pivotd.bus.session import build_config, open_session, validate_endpoint
from pivotd.errors import ConfigError


@pytest.mark.parametrize("bad", ["127.0.0.1:7447", "tcp/", "tcp/127.0.0.1", "tcp/127.0.0.1:99999", "http/x:1",
                                 "tcp/host:port"])
def test_bad_endpoints_rejected_with_the_endpoint_named(bad):
    with pytest.raises(ConfigError) as info:
        open_session(connect=[bad])
    assert repr(bad) in str(info.value) and "\n" not in str(info.value)


def test_good_endpoints_pass():
    for ep in ("tcp/127.0.0.1:7447", "tcp/[::1]:7447", "udp/localhost:1", "tls/robot.local:7447"):
        assert validate_endpoint(ep) == ep


def test_bad_mode_rejected():
    with pytest.raises(ConfigError, match="mode 'router'"):
        open_session(mode="router")


def test_missing_and_invalid_config_file(tmp_path):
    with pytest.raises(ConfigError, match="not found"):
        open_session(config_file=tmp_path / "nope.json5")
    bad = tmp_path / "bad.json5"
    bad.write_text("{ mode: 'peer', this is not json5 ")
    with pytest.raises(ConfigError, match=r"bad\.json5"):
        open_session(config_file=bad)


def test_config_file_is_the_base_and_arguments_override(tmp_path):
    f = tmp_path / "z.json5"
    f.write_text(json.dumps({"mode": "client", "metadata": {"name": "robot-7"}}))
    cfg = build_config(mode="peer", config_file=f, listen=["tcp/127.0.0.1:0"])
    assert json.loads(cfg.get_json("mode")) == "peer"
    assert json.loads(cfg.get_json("metadata")) == {"name": "robot-7"}
    assert "tcp/127.0.0.1:0" in cfg.get_json("listen/endpoints")
    assert json.loads(cfg.get_json("scouting/multicast/enabled")) is False


def test_unusable_listen_address_is_config_error():
    with pytest.raises(ConfigError, match="cannot open Zenoh session") as info:
        open_session(listen=["tcp/192.0.2.1:7447"])  # TEST-NET address: not on this machine, never contacted
    assert ".rs:" not in str(info.value)


def test_client_without_router_is_config_error():
    with pytest.raises(ConfigError, match=r"connect tcp/127\.0\.0\.1"):
        open_session(mode="client", connect=[f"tcp/127.0.0.1:{free_port()}"])


def test_two_sessions_talk_on_loopback():
    ep = f"tcp/127.0.0.1:{free_port()}"
    a = open_session(listen=[ep])
    try:
        b = open_session(connect=[ep])
        try:
            wait_connected(a, b)
            q = queue.Queue()
            sub = a.declare_subscriber("test/x", lambda s: q.put(s.payload.to_bytes()))
            wait_connected(a, b)
            got = []
            for _ in range(50):  # the subscription needs a moment to propagate
                b.put("test/x", b"hello")
                got = drain(q, 1, 0.2)
                if got:
                    break
            assert got == [b"hello"]
            sub.undeclare()
        finally:
            b.close()
    finally:
        a.close()


def test_peer_listens_on_loopback_only_by_default():
    cfg = build_config(mode="peer", connect=["tcp/127.0.0.1:7447"])
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/127.0.0.1:0"]
    cfg = build_config(mode="peer", listen=["tcp/0.0.0.0:7448"])
    assert json.loads(cfg.get_json("listen/endpoints")) == ["tcp/0.0.0.0:7448"]


_SHM_SENDER = """
import sys, time, json, zenoh
c = zenoh.Config()  # Zenoh's defaults: shared memory on, large messages handed over in a 16 MiB pool
c.insert_json5("mode", '"peer"')
c.insert_json5("connect/endpoints", json.dumps([sys.argv[1]]))
c.insert_json5("scouting/multicast/enabled", "false")
s = zenoh.open(c)
pub = s.declare_publisher("shm/test")
payload = bytes(1 << 20)
for _ in range(100):
    pub.put(payload)
    time.sleep(0.1)
"""


def _zenoh_shm_mappings() -> list[str]:
    with open("/proc/self/maps") as fh:
        return [line.split()[-1] for line in fh if line.rstrip().endswith(".zenoh")]


@pytest.mark.parametrize("shared_memory", [False, True])
def test_large_messages_from_a_local_peer_do_not_map_its_shared_memory(tmp_path, shared_memory):
    """A peer on the same host with Zenoh's defaults puts 1 MiB messages. Our session has shared memory off, so they
    arrive over the link and the peer's 16 MiB pool is never mapped into this process (where it counted as the
    daemon's resident memory: +16 MB the first time a large path arrived). Turned back on, the pool is mapped."""
    import subprocess
    import sys

    ep = f"tcp/127.0.0.1:{free_port()}"
    before = set(_zenoh_shm_mappings())
    config = build_config(listen=[ep])
    if shared_memory:
        config.insert_json5("transport/shared_memory/enabled", "true")
    import zenoh

    session = zenoh.open(config)
    got: queue.Queue = queue.Queue()
    sub = session.declare_subscriber("shm/test", lambda sample: got.put(len(sample.payload)))
    sender = subprocess.Popen([sys.executable, "-c", _SHM_SENDER, ep])
    try:
        assert got.get(timeout=30.0) == 1 << 20
        got.get(timeout=10.0)
        assert bool(set(_zenoh_shm_mappings()) - before) == shared_memory
    finally:
        sender.kill()
        sender.wait()
        sub.undeclare()
        session.close()
