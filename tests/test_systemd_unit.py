"""systemd/pivotd.service: required settings present; `systemd-analyze verify` clean where available."""

import shutil
import subprocess
from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
UNIT = REPO / "systemd" / "pivotd.service"


def parse_unit(text: str) -> dict[str, dict[str, list[str]]]:
    """INI-like unit parser: section -> key -> list of values (keys may repeat)."""
    sections: dict[str, dict[str, list[str]]] = {}
    current = None
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith(("#", ";")):
            continue
        if line.startswith("[") and line.endswith("]"):
            current = sections.setdefault(line[1:-1], {})
            continue
        assert current is not None, f"setting outside a section: {line}"
        key, sep, value = line.partition("=")
        assert sep, f"not a key=value line: {line}"
        current.setdefault(key.strip(), []).append(value.strip())
    return sections


@pytest.fixture(scope="module")
def unit() -> dict[str, dict[str, list[str]]]:
    return parse_unit(UNIT.read_text())


def test_service_type_watchdog_and_restart(unit):
    service = unit["Service"]
    assert service["Type"] == ["notify"]
    assert service["NotifyAccess"] == ["main"]
    assert service["Restart"] == ["on-failure"]
    watchdog = service["WatchdogSec"][0]
    assert watchdog.endswith("s") and 0 < float(watchdog[:-1]) <= 10
    assert service["ExecReload"] == ["/bin/kill -HUP $MAINPID"]
    assert "--config /etc/pivotd/pivotd.yaml" in service["ExecStart"][0]
    assert service["ExecStart"][0].split()[0].startswith("/")
    assert unit["Install"]["WantedBy"] == ["multi-user.target"]


def test_dedicated_user_with_serial_access(unit):
    service = unit["Service"]
    assert service["User"] == ["pivotd"]
    assert service["DynamicUser"] == ["no"]
    assert "dialout" in service["SupplementaryGroups"][0].split()
    assert service["DevicePolicy"] == ["closed"]
    assert set(service["DeviceAllow"]) == {"char-ttyUSB rw", "char-ttyACM rw"}


def test_sandboxing(unit):
    service = unit["Service"]
    for key, value in {
        "ProtectSystem": "strict",
        "ProtectHome": "yes",
        "PrivateTmp": "yes",
        "NoNewPrivileges": "yes",
        "ProtectKernelTunables": "yes",
        "ProtectControlGroups": "yes",
        "RestrictNamespaces": "yes",
    }.items():
        assert service[key] == [value], key
    families = set(service["RestrictAddressFamilies"][0].split())
    assert families == {"AF_UNIX", "AF_INET", "AF_INET6", "AF_NETLINK"}
    assert service["CapabilityBoundingSet"] == [""]
    # With ProtectSystem=strict the only writable place is the state directory.
    assert service["StateDirectory"] == ["pivotd"]


def test_stop_timeout_leaves_room_to_park(unit):
    from pivotd.config import load_config

    stop = float(unit["Service"]["TimeoutStopSec"][0].rstrip("s"))
    park = load_config(REPO / "config" / "spot.yaml").gimbal.park_timeout_s
    assert stop >= park + 5


@pytest.mark.skipif(shutil.which("systemd-analyze") is None, reason="systemd-analyze not installed")
@pytest.mark.slow
def test_systemd_analyze_verify_is_clean(tmp_path):
    # verify also checks that ExecStart exists; point it at a binary present on this machine.
    text = UNIT.read_text().replace("ExecStart=/opt/pivotd/bin/pivotd", "ExecStart=/bin/true")
    assert text != UNIT.read_text()
    copy = tmp_path / "pivotd.service"
    copy.write_text(text)
    result = subprocess.run(
        ["systemd-analyze", "verify", str(copy)], capture_output=True, text=True, timeout=60, cwd=tmp_path
    )
    problems = [line for line in (result.stdout + result.stderr).splitlines() if "pivotd.service" in line]
    assert result.returncode == 0, result.stderr
    assert problems == []


def test_parser_catches_broken_units():
    with pytest.raises(AssertionError):
        parse_unit("Type=notify\n")
    assert parse_unit("[Service]\nDeviceAllow=a\nDeviceAllow=b\n")["Service"]["DeviceAllow"] == ["a", "b"]
