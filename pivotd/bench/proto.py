"""``pivotd bench proto``: serial protocol codec throughput, link round trip, and a lossy-link soak.

* decode: frames/s of :class:`pivotd.firmware_proto.codec.StreamDecoder` on a stream of STATE frames fed in
  4 KiB chunks (one core, median over repeats);
* encode: frames/s of :func:`pivotd.firmware_proto.codec.encode` for SETPOINT messages;
* link: round trip setpoint → STATE echoing its seq, over a real pty to ``mock_gimbal`` at 50 Hz STATE;
* ``--faults``: a soak run (default 60 s) with 5 % drops and 5 % bit flips in both directions that
  counts lost ACKed commands and corrupted frames accepted as valid (both must be 0).
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path

from pivotd.firmware_proto import codec
from pivotd.firmware_proto.messages import Setpoint, State
from pivotd.progress import with_progress

REPO_ROOT = Path(__file__).resolve().parents[2]


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--frames", type=int, default=200_000, help="frames per codec repeat (default 200000)")
    parser.add_argument("--repeats", type=int, default=5, help="codec repeats; the median is reported")
    parser.add_argument("--link-seconds", type=float, default=5.0, help="duration of the pty round-trip run")
    parser.add_argument("--state-hz", type=float, default=50.0, help="STATE rate of the simulated gimbal")
    parser.add_argument("--faults", action="store_true", help="also run the lossy-link soak")
    parser.add_argument("--fault-seconds", type=float, default=60.0, help="duration of the soak (default 60)")
    parser.add_argument("--quick", action="store_true", help="small sizes for a smoke run")
    parser.add_argument("--json", metavar="FILE", help="write the results as JSON")


def bench_decode(n: int, repeats: int) -> dict[str, float]:
    """Frames/s of the stream decoder over ``n`` STATE frames fed in 4 KiB chunks."""
    stream = b"".join(codec.encode(State(i * 20_000, 0.001 * i, -0.002 * i, 0.5, -0.5, i & 0xFF, 1, 0), i)
                      for i in range(n))
    chunks = [stream[i:i + 4096] for i in range(0, len(stream), 4096)]
    rates = []
    for _ in range(repeats):
        dec = codec.StreamDecoder()
        t0 = time.perf_counter()
        count = 0
        for chunk in chunks:
            count += len(dec.feed(chunk))
        dt = time.perf_counter() - t0
        if count != n:
            raise RuntimeError(f"decoder returned {count} of {n} frames")
        rates.append(n / dt)
    return {"decode_frames_per_s": statistics.median(rates), "decode_mbyte_per_s":
            statistics.median(rates) * len(stream) / n / 1e6}


def bench_encode(n: int, repeats: int) -> dict[str, float]:
    """Frames/s of encode() for SETPOINT messages (dataclass construction included)."""
    rates = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        for i in range(n):
            codec.encode(Setpoint(0.001 * i, -0.001 * i, 0.1, -0.1, i, i, 200), i)
        rates.append(n / (time.perf_counter() - t0))
    return {"encode_frames_per_s": statistics.median(rates)}


class _MockProcess:
    """``python -m pivotd.firmware_proto.mock_server ARGS`` on a pty."""

    def __init__(self, *args: str) -> None:
        env = dict(os.environ, PYTHONPATH=os.pathsep.join([str(REPO_ROOT), os.environ.get("PYTHONPATH", "")]))
        self.proc = subprocess.Popen([sys.executable, "-m", "pivotd.firmware_proto.mock_server", *args],
                                     stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True, env=env)
        self.path = self.proc.stdout.readline().strip()  # type: ignore[union-attr]

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()
        if self.proc.stdout:
            self.proc.stdout.close()


def _link_config():  # type: ignore[no-untyped-def]
    from pivotd.firmware_proto.messages import Config
    from pivotd.gimbal.link import LinkConfig

    return LinkConfig(Config(-3.0, 3.0, -1.0, 1.0, 2.0, 2.0, 10.0, 10.0, 250), state_timeout_s=2.0)


def _percentile(values: list[float], q: float) -> float:
    s = sorted(values)
    return s[min(len(s) - 1, int(q * len(s)))] if s else float("nan")


def _drive(link, seconds: float, rate_hz: float, command_every_s: float | None = None):  # type: ignore[no-untyped-def]
    """Send setpoints at ``rate_hz`` for ``seconds``; measure setpoint → echoing STATE latency.
    Optionally send an ACKed command every ``command_every_s``; returns (rtts, sent, commands, failed)."""
    sent_at: dict[int, float] = {}
    sent: dict[int, list[tuple[float, float]]] = {}
    rtts: list[float] = []
    lock = threading.Lock()

    def on_state(st) -> None:  # type: ignore[no-untyped-def]
        with lock:
            t = sent_at.pop(st.last_setpoint_seq, None)
        if t is not None:
            rtts.append(st.rx_time - t)

    link.subscribe(on_state)
    period = 1.0 / rate_hz
    t_start = time.monotonic()
    next_cmd = t_start + (command_every_s or 0.0)
    commands = failed = 0
    i = 0
    while time.monotonic() - t_start < seconds:
        pan, tilt = 0.5 * ((i % 200) / 100.0 - 1.0), 0.2 * ((i % 50) / 25.0 - 1.0)
        with lock:
            seq = link.send_setpoint(pan, tilt)
            if seq is not None:
                sent_at[seq] = time.monotonic()
                sent.setdefault(seq, []).append((round(pan, 6), round(tilt, 6)))
        i += 1
        if command_every_s is not None and time.monotonic() >= next_cmd:
            next_cmd += command_every_s
            commands += 1
            ok = link.clear_fault() if commands % 2 else link.set_enabled(True)
            failed += 0 if ok else 1
        time.sleep(max(0.0, t_start + i * period - time.monotonic()))
    return rtts, sent, commands, failed


def bench_link(seconds: float, state_hz: float) -> dict[str, float]:
    """Round trip over a pty to the simulated gimbal, setpoints at the STATE rate."""
    from pivotd.gimbal.link import GimbalLink

    mock = _MockProcess("--state-hz", str(state_hz))
    link = GimbalLink(mock.path, _link_config())
    try:
        link.start()
        if not link.wait_up(10.0):
            raise RuntimeError(f"link to the simulated gimbal did not come up: {link.last_error}")
        rtts, _, _, _ = _drive(link, seconds, state_hz)
    finally:
        link.stop()
        mock.close()
    period = 1.0 / state_hz
    return {
        "link_state_hz": state_hz,
        "link_rtt_samples": len(rtts),
        "link_rtt_median_ms": statistics.median(rtts) * 1e3 if rtts else float("nan"),
        "link_rtt_p95_ms": _percentile(rtts, 0.95) * 1e3,
        "link_rtt_max_ms": max(rtts) * 1e3 if rtts else float("nan"),
        "link_echo_within_2_periods": sum(r <= 2 * period for r in rtts) / len(rtts) if rtts else 0.0,
    }


def bench_faults(seconds: float, state_hz: float) -> dict[str, float]:
    """Soak with --drop 0.05 --corrupt 0.05 over a pty; check ACKed commands and frame integrity."""
    import csv

    from pivotd.gimbal.link import GimbalLink

    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "device.csv"
        mock = _MockProcess("--state-hz", str(state_hz), "--drop", "0.05", "--corrupt", "0.05", "--seed", "1",
                            "--log", str(log_path))
        link = GimbalLink(mock.path, _link_config())
        received = []
        link.subscribe(received.append)
        try:
            link.start()
            if not link.wait_up(10.0):
                raise RuntimeError(f"link did not come up: {link.last_error}")
            _, sent, commands, failed = _drive(link, seconds, state_hz, command_every_s=0.5)
            counters = link.counters()
        finally:
            link.stop(disable=False)
            mock.close()
        with open(log_path, newline="") as f:
            rows = list(csv.DictReader(f))
    bad_rx = sum(1 for r in rows if r["dir"] == "rx" and r["type"] == "SETPOINT"
                 and (float(r["pan"]), float(r["tilt"])) not in sent.get(int(r["seq"]), []))
    emitted = {(int(r["device_time_us"]), float(r["pan"]), float(r["tilt"]), int(r["mode"]), int(r["faults"]))
               for r in rows if r["dir"] == "tx" and r["type"] == "STATE"}
    bad_tx = sum(1 for s in received if (s.device_time_us, s.pan, s.tilt, s.mode, s.faults) not in emitted)
    return {
        "faults_seconds": seconds,
        "faults_acked_commands": commands,
        "faults_acked_commands_lost": failed,
        "faults_retries": counters["retries"],
        "faults_link_losses": counters["link_losses"],
        "faults_host_decode_drops": counters["decode_drops"],
        "faults_host_crc_errors": counters["crc_errors"],
        "faults_corrupted_accepted_by_device": bad_rx,
        "faults_corrupted_accepted_by_host": bad_tx,
        "faults_states_received": len(received),
    }


def run(args: argparse.Namespace) -> int:
    n = 20_000 if args.quick else args.frames
    repeats = 3 if args.quick else args.repeats
    stages: list[Callable[[], dict[str, float]]] = [
        lambda: bench_decode(n, repeats),
        lambda: bench_encode(n, repeats),
        lambda: bench_link(1.0 if args.quick else args.link_seconds, args.state_hz),
    ]
    if args.faults:
        stages.append(lambda: bench_faults(5.0 if args.quick else args.fault_seconds, args.state_hz))
    results: dict[str, float] = {}
    for stage in with_progress(stages, "protocol benchmarks"):
        results.update(stage())
    width = max(len(k) for k in results)
    for key, value in results.items():
        shown = f"{value:,.3f}" if isinstance(value, float) and abs(value) < 1000 else f"{value:,.0f}"
        sys.stdout.write(f"{key:<{width}}  {shown}\n")
    if args.json:
        Path(args.json).write_text(json.dumps(results, indent=1) + "\n")
    lost = results.get("faults_acked_commands_lost", 0) + results.get("faults_corrupted_accepted_by_device", 0) \
        + results.get("faults_corrupted_accepted_by_host", 0)
    return 1 if lost else 0
