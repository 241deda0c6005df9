"""Rate-limited warnings: one per key and interval, with the suppressed count reported."""

import logging

from pivotd.bus.ratelimit import RateLimitedLog


def test_rate_limited_log_suppresses_and_reports(caplog):
    rl = RateLimitedLog(logging.getLogger("test.ratelimit"), interval=3600.0)
    with caplog.at_level(logging.WARNING, logger="test.ratelimit"):
        assert rl.warning("a", "first") is True
        assert [rl.warning("a", "again") for _ in range(3)] == [False, False, False]
        assert rl.warning("b", "other key") is True
        rl._last["a"] -= 7200.0  # as if the interval had passed
        assert rl.warning("a", "later") is True
    assert [r.getMessage() for r in caplog.records] == ["first", "other key", "later (3 similar messages suppressed)"]
