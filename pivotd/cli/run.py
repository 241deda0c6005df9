"""``pivotd [run] --config FILE``: run the daemon (docs/CLI.md)."""

from __future__ import annotations

import argparse
import logging
from pathlib import Path

DEFAULT_CONFIG = Path("/etc/pivotd/pivotd.yaml")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", type=Path, default=DEFAULT_CONFIG, help=f"YAML config (default {DEFAULT_CONFIG})")
    parser.add_argument("--port", help="gimbal pyserial URL, overrides gimbal.port (/dev/ttyUSB0, socket://, mock://)")
    parser.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to connect to, e.g. tcp/127.0.0.1:7447 (repeatable)")
    parser.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                        help="Zenoh endpoint to listen on (repeatable)")
    parser.add_argument("--record", type=Path, help="write an MCAP recording of inputs and outputs to this file")
    parser.add_argument("--log-level", help="override logging.level (DEBUG, INFO, WARNING, ERROR)")


def run(args: argparse.Namespace) -> int:
    from pivotd.daemon import logqueue
    from pivotd.daemon.daemon import Daemon, RunOverrides

    # No thread of the daemon may block in a log call (a log pipe nobody reads): a bounded, dropping queue.
    logs = logqueue.install()
    try:
        overrides = RunOverrides(port=args.port, connect=tuple(args.connect), listen=tuple(args.listen),
                                 record=args.record)
        daemon = Daemon(args.config, overrides)
        if not args.log_level:
            logging.getLogger().setLevel(daemon.cfg.logging.level.upper())
        return daemon.run()
    finally:
        logs.stop()
