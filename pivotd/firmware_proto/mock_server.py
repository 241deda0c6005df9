"""``tools/mock_gimbal``: serve the reference device model on a pty, a TCP port or a real serial port.

The first stdout line is the endpoint: the ``/dev/pts/N`` path (pty), the bound port number (TCP),
or the serial device. After a simulated replug (``--reconnect-after``) a pty server prints the new
pty path on a new line (and updates ``--link``); a TCP server listens again on the same port.
"""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import pty
import select
import signal
import socket
import sys
import threading
import tty

import serial

from pivotd.firmware_proto.device import DeviceInfo, DeviceModel
from pivotd.firmware_proto.messages import PROTOCOL_VERSION
from pivotd.firmware_proto.realtime import CsvMessageLog, FaultInjector, RealTimeDevice

log = logging.getLogger("mock_gimbal")


def _announce(text: str) -> None:
    sys.stdout.write(text + "\n")
    sys.stdout.flush()


class PtyTransport:
    """A fresh pseudo-terminal per connection; the slave path is announced (and linked at ``link``)."""

    def __init__(self, link: str | None = None) -> None:
        self.link = link
        self.master = self.slave = -1

    def open(self) -> None:
        self.master, self.slave = pty.openpty()
        tty.setraw(self.slave)  # no echo, no CR/LF translation: a clean byte pipe
        os.set_blocking(self.master, False)
        path = os.ttyname(self.slave)
        if self.link:
            tmp = f"{self.link}.tmp{os.getpid()}"
            with contextlib.suppress(FileNotFoundError):
                os.unlink(tmp)
            os.symlink(path, tmp)
            os.replace(tmp, self.link)
        _announce(path)

    def read(self, timeout: float) -> bytes:
        ready, _, _ = select.select([self.master], [], [], timeout)
        if not ready:
            return b""
        try:
            return os.read(self.master, 4096)
        except (BlockingIOError, OSError):
            return b""

    def write(self, data: bytes) -> None:
        with contextlib.suppress(BlockingIOError):  # host not reading: the bytes are lost like on a wire
            os.write(self.master, data)

    def close(self) -> None:
        for fd in (self.master, self.slave):
            if fd >= 0:
                with contextlib.suppress(OSError):
                    os.close(fd)
        self.master = self.slave = -1


class TcpTransport:
    """One client at a time on host:port (``socket://`` URLs); further clients are refused."""

    def __init__(self, host: str, port: int) -> None:
        self.host, self.port = host, port
        self.server: socket.socket | None = None
        self.client: socket.socket | None = None
        self._lock = threading.Lock()
        self._announced = False

    def open(self) -> None:
        srv = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
        srv.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        srv.bind((self.host, self.port))
        srv.listen(1)
        self.port = srv.getsockname()[1]  # port 0 -> the chosen one, reused after a replug
        self.server = srv
        if not self._announced:
            _announce(str(self.port))
            self._announced = True
        log.info("listening on %s:%d", self.host, self.port)

    def read(self, timeout: float) -> bytes:
        socks = [s for s in (self.server, self.client) if s is not None]
        ready, _, _ = select.select(socks, [], [], timeout)
        data = b""
        for s in ready:
            if s is self.server:
                conn, addr = s.accept()
                if self.client is None:
                    conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                    with self._lock:
                        self.client = conn
                    log.info("client %s:%d connected", *addr)
                else:
                    conn.close()
            else:
                try:
                    data = s.recv(4096)
                except OSError:
                    data = b""
                if not data:
                    log.info("client disconnected")
                    self._drop_client()
        return data

    def write(self, data: bytes) -> None:
        with self._lock:
            client = self.client
        if client is not None:
            try:
                client.sendall(data)
            except OSError:
                self._drop_client()

    def _drop_client(self) -> None:
        with self._lock:
            client, self.client = self.client, None
        if client is not None:
            client.close()

    def close(self) -> None:
        self._drop_client()
        if self.server is not None:
            self.server.close()
            self.server = None


