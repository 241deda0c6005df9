"""``pivotd status`` output from status documents, and its one-line errors."""

from __future__ import annotations

import subprocess

import pytest
from support import PYTHON, REPO, child_env, free_tcp_port

from pivotd.cli.status import dropped_inputs, format_table, link_drops


def document(name: str, **changes) -> dict:
    doc = {
        "name": name, "state": "tracking", "link": "up", "pose_age_s": 0.0123, "fault_episodes": 0,
        "gimbal": {"fault_names": []},
        "planner": {"plans": 42, "visible_now": 17, "solve_ms_p50": 12.345, "solve_ms_p99": 40.0},
        "control": {"jitter_ms_p99": 0.456},
        "bus": {f"/{name}/odom": {"received": 10, "accepted": 10}, f"/{name}/plan": {"received": 1, "accepted": 1}},
        "last_error": "",
    }
    doc.update(changes)
    return doc


def test_table_has_one_row_per_daemon_with_its_numbers():
    bad = document("robot2", state="fault", pose_age_s=None, fault_episodes=2,
                   gimbal={"fault_names": ["overcurrent"]}, planner={"plans": 0},
                   bus={"/robot2/odom": {"received": 9, "accepted": 4, "dropped_wrong_type": 3,
                                         "dropped_bad_frame": 2}},
                   last_error="reload: bad.yaml:3: pivot.fov_deg: must be > 0")
    lines = format_table({"robot1": document("robot1"), "robot2": bad}).splitlines()
    head = lines[0].split("  ")
    assert [h.strip() for h in head if h.strip()][:5] == ["NAME", "STATE", "LINK", "POSE AGE", "VISIBLE"]
    row1, row2 = lines[1], lines[2]
    assert row1.split()[:8] == ["robot1", "tracking", "up", "0.01", "s", "17", "42", "12.3/40.0"]
    assert row1.split()[8:] == ["0.46", "none", "0", "-"]  # no framed gimbal link in this document
    assert row2.split()[:7] == ["robot2", "fault", "up", "-", "-", "0", "-/-"]
    assert row2.split()[-5:] == ["overcurrent", "(2", "seen)", "5", "-"]
    assert lines[3] == "robot2: /robot2/odom: 5 dropped (bad_frame 2, wrong_type 3)"
    assert lines[4] == "robot2: last error: reload: bad.yaml:3: pivot.fov_deg: must be > 0"
    assert len(lines) == 5
    # columns line up: every row starts each column where the heading does
    starts = [lines[0].index(h) for h in ("STATE", "LINK", "POSE AGE")]
    for row in (row1, row2):
        assert [row[s - 2:s] for s in starts] == ["  "] * 3 and all(row[s] != " " for s in starts)


def test_dropped_inputs_sums_the_reasons_per_topic():
    doc = document("r", bus={"/a": {"received": 5, "accepted": 1, "dropped_x": 3, "dropped_y": 1},
                             "/b": {"received": 2, "accepted": 2}})
    assert dropped_inputs(doc) == {"/a": 4}
    assert dropped_inputs({"state": "starting"}) == {}


def test_gimbal_link_decode_drops_show_per_daemon_with_their_reasons():
    counters = {"frames_received": 900, "crc_errors": 3, "decode_drops": 5, "drop_framing": 1, "drop_length": 0,
                "drop_crc": 3, "drop_version": 0, "drop_unknown_type": 0, "drop_payload": 1, "retries": 7}
    clean = dict(counters, crc_errors=0, decode_drops=0, drop_framing=0, drop_crc=0, drop_payload=0)
    docs = {"r1": document("r1", link_counters=counters), "r2": document("r2", link_counters=clean),
            "r3": document("r3", link_counters={"sync_reads": 4, "comm_errors": 1})}
    assert link_drops(docs["r1"]) == {"crc": 3, "framing": 1, "payload": 1}
    assert link_drops(docs["r2"]) == {} and link_drops({"state": "starting"}) == {}
    lines = format_table(docs).splitlines()
    assert lines[0].endswith("DROPPED  LINK DROPS")
    assert [row.split()[-1] for row in lines[1:4]] == ["5", "0", "-"]  # r3's link has no frame decoder
    assert lines[4:] == ["r1: gimbal link: 5 frames dropped (crc 3, framing 1, payload 1)"]


def run_status(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([PYTHON, "-m", "pivotd.cli", "status", *args], capture_output=True, text=True,
                          env=child_env(), cwd=str(REPO), timeout=60)


@pytest.mark.slow
def test_no_router_is_one_line_error():
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"  # nobody listens there
    out = run_status("--connect", endpoint, "--timeout", "0.5")
    assert out.returncode == 2
    lines = out.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("pivotd status: error: cannot open Zenoh session (connect "
                                                   f"{endpoint})"), out.stderr


@pytest.mark.slow
def test_bad_options_are_one_line_errors():
    out = run_status("--connect", "nonsense")
    assert out.returncode == 2 and out.stderr.strip().endswith("invalid Zenoh --connect endpoint 'nonsense' "
                                                               "(expected e.g. tcp/127.0.0.1:7447)")
    out = run_status("--timeout", "0")
    assert out.returncode == 2 and out.stderr.strip() == "pivotd status: error: --timeout 0.0: must be > 0"
    out = run_status("--name", "robot*")
    assert out.returncode == 2 and out.stderr.strip() == (
        "pivotd status: error: --name 'robot*': a daemon name has letters, digits, '_' and '-' only")
    out = run_status("--name", "a", "--all")
    assert out.returncode == 2 and "not allowed with argument" in out.stderr


def test_a_daemon_reports_its_last_error_with_its_age_and_whether_it_cleared_and_its_failures():
    err = {"message": "reload: bad.yaml:3: pivot.fov_deg: must be > 0", "source": "reload", "time": 990.0,
           "resolved_time": None}
    now = document("r1", time=1002.34, last_error=err)
    cleared = document("r2", time=1002.34, last_error=dict(err, resolved_time=995.0))
    failing = document("r3", time=1000.0, last_error=None, threads_dead=["pivotd-control"],
                       recording={"state": "failed", "path": "/data/run.mcap", "messages": 4711, "bytes": 1 << 20,
                                  "dropped": 12, "errors": 1, "error": "No space left on device (errno 28)"},
                       logging={"dropped": 37, "queued": 10000}, link_counters={"host_stalls": 2})
    lines = format_table({"r1": now, "r2": cleared, "r3": failing}).splitlines()[4:]
    assert lines == [
        "r1: last error (12.3 s ago): reload: bad.yaml:3: pivot.fov_deg: must be > 0",
        "r2: last error (12.3 s ago, resolved): reload: bad.yaml:3: pivot.fov_deg: must be > 0",
        "r3: threads died: pivotd-control (nothing is controlled)",
        "r3: recording failed: No space left on device (errno 28) (/data/run.mcap; 4711 messages recorded, 12 not)",
        "r3: 37 log records dropped (the log output was not read fast enough)",
        "r3: host stalled 2 times while the gimbal link was up (not counted as link losses)",
    ]
