"""``tools/mock_gimbal --protocol mavlink``: the MAVLink gimbal manager + device of :mod:`pivotd.sim.mavlink_device`
in real time on a UDP port on loopback.

The first stdout line is the bound UDP port (connect with ``udpout:127.0.0.1:PORT``); the simulator answers the
address the last datagram came from. Link faults (drop, bit flips, latency) apply per datagram in both
directions; a simulated unplug (``--disconnect-after``) ignores everything and sends nothing until
``--reconnect-after``; ``--fault-at SECONDS:BIT`` sets GIMBAL_DEVICE_ERROR_FLAGS bit BIT for ``--fault-duration``.
``--yaw-frame`` picks the frame the attitude status reports yaw in, on a vehicle at ``--heading-deg`` turning at
``--heading-rate-deg-s``.
"""

from __future__ import annotations

import argparse
import heapq
import logging
import math
import select
import signal
import socket
import sys
import threading
import time
from typing import Any

from pivotd.firmware_proto.mock_server import add_fault_arguments, parse_simulator_args
from pivotd.firmware_proto.realtime import CsvMessageLog, FaultInjector
from pivotd.gimbal.kinematics import JointLimits
from pivotd.gimbal.mavlink_link import load_mavutil
from pivotd.sim.mavlink_device import MavlinkGimbalModel, StatusFrame

log = logging.getLogger("mock_gimbal.mavlink")


class _Collector:
    """File-like sink for pymavlink's ``MAVLink.send``: keeps the packed bytes."""

    def __init__(self) -> None:
        self.data = b""

    def write(self, data: bytes) -> None:
        self.data += bytes(data)


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mock_gimbal --protocol mavlink",
                                description="MAVLink Gimbal Protocol v2 manager + device simulator on UDP.")
    p.add_argument("--udp", metavar="HOST:PORT", default="127.0.0.1:0", help="bind here (port 0: pick one, print it)")
    p.add_argument("--state-hz", type=float, default=50.0, help="GIMBAL_DEVICE_ATTITUDE_STATUS rate [Hz]")
    add_fault_arguments(p, unit="datagram", fault_bit="set GIMBAL_DEVICE_ERROR_FLAGS bit BIT (5 = motor error)",
                        disconnect="go silent", reconnect="answer again")
    p.add_argument("--fault-duration", type=float, default=2.0, help="seconds until the device clears a failure")
    p.add_argument("--pan-range-deg", type=float, nargs=2, default=(-180.0, 180.0), metavar=("MIN", "MAX"),
                   help="device pan range in pivotd's convention (positive left) [deg]")
    p.add_argument("--tilt-range-deg", type=float, nargs=2, default=(-90.0, 90.0), metavar=("MIN", "MAX"),
                   help="device tilt range in pivotd's convention (positive down) [deg]")
    p.add_argument("--vmax-deg-s", type=float, default=180.0, help="axis rate limit [deg/s]")
    p.add_argument("--amax-deg-s2", type=float, default=720.0, help="axis acceleration limit [deg/s²]")
    p.add_argument("--setpoint-timeout-ms", type=float, default=250.0,
                   help="without setpoints for this long the device holds its angle")
    p.add_argument("--yaw-frame", choices=[f.value for f in StatusFrame], default=StatusFrame.VEHICLE.value,
                   help="frame of the reported yaw: vehicle / earth (YAW_IN_*_FRAME, delta_yaw = the heading), "
                        "earth-no-delta (delta_yaw NaN), legacy-lock / legacy-follow (no frame flag, YAW_LOCK set or "
                        "not), both-flags (not allowed)")
    p.add_argument("--heading-deg", type=float, default=0.0,
                   help="the vehicle's heading, clockwise from North [deg]")
    p.add_argument("--heading-rate-deg-s", type=float, default=0.0, help="the vehicle's turn rate [deg/s]")
    p.add_argument("--log", metavar="FILE", help="CSV log (the serial mock's columns, pivotd's pan/tilt convention)")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


