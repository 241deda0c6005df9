"""Bus access control: mutual TLS and Zenoh access-control rules on loopback with certificates made here.

Only a peer with a certificate of the configured CA *and* a listed common name can make pivotd accept a
pose; the others cannot, whether they have no valid certificate or a valid one outside the rules.
"""

from __future__ import annotations

import json
import os
import queue
import shutil
import subprocess
import sys
from pathlib import Path

import pytest
import zenoh
from bus_support import drain, free_port, wait_for

from pivotd.bus import messages as m
from pivotd.bus import ros
from pivotd.bus.pivot_bus import PivotBus
from pivotd.bus.security import exposure_warning, input_key_exprs, is_loopback
from pivotd.bus.security_settings import ZenohSecurity
from pivotd.bus.session import build_config, open_session
from pivotd.bus.topics import BusTopics
from pivotd.config import load_config
from pivotd.errors import ConfigError

REPO = Path(__file__).resolve().parent.parent
MAKE_CERTS = REPO / "config" / "secure" / "make-certs.sh"
pytestmark = pytest.mark.skipif(shutil.which("openssl") is None, reason="needs the openssl command")


def make_certs(directory: Path, *names: str) -> Path:
    subprocess.run(["sh", str(MAKE_CERTS), str(directory), *names], check=True, timeout=120)
    return directory


@pytest.fixture(scope="module")
def certs(tmp_path_factory) -> dict[str, Path]:
    good = make_certs(tmp_path_factory.mktemp("pki"), "pivotd", "robot-localization", "visitor")
    rogue = make_certs(tmp_path_factory.mktemp("rogue-pki"), "robot-localization")  # same name, another CA
    return {"ca": good / "ca.pem", "good": good, "rogue": rogue}


def identity(directory: Path, name: str, ca: Path, **kw) -> ZenohSecurity:
    return ZenohSecurity(ca=ca, cert=directory / f"{name}.pem", key=directory / f"{name}.key", **kw)


@pytest.fixture(scope="module")
def daemon_side(certs):
    """pivotd's session and bus: TLS listener on loopback, only robot-localization may publish inputs."""
    topics = BusTopics()
    endpoint = f"tls/127.0.0.1:{free_port()}"
    sec = identity(certs["good"], "pivotd", certs["ca"], allow_cert_common_names=("robot-localization",))
    session = open_session(listen=[endpoint], security=sec, input_keys=input_key_exprs(topics))
    events: queue.Queue = queue.Queue()
    bus = PivotBus(session, topics, on_pose=events.put)
    bus.publish_status({"state": "ready"})
    try:
        yield session, bus, events, endpoint
    finally:
        bus.close()
        session.close()


def publish_poses_then_query(peer: zenoh.Session, x: float, matched: bool = False) -> list:
    """Publish five poses at ``x`` from ``peer`` (``matched``: once pivotd's subscription is known to the publisher),
    then query pivotd's status over the same link (queries are allowed to everyone); the replies come back after the
    poses were delivered or refused."""
    node = ros.RosNode(peer, "publisher", node_id=7)
    try:
        pub = node.publisher("/odom", m.ODOMETRY)
        if matched:  # a new link: pivotd's subscription may reach the peer after the link is up
            assert wait_for(pub.matched), "pivotd's pose subscription never reached the peer"
        for _ in range(5):
            pub.put(m.encode_odometry(0.0, "map", "base_link", [x, 0.0, 0.0], [0, 0, 0, 1]))
        return list(peer.get("pivot/pivotd/status", timeout=3.0))
    finally:
        node.close()