class SerialTransport:
    """A real serial port (bench use: emulate a gimbal on a second USB adapter)."""

    def __init__(self, port: str, baudrate: int) -> None:
        self.port_name, self.baudrate = port, baudrate
        self.port: serial.Serial | None = None

    def open(self) -> None:
        self.port = serial.serial_for_url(self.port_name, baudrate=self.baudrate, timeout=0)
        _announce(self.port_name)

    def read(self, timeout: float) -> bytes:
        assert self.port is not None
        self.port.timeout = timeout
        return self.port.read(max(1, self.port.in_waiting))

    def write(self, data: bytes) -> None:
        if self.port is not None:
            self.port.write(data)

    def close(self) -> None:
        if self.port is not None:
            self.port.close()
            self.port = None


def parse_fault_at(text: str) -> tuple[float, int]:
    """``SECONDS:BIT`` -> (seconds, bit)."""
    try:
        t, bit = text.split(":")
        out = (float(t), int(bit))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--fault-at expects SECONDS:BIT, got {text!r}") from None
    if not 0 <= out[1] <= 15 or out[0] < 0:
        raise argparse.ArgumentTypeError(f"--fault-at {text!r}: bit must be 0..15 and seconds >= 0")
    return out


def parse_stuck_axis(text: str) -> tuple[str, float, float]:
    """``AXIS:AT:SECONDS`` -> (axis, seconds after start, seconds held)."""
    try:
        axis, at, seconds = text.split(":")
        out = (axis, float(at), float(seconds))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--stuck-axis expects AXIS:AT:SECONDS, got {text!r}") from None
    if axis not in ("pan", "tilt") or not out[1] >= 0 or not out[2] >= 0:
        raise argparse.ArgumentTypeError(f"--stuck-axis {text!r}: AXIS must be pan or tilt, AT and SECONDS >= 0")
    return out


def add_fault_arguments(p: argparse.ArgumentParser, unit: str = "frame", fault_bit: str = "latch fault BIT",
                        disconnect: str = "close the port", reconnect: str = "reopen the port",
                        corrupt: bool = True, latency: str = "one-way delivery delay [ms]") -> None:
    """Declare the fault-injection options every device simulator shares (read back by
    :func:`parse_simulator_args`): ``--drop``, ``--corrupt`` (when the medium has bit flips), ``--latency-ms``,
    ``--seed``, ``--fault-at``, ``--disconnect-after``, ``--from-first-frame``, ``--reconnect-after``. The words
    name the simulator's own unit of transfer (``unit``), what a fault bit does, and what a disconnect is."""
    p.add_argument("--drop", type=float, default=0.0, help=f"probability of losing each {unit} (both directions)")
    if corrupt:
        p.add_argument("--corrupt", type=float, default=0.0, help=f"probability of one bit flip in each {unit}")
    p.add_argument("--latency-ms", type=float, default=0.0, help=latency)
    p.add_argument("--seed", type=int, default=None, help="random seed of the fault injection")
    p.add_argument("--fault-at", type=parse_fault_at, action="append", default=[], metavar="SECONDS:BIT",
                   help=f"{fault_bit} at SECONDS after start (repeatable)")
    p.add_argument("--disconnect-after", type=float, metavar="SECONDS", help=f"{disconnect} after SECONDS")
    p.add_argument("--from-first-frame", action="store_true",
                   help=f"count --fault-at and --disconnect-after from the host's first {unit}, not from start")
    p.add_argument("--reconnect-after", type=float, metavar="SECONDS",
                   help=f"{reconnect} SECONDS after the disconnect")


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="mock_gimbal", description="Gimbal simulator speaking the pivotd serial protocol.")
    where = p.add_mutually_exclusive_group()
    where.add_argument("--tcp", metavar="HOST:PORT", help="serve on TCP (port 0: pick one and print it)")
    where.add_argument("--serial", metavar="DEVICE", help="serve on a real serial port")
    p.add_argument("--baudrate", type=int, default=115200)
    p.add_argument("--link", metavar="PATH", help="pty mode: keep a symlink at PATH pointing to the current pty")
    p.add_argument("--state-hz", type=float, default=50.0, help="STATE rate [Hz] (default 50)")
    add_fault_arguments(p)
    p.add_argument("--stuck-axis", type=parse_stuck_axis, action="append", default=[], metavar="AXIS:AT:SECONDS",
                   help="hold AXIS (pan or tilt) mechanically for SECONDS from AT seconds after start (counted like "
                        "--fault-at): it does not move, its encoder reports the stuck position, no fault bit "
                        "(repeatable)")
    p.add_argument("--protocol-version", type=int, default=PROTOCOL_VERSION,
                   help=f"protocol version the device speaks (default {PROTOCOL_VERSION}; 1: no setpoint validity)")
    p.add_argument("--log", metavar="FILE", help="CSV log of every received and emitted message")
    p.add_argument("-v", "--verbose", action="store_true")
    return p


