"""The daemon's log path (pivotd/daemon/logqueue.py): a log call never waits for the log stream; a full queue drops
records and counts them; the listener reports the drops once the stream drains."""

from __future__ import annotations

import contextlib
import logging
import os
import re
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
        # the oldest went out, and every record is either written or counted as dropped (which ones a full queue
        # drops depends on when the listener gets the CPU; none is lost silently)
        written = {int(m) for m in re.findall(rb"record (\d+)\n", bytes(got))}
        assert 0 in written and len(written) + lq.dropped == 200, (sorted(written), lq.dropped)
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
    # it now drains the queue at once; let it end before its fd is closed (a later test's pipe may get the number)
    assert wait_until(lambda: (lq.stop(timeout=1.0), not lq._thread.is_alive())[1], 30)
    os.close(w)


def journal_queue(monkeypatch, matching: bool) -> tuple[LogQueue, int]:
    r, w = os.pipe()
    st = os.fstat(w if matching else r)  # the read end: another inode, so not the journal's stream
    monkeypatch.setenv("JOURNAL_STREAM", f"{st.st_dev}:{st.st_ino + (0 if matching else 1)}")
    lq = LogQueue(fd=w)
    lq.start()
    return lq, r


def read_lines(r: int, lq: LogQueue) -> list[str]:
    lq.stop()
    os.set_blocking(r, False)
    data = b""
    with contextlib.suppress(BlockingIOError):
        while chunk := os.read(r, 65536):
            data += chunk
    return data.decode().splitlines()


def log_some(lq: LogQueue, name: str) -> None:
    logger = logging.getLogger(name)
    logger.propagate = False
    logger.addHandler(lq.handler)
    logger.setLevel(logging.DEBUG)
    logger.debug("d")
    logger.info("i")
    logger.warning("w")
    try:
        raise ValueError("boom")
    except ValueError:
        logger.exception("e")
    logger.critical("c")
    logger.removeHandler(lq.handler)


def test_on_the_journal_each_line_has_its_priority_and_no_timestamp(monkeypatch):
    lq, r = journal_queue(monkeypatch, matching=True)
    log_some(lq, "test.journal")
    lines = read_lines(r, lq)
    assert lines[:4] == ["<7>DEBUG test.journal: d", "<6>INFO test.journal: i", "<4>WARNING test.journal: w",
                         "<3>ERROR test.journal: e"]
    traceback = lines[4:-1]  # every line of the traceback is an error line too
    assert traceback[0] == "<3>Traceback (most recent call last):" and traceback[-1] == "<3>ValueError: boom"
    assert all(line.startswith("<3>") for line in traceback)
    assert lines[-1] == "<2>CRITICAL test.journal: c"


def test_off_the_journal_lines_keep_their_timestamp_and_no_prefix(monkeypatch):
    lq, r = journal_queue(monkeypatch, matching=False)
    log_some(lq, "test.notjournal")
    lines = read_lines(r, lq)
    assert re.match(r"^\d{4}-\d\d-\d\d \d\d:\d\d:\d\d,\d{3} DEBUG test.notjournal: d$", lines[0]), lines
    assert not any(line.startswith("<") for line in lines)