class MavlinkServer:
    """The model on a UDP socket, stepped by :meth:`serve` on the calling thread until ``stop`` is set."""

    def __init__(self, model: MavlinkGimbalModel, sock: socket.socket, injector: FaultInjector,
                 faults_at: list[tuple[float, int]], fault_duration: float) -> None:
        self.model = model
        self.sock = sock
        self.injector = injector
        self.faults_at = sorted(faults_at)
        self.fault_duration = fault_duration
        self.from_first_frame = False
        self.first_frame_at: float | None = None  # device time of the host's first datagram
        self.mavutil = load_mavutil()
        self.out = _Collector()
        self.mav = self.mavutil.mavlink.MAVLink(self.out, srcSystem=model.system_id, srcComponent=model.component_id)
        self.mav.robust_parsing = True
        self.peer: tuple[str, int] | None = None
        self.silent = False
        self._incoming: list[tuple[float, int, bytes, int]] = []
        self._outgoing: list[tuple[float, int, bytes]] = []
        self._order = 0
        self._t0 = time.monotonic()

    def elapsed(self) -> float:
        return time.monotonic() - self._t0

    def _queue_out(self, msgs: list[Any], now: float) -> None:
        for msg in msgs:
            self.mav.send(msg)
            data, self.out.data = self.out.data, b""
            data = self.injector.apply(data)
            if data is not None:
                self._order += 1
                heapq.heappush(self._outgoing, (now + self.injector.latency_s, self._order, data))

    def poll(self, timeout: float) -> None:
        """Wait up to ``timeout`` s for a datagram, then handle everything due."""
        ready, _, _ = select.select([self.sock], [], [], max(0.0, timeout))
        now = self.elapsed()
        if ready:
            try:
                data, addr = self.sock.recvfrom(65535)
            except OSError:
                data, addr = b"", None
            if data and not self.silent:
                if self.first_frame_at is None:
                    self.first_frame_at = now
                self.peer = addr
                sent_us = round(time.monotonic() * 1e6)
                data = self.injector.apply(data)
                if data is not None:
                    self._order += 1
                    heapq.heappush(self._incoming, (now + self.injector.latency_s, self._order, data, sent_us))
        while self._incoming and self._incoming[0][0] <= now:
            _, _, data, sent_us = heapq.heappop(self._incoming)
            for msg in self.mav.parse_buffer(data) or []:
                if msg.get_type() != "BAD_DATA":
                    self._queue_out(self.model.handle(msg, now, sent_us), now)
        t0 = self.origin()
        while self.faults_at and t0 is not None and self.faults_at[0][0] <= now - t0:
            _, bit = self.faults_at.pop(0)
            log.info("setting failure flag bit %d at t=%.3f s", bit, now)
            self.model.inject_failure(1 << bit, now, self.fault_duration)
        self._queue_out(self.model.step(now), now)
        while self._outgoing and self._outgoing[0][0] <= now:
            data = heapq.heappop(self._outgoing)[2]
            if self.peer is not None and not self.silent:
                try:
                    self.sock.sendto(data, self.peer)
                except OSError as exc:
                    log.debug("datagram lost: %s", exc)

    def origin(self) -> float | None:
        """Device time the fault and disconnect timers count from (None: not yet, waiting for the first datagram)."""
        return self.first_frame_at if self.from_first_frame else 0.0

    def next_due(self) -> float:
        """Device time [s] of the next thing to do."""
        times = [min(self.model._next.values()), self.elapsed() + 0.05]
        for heap in (self._incoming, self._outgoing):
            if heap:
                times.append(heap[0][0])
        t0 = self.origin()
        if self.faults_at and t0 is not None:
            times.append(t0 + self.faults_at[0][0])
        return min(times)


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, injector = parse_simulator_args(parser, argv)
    host, _, port = args.udp.rpartition(":")
    if not port.isdigit():
        parser.error(f"--udp expects HOST:PORT, got {args.udp!r}")
    pan, tilt = args.pan_range_deg, args.tilt_range_deg
    if pan[1] <= pan[0] or tilt[1] <= tilt[0]:
        parser.error("--pan-range-deg / --tilt-range-deg: MAX must be > MIN")
    limits = JointLimits(*(math.radians(a) for a in (*pan, *tilt)))
    msg_log = CsvMessageLog(args.log) if args.log else None
    model = MavlinkGimbalModel(limits, math.radians(args.vmax_deg_s), math.radians(args.amax_deg_s2), args.state_hz,
                               args.setpoint_timeout_ms / 1000.0, log=msg_log, yaw_frame=StatusFrame(args.yaw_frame),
                               heading=math.radians(args.heading_deg),
                               heading_rate=math.radians(args.heading_rate_deg_s))
    sock = socket.socket(socket.AF_INET, socket.SOCK_DGRAM)
    try:
        sock.bind((host or "127.0.0.1", int(port)))
    except OSError as exc:
        raise SystemExit(f"mock_gimbal: error: cannot bind {args.udp}: {exc}") from None
    sys.stdout.write(f"{sock.getsockname()[1]}\n")
    sys.stdout.flush()
    server = MavlinkServer(model, sock, injector, args.fault_at, args.fault_duration)
    server.from_first_frame = args.from_first_frame

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    silent_from = args.disconnect_after
    silent_until = None
    try:
        while not stop.is_set():
            server.poll(min(0.02, server.next_due() - server.elapsed()))
            now = server.elapsed()
            t0 = server.origin()
            if silent_from is not None and t0 is not None and now - t0 >= silent_from:
                log.info("disconnecting at t=%.2f s", now)
                server.silent, silent_from = True, None
                silent_until = math.inf if args.reconnect_after is None else now + args.reconnect_after
            if silent_until is not None and now >= silent_until:
                log.info("reconnecting at t=%.2f s", now)
                server.silent, silent_until = False, None
    finally:
        sock.close()
        if msg_log is not None:
            msg_log.close()
        log.info("stopped (setpoints %d, datagrams dropped %d, corrupted %d)", model.setpoints, injector.dropped,
                 injector.corrupted)
    return 0


if __name__ == "__main__":
    sys.exit(main())