def test_authorised_peer_is_accepted_and_others_are_not(certs, daemon_side):
    session, bus, events, endpoint = daemon_side
    good, ca = certs["good"], certs["ca"]

    # 1. No certificate at all: a plain TCP peer cannot open a link to the TLS listener.
    plain = open_session(connect=[endpoint.replace("tls/", "tcp/")])
    try:
        replies = publish_poses_then_query(plain, 11.0)
        assert not [r for r in replies if r.ok]
    finally:
        plain.close()

    # 2. A certificate with the allowed name, signed by another CA: the TLS handshake fails.
    rogue = open_session(connect=[endpoint], security=identity(certs["rogue"], "robot-localization",
                                                               certs["rogue"] / "ca.pem"))
    try:
        replies = publish_poses_then_query(rogue, 22.0)
        assert not [r for r in replies if r.ok]
        assert str(session.info.zid()) not in {str(z) for z in rogue.info.peers_zid()}
    finally:
        rogue.close()

    # 3. A valid certificate outside the rules: connected, may query the status, may not publish the pose.
    visitor = open_session(connect=[endpoint], security=identity(good, "visitor", ca))
    try:
        assert wait_for(lambda: str(session.info.zid()) in {str(z) for z in visitor.info.peers_zid()})
        replies = publish_poses_then_query(visitor, 33.0)
        assert [r for r in replies if r.ok], "the visitor should reach the status queryable"
    finally:
        visitor.close()
    assert bus.counters()["/odom"]["received"] == 0
    assert events.empty()

    # 4. The authorised node: its pose is accepted.
    robot = open_session(connect=[endpoint], security=identity(good, "robot-localization", ca))
    try:
        assert wait_for(lambda: str(session.info.zid()) in {str(z) for z in robot.info.peers_zid()})
        publish_poses_then_query(robot, 44.0, matched=True)
        got = drain(events, 1)
        assert got and got[0].position[0] == 44.0
    finally:
        robot.close()
    c = bus.counters()["/odom"]
    assert c["accepted"] >= 1 and c["received"] == c["accepted"] + c.get("superseded", 0)  # latest-wins


def test_access_control_only_restricts_publications_on_the_inputs():
    sec = ZenohSecurity(allow_interfaces=("lo",))
    config = build_config(listen=["tcp/127.0.0.1:0"], security=sec, input_keys=input_key_exprs(BusTopics()))
    acl = json.loads(config.get_json("access_control"))
    assert acl["enabled"] and acl["default_permission"] == "deny"
    rules = {r["id"]: r for r in acl["rules"]}
    assert rules["input-publications"]["key_exprs"] == ["0/odom/**", "0/pivot/landmarks/**", "0/pivot/targets/**",
                                                        "0/plan/**"]
    assert set(rules["input-publications"]["messages"]) == {"put", "delete"}
    assert "put" not in rules["incoming-non-publications"]["messages"]
    subjects = {s["id"]: s for s in acl["subjects"]}
    given = {k: v for k, v in subjects["input-publishers"].items() if v is not None}
    assert given == {"id": "input-publishers", "interfaces": ["lo"]}


@pytest.mark.parametrize(("endpoint", "loopback"), [
    ("tcp/127.0.0.1:7447", True), ("tcp/[::1]:7447", True), ("tls/localhost:7447", True),
    ("tcp/0.0.0.0:7447", False), ("tcp/[::]:7447", False), ("tcp/robot.local:7447", False),
    ("udp/192.168.1.4:7447", False), ("unixsock-stream//tmp/z.sock", True),
])
def test_loopback_endpoints(endpoint, loopback):
    assert is_loopback(endpoint) is loopback


def test_exposure_warning_needs_tls_and_access_control(certs):
    good, ca = certs["good"], certs["ca"]
    keys = input_key_exprs(BusTopics())
    assert exposure_warning(build_config(listen=["tcp/127.0.0.1:7447"])) is None
    warning = exposure_warning(build_config(listen=["tcp/0.0.0.0:7447"]))
    assert warning is not None and "\n" not in warning
    assert "listen tcp/0.0.0.0:7447" in warning and "mutual TLS and access control" in warning
    tls_only = build_config(listen=["tls/0.0.0.0:7447"], security=identity(good, "pivotd", ca), input_keys=keys)
    assert "without access control" in exposure_warning(tls_only)
    full = identity(good, "pivotd", ca, allow_cert_common_names=("robot-localization",))
    assert exposure_warning(build_config(listen=["tls/0.0.0.0:7447"], security=full, input_keys=keys)) is None
    mixed = build_config(listen=["tls/0.0.0.0:7447", "tcp/0.0.0.0:7448"], security=full, input_keys=keys)
    assert "listen tcp/0.0.0.0:7448" in exposure_warning(mixed) and "7447" not in exposure_warning(mixed)
    client = exposure_warning(build_config(mode="client", connect=["tcp/10.0.0.2:7447"]))
    assert "connect tcp/10.0.0.2:7447" in client


