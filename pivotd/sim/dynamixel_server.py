"""``tools/mock_gimbal --protocol dynamixel``: two simulated DYNAMIXEL X-series servos (pan and tilt) on a pty.

The first stdout line is the pty path (``--link PATH`` keeps a symlink to the current one, which is what a
host should open: after a simulated unplug the pty is new). The real ``dynamixel_sdk`` PortHandler opens it
like a U2D2. ``--fault-at SECONDS:BIT`` sets Hardware Error Status bit BIT on the pan servo.
"""

from __future__ import annotations

import argparse
import heapq
import logging
import signal
import sys
import threading
import time

from pivotd.firmware_proto.mock_server import PtyTransport, add_fault_arguments, parse_simulator_args
from pivotd.firmware_proto.realtime import CsvMessageLog
from pivotd.gimbal.dynamixel_table import CENTRE_TICKS, MAX_TICK
from pivotd.sim.dynamixel_device import DynamixelChain

log = logging.getLogger("mock_gimbal.dynamixel")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mock_gimbal --protocol dynamixel",
                                description="Two DYNAMIXEL X-series servos (Protocol 2.0) on a pty.")
    p.add_argument("--link", metavar="PATH", help="keep a symlink at PATH pointing to the current pty")
    p.add_argument("--pan-id", type=int, default=1)
    p.add_argument("--tilt-id", type=int, default=2)
    p.add_argument("--state-hz", type=float, default=50.0, help="rate of the logged pan/tilt state [Hz]")
    for axis in ("pan", "tilt"):
        p.add_argument(f"--{axis}-zero-tick", type=int, default=CENTRE_TICKS, metavar="TICK",
                       help=f"log {axis} angles around this tick, as gimbal.dynamixel.{axis}_zero_tick (default "
                            f"{CENTRE_TICKS})")
        p.add_argument(f"--{axis}-reversed", action="store_true",
                       help=f"log {axis} angles the other way, as gimbal.dynamixel.{axis}_reversed")
    add_fault_arguments(p, unit="chunk of bytes", corrupt=False, latency="delay of the servos' answers [ms]",
                        fault_bit="set Hardware Error Status bit BIT on the pan servo (2: overheating)",
                        disconnect="close the pty", reconnect="open a new pty")
    p.add_argument("--log", metavar="FILE", help="CSV log (the serial mock's columns, pivotd's pan/tilt convention)")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, injector = parse_simulator_args(parser, argv)
    if args.pan_id == args.tilt_id:
        parser.error("--pan-id and --tilt-id must differ")
    msg_log = CsvMessageLog(args.log) if args.log else None
    for tick in (args.pan_zero_tick, args.tilt_zero_tick):
        if not 0 <= tick <= MAX_TICK:
            parser.error(f"a zero tick must be 0–{MAX_TICK}, got {tick}")
    chain = DynamixelChain((args.pan_id, args.tilt_id), args.pan_id, args.tilt_id, args.state_hz, msg_log,
                           (args.pan_zero_tick, args.tilt_zero_tick), (args.pan_reversed, args.tilt_reversed))
    transport = PtyTransport(args.link)
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    faults = sorted(args.fault_at)
    outgoing: list[tuple[float, int, bytes]] = []
    order = 0
    t0 = time.monotonic()
    transport.open()
    disconnect_at, reconnect_at, connected = args.disconnect_after, None, True
    first_frame_at: float | None = None
    try:
        while not stop.is_set():
            data = transport.read(0.002) if connected else b""
            now = time.monotonic() - t0
            if data and first_frame_at is None:
                first_frame_at = now
            origin = first_frame_at if args.from_first_frame else 0.0
            if data and injector.apply(data) is not None:
                out = chain.feed(data, now, round(time.monotonic() * 1e6))
                if out:
                    order += 1
                    heapq.heappush(outgoing, (now + injector.latency_s, order, out))
            chain.step(now)
            while faults and origin is not None and faults[0][0] <= now - origin:
                _, bit = faults.pop(0)
                log.info("hardware error bit %d on servo %d at t=%.3f s", bit, args.pan_id, now)
                chain.inject_error(args.pan_id, 1 << bit, now)
            while outgoing and outgoing[0][0] <= now:
                out = heapq.heappop(outgoing)[2]
                if connected and injector.apply(out) is not None:
                    transport.write(out)
            if not connected:
                stop.wait(0.005)
            if disconnect_at is not None and origin is not None and now - origin >= disconnect_at:
                log.info("disconnecting at t=%.2f s", now)
                transport.close()
                connected, disconnect_at = False, None
                reconnect_at = None if args.reconnect_after is None else now + args.reconnect_after
            if reconnect_at is not None and now >= reconnect_at:
                log.info("reconnecting at t=%.2f s", now)
                transport.open()
                connected, reconnect_at = True, None
    finally:
        transport.close()
        if msg_log is not None:
            msg_log.close()
        log.info("stopped (packets %d, CRC errors %d)", chain.packets, chain.decoder.crc_errors)
    return 0


if __name__ == "__main__":
    sys.exit(main())
