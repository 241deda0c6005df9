"""End to end, MAVLink backend: the gimbal manager (``tools/mock_gimbal --protocol mavlink``) stalls while the real
daemon tracks the simulated robot. GIMBAL_MANAGER_SET_PITCHYAW has no validity, so what the daemon sends into the
stall is executed on resume: it must stop within a few attitude-status periods and restart from the measured state.
"""

from __future__ import annotations

import csv
import signal
import time

import pytest
from support import free_tcp_port, wait_until
from test_e2e_daemon import start_daemon, start_mock_gimbal, start_sim, write_config

from pivotd.bus.probe import BusProbe
from pivotd.config import load_config
from pivotd.daemon.control import ControlSettings

pytestmark = [pytest.mark.slow, pytest.mark.timeout(180)]


def moving(probe: BusProbe, since: float) -> bool:
    """The daemon tracks and the gimbal turned by more than a degree since ``since`` (wall clock)."""
    docs = [s for s in list(probe.statuses) if s.get("time", 0) > since and s.get("gimbal")]
    return (len(docs) >= 2 and docs[-1].get("state") == "tracking"
            and abs(docs[-1]["gimbal"]["pan_deg"] - docs[0]["gimbal"]["pan_deg"]) > 1.0)


def test_a_mavlink_manager_stall_executes_no_burst_on_resume_and_the_stream_restarts_from_the_measured_state(
        tmp_path):
    """SIGSTOP of the simulated manager for 2 s mid-motion. The daemon's link stops sending 0.1 s (5 status periods
    at 50 Hz) after the last attitude status, so on resume the manager executes at most those few setpoints (before:
    the 0.5 s state timeout's worth, ~50 at 100 Hz, in a burst); the link reconnects and the first setpoint after
    control is taken again starts where the gimbal was measured to stand."""
    endpoint = f"tcp/127.0.0.1:{free_tcp_port()}"
    mock, url, dev_log = start_mock_gimbal(tmp_path, backend="mavlink")
    config = write_config(tmp_path, endpoint, url, "mavlink")
    cfg = load_config(config)
    rate_hz = cfg.control.rate_hz
    with mock, start_daemon(config) as daemon:
        assert daemon.wait_stderr("ready", 30), daemon.output()
        probe = BusProbe.connect(endpoint, cfg.topics)
        try:
            with start_sim(endpoint, "--speed", "1.0", "--duration", "40"):
                assert wait_until(lambda: moving(probe, time.time() - 1.0), 30), daemon.output()
                mock.send_signal(signal.SIGSTOP)
                try:
                    assert wait_until(lambda: probe.status.get("link_counters", {}).get("setpoints_withheld", 0)
                                      >= 1, 10), daemon.output()
                    time.sleep(2.0)  # the stall lasts on; the link times out meanwhile
                finally:
                    mock.send_signal(signal.SIGCONT)
                assert wait_until(lambda: probe.status.get("link_counters", {}).get("reconnects", 0) >= 1
                                  and moving(probe, time.time() - 1.0), 30), daemon.output()
                counters = probe.status["link_counters"]
                assert counters["silences"] >= 1 and counters["setpoints_withheld"] >= 1, counters
            assert daemon.stop(signal.SIGTERM, timeout=20) == 0, daemon.output()
        finally:
            probe.close()
    with open(dev_log, newline="") as fh:
        rows = list(csv.DictReader(fh))
    rx = [i for i, r in enumerate(rows) if r["dir"] == "rx"]
    resume = next(k for k in range(1, len(rx)) if float(rows[rx[k]]["t_s"]) - float(rows[rx[k - 1]]["t_s"]) > 1.0)
    burst = []  # what the manager executed on resuming, before the daemon's new handshake
    for i in rx[resume:]:
        if rows[i]["type"] != "SETPOINT":
            break
        burst.append(i)
    # 5 status periods of setpoints at the control rate, + those in flight or unread when it stopped
    assert len(burst) <= 0.1 * rate_hz + 1 + 5, len(burst)
    # control taken again after the resume: the first setpoint then starts from the measured state
    taken = next(i for i in range(rx[resume], len(rows)) if rows[i]["type"] == "GIMBAL_MANAGER_CONFIGURE"
                 and "on=1" in rows[i]["detail"])
    first = next(i for i in range(taken, len(rows)) if rows[i]["dir"] == "rx" and rows[i]["type"] == "SETPOINT")
    state = next(rows[i] for i in range(first, 0, -1) if rows[i]["dir"] == "tx" and rows[i]["type"] == "STATE")
    sp = rows[first]
    dt = 1.0 / rate_hz
    ahead = ControlSettings().stall_s + dt  # the loop advances a measured state in motion by at most stall_s
    for axis, motion in (("pan", cfg.motion.pan), ("tilt", cfg.motion.tilt)):
        measured, rate = float(state[axis]), float(state[f"{axis}_rate"])
        assert abs(float(sp[axis]) - measured) <= abs(rate) * ahead + motion.max_acceleration * dt * dt + 1e-4, \
            (axis, sp, state)
        assert abs(float(sp[f"{axis}_rate"]) - rate) <= motion.max_acceleration * ahead + 1e-3, (axis, sp, state)
