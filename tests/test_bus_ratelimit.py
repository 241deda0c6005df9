"""Rate-limited warnings: one per key and interval, with the suppressed count reported."""

import logging

from pivotd.bus.ratelimit import RateLimitedLog


def test_rate_limited_log_suppresses_and_reports(caplog):
    now = [0.0]
    rl = RateLimitedLog(logging.getLogger("test.ratelimit"), interval=3600.0, clock=lambda: now[0])
    with caplog.at_level(logging.WARNING, logger="test.ratelimit"):
        assert rl.warning("a", "first") is True
        assert [rl.warning("a", "again") for _ in range(3)] == [False, False, False]
        assert rl.warning("b", "other key") is True
        now[0] = 3599.0
        assert rl.warning("a", "not yet") is False
        now[0] = 3600.0  # the interval has passed
        assert rl.warning("a", "later") is True
    assert [r.getMessage() for r in caplog.records] == ["first", "other key", "later (4 similar messages suppressed)"]


def test_rate_limited_exception_carries_the_traceback(caplog):
    rl = RateLimitedLog(logging.getLogger("test.ratelimit"), interval=3600.0, clock=lambda: 0.0)
    with caplog.at_level(logging.ERROR, logger="test.ratelimit"):
        for _ in range(3):
            try:
                {}["missing"]
            except KeyError:
                rl.exception("tick", "tick failed")
    assert len(caplog.records) == 1
    record = caplog.records[0]
    assert record.levelno == logging.ERROR and record.exc_info is not None and record.exc_info[0] is KeyError
    assert "Traceback" in caplog.text and "KeyError: 'missing'" in caplog.text
