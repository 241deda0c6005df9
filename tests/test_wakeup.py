"""The signal-safe wake-up primitives of the daemon (pivotd.daemon.wakeup)."""

from __future__ import annotations

import threading

from support import wait_until

from pivotd.daemon.wakeup import StopFlag


def test_stop_flag_wakes_every_waiter_and_stays_set() -> None:
    flag = StopFlag()
    assert not flag.is_set() and flag.wait(0.0) is False
    woken: list[bool] = []
    waiters = [threading.Thread(target=lambda: woken.append(flag.wait(None))) for _ in range(3)]
    for t in waiters:
        t.start()
    flag.set()
    for t in waiters:
        t.join(30)
    assert woken == [True, True, True]
    assert flag.is_set() and flag.wait(0.0) is True and flag.wait(10.0) is True
    flag.set()  # setting it again is harmless
    assert wait_until(flag.is_set, 1)