def write_config(tmp_path: Path, security: str, listen: str = "tls/0.0.0.0:7447") -> Path:
    path = tmp_path / "pivotd.yaml"
    path.write_text(f"map: {{allow_empty: true}}\nzenoh:\n  listen: [{listen}]\n  security:\n{security}")
    return path


def test_security_section_loads_and_names_bad_files(tmp_path):
    pki = make_certs(tmp_path / "certs", "pivotd")
    ok = "    ca: certs/ca.pem\n    cert: certs/pivotd.pem\n    key: certs/pivotd.key\n"
    cfg = load_config(write_config(tmp_path, ok + "    allow_cert_common_names: [robot]\n"))
    sec = cfg.zenoh.security
    assert sec.ca == pki / "ca.pem" and sec.tls and sec.access_control
    assert sec.allow_cert_common_names == ("robot",)

    cases = [
        ("    ca: certs/ca.pem\n    cert: certs/pivotd.pem\n", r":4: zenoh\.security\.key: required with ca, cert"),
        (ok.replace("pivotd.key", "absent.key"), r"zenoh\.security\.key: file not found: .*absent\.key"),
        (ok.replace("ca.pem", "ca.srl"), r"zenoh\.security\.ca: .*ca\.srl: not a PEM file"),
        (ok.replace("certs/ca.pem", "certs"), r"zenoh\.security\.ca: .*certs: not a file"),
        ("    allow_cert_common_names: [robot]\n",
         r"zenoh\.security\.allow_cert_common_names: needs mutual TLS"),
        ("    allow_zids: [XYZ]\n", r"zenoh\.security\.allow_zids\[0\]: a Zenoh id"),
    ]
    for text, pattern in cases:
        with pytest.raises(ConfigError, match=pattern):
            load_config(write_config(tmp_path, text))
    (pki / "pivotd.key").chmod(0)
    try:
        with open(pki / "pivotd.key", "rb"):
            readable_anyway = True  # running as root: permissions do not stop reading
    except OSError:
        readable_anyway = False
    if not readable_anyway:
        with pytest.raises(ConfigError, match=r"zenoh\.security\.key: .*cannot be read"):
            load_config(write_config(tmp_path, ok))
    (pki / "pivotd.key").chmod(0o600)


@pytest.mark.slow
def test_shipped_secure_profile_checks_clean_and_open_listener_warns(tmp_path):
    profile = tmp_path / "secure"
    shutil.copytree(REPO / "config" / "secure", profile)
    make_certs(profile / "certs", "pivotd")
    check = [sys.executable, "-m", "pivotd.cli", "check", "--config"]
    env = dict(os.environ, PYTHONPATH=str(REPO))
    # the profile's gimbal is a serial adapter this machine does not have: checked against the mock instead
    secure = subprocess.run([*check, str(profile / "pivotd.yaml"), "--port", "mock://"], capture_output=True,
                            text=True, env=env, timeout=60)
    assert secure.returncode == 0, secure.stderr
    assert "mutual TLS, access control on the inputs" in secure.stdout
    assert "warning" not in secure.stderr

    open_cfg = tmp_path / "open.yaml"
    open_cfg.write_text("map: {allow_empty: true}\nzenoh:\n  listen: [tcp/0.0.0.0:7447]\n")
    opened = subprocess.run([*check, str(open_cfg)], capture_output=True, text=True, env=env, timeout=60)
    assert opened.returncode == 0, opened.stderr
    warnings = [line for line in opened.stderr.splitlines() if line.startswith("warning:")]
    assert len(warnings) == 1 and "listen tcp/0.0.0.0:7447" in warnings[0]
