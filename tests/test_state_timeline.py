"""The recording's state timeline (pivotd/daemon/timeline.py): each change once, in order, with both clocks, and
the status document at most once per period, written through the daemon's recorder to a real MCAP file."""

from __future__ import annotations

import json
import time

from mcap.reader import make_reader

from pivotd.daemon.recorder import STATE_TOPIC, STATUS_TOPIC, Recorder
from pivotd.daemon.states import DaemonState
from pivotd.daemon.timeline import STRING, StateTimeline, decode_text


def status(link: str, faults: int = 0, dead: tuple[str, ...] = ()) -> dict:
    return {"state": "tracking", "link": link, "threads_dead": list(dead),
            "gimbal": {"faults": faults, "fault_names": ["overcurrent"] if faults else [], "mode": "enabled"}}


def test_each_change_is_recorded_once_in_order_with_wall_and_monotonic_time(tmp_path):
    path = tmp_path / "t.mcap"
    rec = Recorder(path)
    timeline = StateTimeline(rec, status_period_s=3600.0)  # one status document in this test, the first
    before_wall, before_mono = time.time(), time.monotonic()
    for state in (DaemonState.STARTING, DaemonState.WAITING, DaemonState.WAITING, DaemonState.TRACKING,
                  DaemonState.TRACKING, DaemonState.HOLDING, DaemonState.TRACKING):
        timeline.state(state)
    for doc in (status("up"), status("up"), status("up", 4), status("up", 4), status("up"), status("down"),
                status("down", dead=("pivotd-planner",))):
        timeline.status(doc)
    timeline.parking()
    timeline.state(DaemonState.HOLDING)  # a control tick begun before the park target was set: not a change
    timeline.state(DaemonState.TRACKING_ERROR)  # while parking: one
    timeline.state(DaemonState.STOPPED)
    rec.close()
    with path.open("rb") as fh:
        rows = [(c.topic, s.name, m.log_time, json.loads(decode_text(m.data, c.topic)))
                for s, c, m in make_reader(fh).iter_messages()]
    assert {(topic, schema) for topic, schema, _, _ in rows} == {(STATE_TOPIC, STRING), (STATUS_TOPIC, STRING)}
    events = [doc for topic, _, _, doc in rows if topic == STATE_TOPIC]
    assert [(e["kind"], e["value"], e["previous"]) for e in events] == [
        ("state", "starting", None), ("state", "waiting", "starting"), ("state", "tracking", "waiting"),
        ("state", "holding", "tracking"), ("state", "tracking", "holding"),
        ("link", "up", None), ("faults", 0, None), ("threads_dead", [], None),
        ("faults", 4, 0), ("faults", 0, 4), ("link", "down", "up"), ("threads_dead", ["pivotd-planner"], []),
        ("state", "parking", "tracking"), ("state", "tracking-error", "parking"),
        ("state", "stopped", "tracking-error")]
    assert events[8]["names"] == ["overcurrent"] and events[8]["mode"] == "enabled"
    walls = [e["wall_time"] for e in events]
    monos = [e["monotonic"] for e in events]
    assert walls == sorted(walls) and monos == sorted(monos)
    assert walls[0] >= before_wall and monos[0] >= before_mono
    # the log time is the event's wall time
    assert [lt for topic, _, lt, _ in rows if topic == STATE_TOPIC] == [int(w * 1e9) for w in walls]
    statuses = [doc for topic, _, _, doc in rows if topic == STATUS_TOPIC]
    assert statuses == [status("up")]