def make_transport(args: argparse.Namespace) -> PtyTransport | TcpTransport | SerialTransport:
    if args.tcp:
        host, _, port = args.tcp.rpartition(":")
        if not port.isdigit():
            raise SystemExit(f"mock_gimbal: error: --tcp expects HOST:PORT, got {args.tcp!r}")
        return TcpTransport(host or "127.0.0.1", int(port))
    if args.serial:
        return SerialTransport(args.serial, args.baudrate)
    return PtyTransport(args.link)


def parse_simulator_args(parser: argparse.ArgumentParser,
                         argv: list[str] | None) -> tuple[argparse.Namespace, FaultInjector]:
    """Parse the options every device simulator shares (``--verbose``, ``--state-hz`` and those of
    :func:`add_fault_arguments`), set up logging on stderr and build the fault injector; bad values exit through
    ``parser.error``."""
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.DEBUG if args.verbose else logging.INFO, stream=sys.stderr,
                        format="%(asctime)s %(levelname)s %(name)s: %(message)s")
    if args.state_hz <= 0:
        parser.error("--state-hz must be > 0")
    if args.reconnect_after is not None and args.disconnect_after is None:
        parser.error("--reconnect-after needs --disconnect-after")
    try:
        injector = FaultInjector(args.drop, getattr(args, "corrupt", 0.0), args.latency_ms / 1000.0, args.seed)
    except ValueError as exc:
        parser.error(str(exc))
    return args, injector


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args, injector = parse_simulator_args(parser, argv)
    msg_log = CsvMessageLog(args.log) if args.log else None
    model = DeviceModel(state_hz=args.state_hz, info=DeviceInfo(version=args.protocol_version), on_message=msg_log)
    device = RealTimeDevice(model, injector, args.fault_at, faults_from_first_frame=args.from_first_frame)
    transport = make_transport(args)

    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    try:
        transport.open()
    except (OSError, serial.SerialException) as exc:
        raise SystemExit(f"mock_gimbal: error: cannot open the port: {exc}") from None
    device.sink = transport.write
    device.start()
    disconnect_at = args.disconnect_after
    reconnect_at: float | None = None
    stuck = sorted(args.stuck_axis, key=lambda s: s[1])
    try:
        while not stop.is_set():
            data = transport.read(0.02)
            if data:
                device.write(data)
            now = device.elapsed()
            t0 = device.first_frame_at if args.from_first_frame else 0.0
            while stuck and t0 is not None and now - t0 >= stuck[0][1]:
                axis, _, seconds = stuck.pop(0)
                log.info("holding the %s axis mechanically for %.2f s at t=%.2f s", axis, seconds, now)
                device.inject_stuck_axis(axis, seconds)
            if disconnect_at is not None and t0 is not None and now - t0 >= disconnect_at:
                log.info("disconnecting at t=%.2f s", now)
                device.sink = None
                transport.close()
                disconnect_at = None
                reconnect_at = None if args.reconnect_after is None else now + args.reconnect_after
                while not stop.is_set() and (reconnect_at is None or device.elapsed() < reconnect_at):
                    stop.wait(0.02)
                if stop.is_set():
                    break
                log.info("reconnecting at t=%.2f s", device.elapsed())
                transport.open()
                device.sink = transport.write
    finally:
        device.sink = None
        device.stop()
        transport.close()
        if msg_log is not None:
            msg_log.close()
        log.info("stopped (frames dropped %d, corrupted %d)", injector.dropped, injector.corrupted)
    return 0


if __name__ == "__main__":
    sys.exit(main())
