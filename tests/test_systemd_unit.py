"""systemd/pivotd.service: required settings present; `systemd-analyze verify` clean where available."""

import re
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


def test_a_router_is_ordered_before_but_not_required(unit):
    """pivotd waits for its Zenoh router by itself (tests/test_e2e_late_router.py): the unit orders itself after a
    local router but neither requires nor wants one, so a router that is late or absent costs no restart."""
    u = unit["Unit"]
    assert "zenohd.service" in " ".join(u["After"]).split()
    assert not any("zenohd" in v for key in ("Requires", "Wants", "BindsTo", "Requisite") for v in u.get(key, []))
    assert int(u["StartLimitBurst"][0]) >= 3 and u["StartLimitIntervalSec"]


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
    # verify also checks that ExecStart (and ExecStartPre) exist; point them at a binary present on this machine.
    text = UNIT.read_text().replace("=/opt/pivotd/bin/pivotd", "=/bin/true")
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


def test_resource_limits_and_stop_behaviour(unit):
    service = unit["Service"]
    units = {"K": 2**10, "M": 2**20, "G": 2**30}

    def size(text: str) -> int:
        return int(float(text[:-1]) * units[text[-1]]) if text[-1] in units else int(text)

    high, hard = size(service["MemoryHigh"][0]), size(service["MemoryMax"][0])
    # Room for a 1M-landmark map (<= 200 MB measured) and below what a robot computer can spare.
    assert 400 * 2**20 <= high < hard <= 2 * 2**30
    assert service["MemorySwapMax"] == ["0"]
    assert 64 <= int(service["TasksMax"][0]) <= 1024
    assert service["KillMode"] == ["mixed"]  # SIGTERM to the daemon alone: it parks, then stops its planner
    assert "~@privileged" in service["SystemCallFilter"]


def _offline_security_supported() -> tuple[bool, str]:
    exe = shutil.which("systemd-analyze")
    if exe is None:
        return False, "systemd-analyze is not installed"
    version = subprocess.run([exe, "--version"], capture_output=True, text=True, timeout=30).stdout.split()
    number = int(version[1]) if len(version) > 1 and version[1].isdigit() else 0
    if number < 250:
        return False, f"systemd-analyze {number} has no 'security --offline' (needs systemd >= 250)"
    return True, ""


@pytest.mark.skipif(not _offline_security_supported()[0], reason=_offline_security_supported()[1])
def test_systemd_analyze_security_exposure(tmp_path):
    copy = tmp_path / "pivotd.service"
    copy.write_text(UNIT.read_text())
    result = subprocess.run(["systemd-analyze", "security", "--offline=yes", "--no-pager", str(copy)],
                            capture_output=True, text=True, timeout=60, cwd=tmp_path)
    assert result.returncode == 0, result.stderr
    match = re.search(r"Overall exposure level for pivotd\.service: (\d+(?:\.\d+)?)", result.stdout)
    assert match, result.stdout[-2000:]
    assert float(match.group(1)) <= 2.5, result.stdout
    passed = {line.split()[1] for line in result.stdout.splitlines() if line.startswith("✓")}
    for setting in ("NoNewPrivileges=", "ProtectSystem=", "ProtectHome=", "PrivateTmp=", "RestrictSUIDSGID=",
                    "SystemCallFilter=~@privileged", "CapabilityBoundingSet=~CAP_SYS_ADMIN", "ProtectKernelModules=",
                    "RestrictNamespaces=~user", "LockPersonality="):
        assert setting in passed, (setting, result.stdout)
