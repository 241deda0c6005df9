"""The daemon's state changes are logged once each (pivotd/daemon/state_log.py), not per tick or per message."""

from __future__ import annotations

import logging
import re

import numpy as np

from pivotd.bus.messages import PoseSample
from pivotd.daemon.state_log import StateLog
from pivotd.daemon.states import DaemonState as S

TIMEOUT = 0.5


def pose(rx: float) -> PoseSample:
    return PoseSample(stamp=rx, frame_id="map", position=np.array([1.234, 2.0, 0.0]), quat=np.array([0, 0, 0, 1.0]),
                      rx_time=rx)


def test_each_state_change_is_one_line(caplog):
    caplog.set_level(logging.DEBUG, logger="test.state_log")
    states = StateLog("/odom", "/plan", logging.getLogger("test.state_log"))
    t = 0.0
    for _ in range(50):  # waiting for a pose
        states.tick(t, S.WAITING, None, TIMEOUT)
        t += 0.01
    for k in range(100):  # poses at 50 Hz, a path now and then, tracking
        p = pose(t - 0.01 * (k % 2))
        states.pose(p)
        if k % 20 == 0:
            states.path(7)
        states.tick(t, S.HOLDING if k < 3 else S.TRACKING, p, TIMEOUT)
        t += 0.01
    last = pose(t)
    for _ in range(200):  # 2 s without a pose: holding
        t += 0.01
        states.tick(t, S.HOLDING if t - last.rx_time > TIMEOUT else S.TRACKING, last, TIMEOUT)
    for _ in range(100):  # poses again
        t += 0.01
        p = pose(t)
        states.pose(p)
        states.tick(t, S.TRACKING, p, TIMEOUT)
    lines = [(r.levelno, r.getMessage()) for r in caplog.records]
    assert re.fullmatch(r"no pose on /odom for 0\.5\d s \(more than control.pose_timeout_s 0\.50 s\): holding the "
                        r"gimbal still until poses resume", lines[3][1]), lines
    lines[3] = (lines[3][0], "stale")
    assert lines == [
        (logging.INFO, "first pose on /odom: robot at [1.23, 2.0, 0.0]"),
        (logging.INFO, "first path on /plan: 7 poses"),
        (logging.INFO, "tracking: the gimbal follows the plan"),
        (logging.WARNING, "stale"),
        (logging.INFO, "poses on /odom again after a gap of 2.01 s: the hold ends"),
    ]


def test_a_second_gap_is_logged_again(caplog):
    caplog.set_level(logging.DEBUG, logger="test.state_log2")
    states = StateLog("/odom", "/plan", logging.getLogger("test.state_log2"))
    for gap_start in (0.0, 10.0):
        stale = pose(gap_start)
        for k in range(1, 11):
            states.tick(gap_start + 0.1 * k, S.HOLDING, stale, TIMEOUT)
        states.tick(gap_start + 1.05, S.TRACKING, pose(gap_start + 1.05), TIMEOUT)
    messages = [r.getMessage() for r in caplog.records if "pose" in r.getMessage()]
    assert [m.split(" ")[0] for m in messages] == ["no", "poses", "no", "poses"], messages
