"""The daemon's log path (pivotd/daemon/logqueue.py): a log call never waits for the log stream; a full queue drops
records and counts them; the listener reports the drops once the stream drains."""

from __future__ import annotations

import logging
import os
import threading

from support import wait_until

from pivotd.daemon.logqueue import LogQueue


def fill(fd: int) -> None:
    os.set_blocking(fd, False)
    try:
        while True:
            os.write(fd, b"x" * 4096)
    except BlockingIOError:
        pass
    try:
        while True:
            os.write(fd, b"x")
    except BlockingIOError:
        pass
    os.set_blocking(fd, True)


def test_logging_into_a_stream_nobody_reads_never_blocks_drops_and_counts_and_reports_after():
    r, w = os.pipe()
    fill(w)  # the listener's first write blocks: nobody reads
    lq = LogQueue(fd=w, maxsize=5)
    lq.start()
    logger = logging.getLogger("test.logqueue")
    logger.propagate = False
    logger.addHandler(lq.handler)
    logger.setLevel(logging.INFO)
    try:
        done = threading.Event()

        def log_many() -> None:
            for i in range(200):
                logger.info("record %d", i)
            done.set()

        threading.Thread(target=log_many, daemon=True).start()
        assert done.wait(30), "a log call blocked on the full stream"
        # the queue holds five, the listener at most one (blocked writing it): the rest were dropped and counted
        assert 200 - 5 - 1 <= lq.dropped <= 200 - 5, lq.status()
        got = bytearray()

        def drained() -> bool:
            os.set_blocking(r, False)
            try:
                while chunk := os.read(r, 1 << 16):
                    got.extend(chunk)
            except BlockingIOError:
                pass
            return f"{lq.dropped} log records dropped".encode() in got

        assert wait_until(drained, 30), bytes(got[-500:])
        assert b"record 0\n" in got and b"record 199" not in got  # a full queue drops the newest records
    finally:
        logger.removeHandler(lq.handler)
        lq.stop(timeout=2.0)
        os.close(r)
        os.close(w)


def test_stop_returns_while_the_stream_is_stuck():
    r, w = os.pipe()
    fill(w)
    lq = LogQueue(fd=w, maxsize=2)
    lq.start()
    for i in range(10):
        lq.handler.handle(logging.makeLogRecord({"msg": f"line {i}", "levelno": logging.INFO}))
    finished = threading.Event()
    threading.Thread(target=lambda: (lq.stop(timeout=0.5), finished.set()), daemon=True).start()
    assert finished.wait(30)
    os.close(r)  # the listener's write fails (EPIPE): it goes on quietly
    os.close(w)
