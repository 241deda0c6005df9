"""``pivotd bench soak --minutes N``: the full stack under random faults and hostile input, judged from outside.

Runs ``pivotd`` (config/demo.yaml) with ``tools/sim_pose`` walking the hallway in a loop, as the demo launches
them, against the reference device model (pivotd.firmware_proto) served on a loopback TCP port of this process, so
that faults can be injected at any time: unplug/replug, bursts of bit flips and of lost frames, a device reboot
(the port stays, the device forgets its configuration), every fault bit, a device stall (its process stopped
while setpoints queue in its socket), a pan axis held mechanically (no fault bit); and, on the bus, hostile
input: NaN and teleported poses, poses from the past, floods, garbage payloads, empty, single-point, far-away, huge and
malformed paths; a storm of SIGHUPs (``reload_storm``, the config unchanged); and a recording that fails
mid-run (the daemon records to a FIFO whose reader the soak closes: ``recorder_failure``, once per daemon
start). One event at a time, at random intervals (seeded); after each the soak waits for the daemon to track
again and records the recovery time.

Reported: setpoints beyond limits (joint limits, velocity, and between consecutive setpoints the device
followed, acceleration and jerk, each with the wire-resolution allowance), tracebacks in the daemon's log,
resident memory growth after warm-up, recovery times per event kind, and the daemon's exit code after SIGTERM.
"""

from __future__ import annotations

import argparse
import contextlib
import csv
import json
import logging
import os
import queue
import random
import signal
import sys
import tempfile
import threading
import time
from collections import deque
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from pivotd.bench._procs import process_tree, rss_mb

log = logging.getLogger("pivotd.bench.soak")

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "config" / "demo.yaml"

#: event kinds and their relative weights in the random schedule
DEVICE_EVENTS = {"unplug": 3, "bitflips": 2, "drops": 2, "reboot": 2, "fault_bit": 3}
BUS_EVENTS = {"nan_pose": 1, "teleport": 1, "past_pose": 1, "pose_flood": 1, "garbage": 1, "path_empty": 1,
              "path_single": 1, "path_far": 1, "path_huge": 1, "path_garbage": 1}
RANDOM_EXTRA_EVENTS = {"silent": 1, "stale_pose": 1, "planner_stall": 1, "off_path": 1, "device_stall": 1,
                       "reload_storm": 1, "stuck_axis": 1}
OFF_PATH_M = 5.0  # [m] how far to the side the off-path fault moves the route's path (max_path_offset: 3 m)
OFF_PATH_HZ = 20.0  # [Hz] it outpaces tools/sim_pose re-publishing the true path every 2 s
ONCE_EVENTS = {"recorder_failure": 1}  # at most once per daemon start (the recording stops for good)
RELOAD_STORM = 300  # SIGHUPs in a reload storm
RELOAD_STORM_GAP_S = 0.002  # [s] between them
STUCK_SECONDS = 6.0  # [s] how long the stuck_axis fault holds the pan axis mechanically (a few 10° of turn)
UNPLUG_SECONDS = {0.5: 4, 5.0: 4, 60.0: 1}  # replug after [s]: relative weights
NOISE_SECONDS = 5.0
RECOVERY_TIMEOUT_S = 60.0
AXIS_DECISION_S = 0.1  # [s] device time a tracking-error hold may come after the state the host decided on
RESTART_WINDOW_S = 1.0  # [s] device time after it reported a stop during which a stream may restart from its states
GRACE_S = 0.05  # [s] status documents made this soon after a fault may predate its effect


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--minutes", type=float, default=30.0, help="length of the soak [min]")
    parser.add_argument("--seed", type=int, default=1, help="seed of the fault schedule")
    parser.add_argument("--mean-gap", type=float, default=6.0, metavar="S",
                        help="mean time between one event's recovery and the next event [s]")
    parser.add_argument("--warmup", type=float, default=None, metavar="S",
                        help="seconds before the RSS baseline (default: 10%% of the run, 5..120 s)")
    parser.add_argument("--out", type=Path, default=None, help="keep the logs in this directory")
    parser.add_argument("--matrix", action="store_true",
                        help="instead of random faults, each fault of docs/RELIABILITY.md once, with its recovery time")
    parser.add_argument("--skip-long", action="store_true", help="--matrix without the 60 s unplug")
    parser.add_argument("--json", type=Path, help="write the results to this file")


# ---------------------------------------------------------------------------------------------- device side
class SoakDevice:
    """The reference device model on a loopback TCP port (``socket://`` URL), with commands to unplug it for a
    while, reboot it, latch a fault bit, and change the per-frame bit-flip/loss probabilities."""

    def __init__(self, log_path: Path, seed: int) -> None:
        from pivotd.firmware_proto.mock_server import TcpTransport
        from pivotd.firmware_proto.realtime import CsvMessageLog, FaultInjector

        self.msg_log = CsvMessageLog(log_path)
        self.injector = FaultInjector(seed=seed)
        self.transport = TcpTransport("127.0.0.1", 0)
        self.transport._announced = True  # the soak reports the port itself, not on stdout
        self.device = self._new_device()
        self.reboots = 0
        self._commands: queue.Queue = queue.Queue()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="soak-device", daemon=True)

    def _new_device(self):
        from pivotd.firmware_proto.device import DeviceModel
        from pivotd.firmware_proto.realtime import RealTimeDevice

        return RealTimeDevice(DeviceModel(state_hz=50.0, on_message=self.msg_log), self.injector)

    @property
    def url(self) -> str:
        return f"socket://127.0.0.1:{self.transport.port}"

    def start(self) -> None:
        self.transport.open()
        self.device.sink = self.transport.write
        self.device.start()
        self._thread.start()

    def unplug(self, seconds: float) -> None:
        self._commands.put(("unplug", seconds))

    def reboot(self) -> None:
        self._commands.put(("reboot", 0.0))

    def fault(self, bit: int) -> None:
        self._commands.put(("fault", bit))

    def stuck(self, axis: str, seconds: float) -> None:
        """Hold ``axis`` mechanically for ``seconds`` (no fault bit; DeviceModel.inject_stuck_axis)."""
        self._commands.put(("stuck", (axis, seconds)))

    def noise(self, drop: float, corrupt: float) -> None:
        self.injector.drop, self.injector.corrupt = drop, corrupt

    def _run(self) -> None:
        unplugged_until: float | None = None
        while not self._stop.is_set():
            with contextlib.suppress(queue.Empty):
                kind, value = self._commands.get_nowait()
                if kind == "unplug":
                    self.device.sink = None
                    self.transport.close()
                    unplugged_until = time.monotonic() + value
                elif kind == "reboot":
                    old, self.device = self.device, self._new_device()
                    old.sink = None
                    old.stop()
                    self.device.sink = self.transport.write if unplugged_until is None else None
                    self.device.start()
                    self.reboots += 1
                elif kind == "fault":
                    self.device.inject_fault(int(value))
                elif kind == "stuck":
                    self.device.inject_stuck_axis(*value)
            if unplugged_until is not None:
                if time.monotonic() < unplugged_until:
                    self._stop.wait(0.01)
                    continue
                self.transport.open()
                self.device.sink = self.transport.write
                unplugged_until = None
            data = self.transport.read(0.01)
            if data:
                self.device.write(data)

    def stop(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        self.device.sink = None
        self.device.stop()
        self.transport.close()
        self.msg_log.close()


def _serve_device(conn, log_path: str, seed: int) -> None:  # pragma: no cover - runs in the child
    """Child process: a :class:`SoakDevice` driven by (command, argument) messages from ``conn``."""
    device = SoakDevice(Path(log_path), seed)
    device.start()
    conn.send(device.url)
    try:
        while True:
            try:
                name, arg = conn.recv()
            except (EOFError, OSError):
                return
            if name == "stop":
                return
            if name == "elapsed":
                conn.send(device.device.elapsed())
            elif name == "noise":
                device.noise(*arg)
            else:
                getattr(device, name)(*arg)
    finally:
        device.stop()
        with contextlib.suppress(OSError):
            conn.send(None)


class DeviceProcess:
    """A :class:`SoakDevice` in its own process, as a real gimbal runs beside the host: the soak's own load
    (publishing floods) cannot stall the device model. Same commands as :class:`SoakDevice`."""

    def __init__(self, log_path: Path, seed: int) -> None:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve_device, args=(child, str(log_path), seed), name="soak-device",
                                 daemon=True)
        self._proc.start()
        child.close()
        if not self._conn.poll(30.0):
            self._proc.kill()
            raise RuntimeError("the simulated gimbal did not start")
        self.url: str = self._conn.recv()

    def unplug(self, seconds: float) -> None:
        self._conn.send(("unplug", (seconds,)))

    def reboot(self) -> None:
        self._conn.send(("reboot", ()))

    def fault(self, bit: int) -> None:
        self._conn.send(("fault", (bit,)))

    def stuck(self, axis: str, seconds: float) -> None:
        self._conn.send(("stuck", (axis, seconds)))

    def noise(self, drop: float, corrupt: float) -> None:
        self._conn.send(("noise", (drop, corrupt)))

    @property
    def pid(self) -> int | None:
        """Process id of the device model (e.g. to stop it for a while: a burst of late frames)."""
        return self._proc.pid

    def elapsed(self) -> float:
        """Seconds on the device clock."""
        self._conn.send(("elapsed", ()))
        return float(self._conn.recv())

    def stop(self) -> None:
        with contextlib.suppress(OSError):
            self._conn.send(("stop", ()))
            if self._conn.poll(10.0):
                self._conn.recv()
        self._proc.join(timeout=10.0)
        if self._proc.is_alive():
            self._proc.kill()
        self._conn.close()


class FifoSink:
    """A FIFO the daemon records to (``pivotd --record``), read and discarded by a thread of the soak. :meth:`close`
    closes the reading end: the daemon's next write to its recording fails (EPIPE), as a full disk would."""

    def __init__(self, path: Path) -> None:
        self.path = path
        os.mkfifo(path)
        self._fd: int | None = os.open(path, os.O_RDONLY | os.O_NONBLOCK)  # before the daemon opens it to write
        self.bytes = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._drain, name="soak-recording", daemon=True)
        self._thread.start()

    def _drain(self) -> None:
        import select

        while not self._stop.is_set():
            ready, _, _ = select.select([self._fd], [], [], 0.1)
            if not ready:
                continue
            try:
                data = os.read(self._fd, 1 << 16)
            except BlockingIOError:
                continue
            if data:
                self.bytes += len(data)
            else:  # no writer (yet, or any more)
                self._stop.wait(0.05)

    @property
    def open(self) -> bool:
        return self._fd is not None

    def close(self) -> None:
        self._stop.set()
        self._thread.join(timeout=5.0)
        if self._fd is not None:
            os.close(self._fd)
            self._fd = None


def tree_rss_mb(pid: int) -> float:
    """Resident memory [MB] of process ``pid`` and all its descendants (children of any of its threads)."""
    return sum(rss_mb(p)[0] for p in process_tree(pid))


# ---------------------------------------------------------------------------------------------- checks
@dataclass
class SetpointCheck:
    """What the device received: counts of setpoints beyond each limit and the worst ratios to the limits."""

    setpoints: int = 0
    checked_pairs: int = 0
    restarts: int = 0  # segments judged from a measured state after the device reported a stop
    restarted_steps: int = 0  # of those, pairs that were a step from the previous setpoint (late frames before)
    axis_restarts: int = 0  # pairs where an axis that did not follow restarted from its measured state at rest
    beyond_position: int = 0
    beyond_velocity: int = 0
    beyond_acceleration: int = 0
    beyond_jerk: int = 0
    beyond_step: int = 0  # pairs whose position stepped farther than their rates move in a period, unexplained
    worst: dict = field(default_factory=lambda: {"velocity": 0.0, "acceleration": 0.0, "jerk": 0.0})

    @property
    def beyond_limits(self) -> int:
        return (self.beyond_position + self.beyond_velocity + self.beyond_acceleration + self.beyond_jerk
                + self.beyond_step)


def check_device_log(cfg, path: Path) -> SetpointCheck:
    """Check every SETPOINT in a device message log against ``cfg``'s joint and motion limits.

    Position and velocity hold for every setpoint. Acceleration (rate difference / dt) and jerk hold between every
    two consecutive setpoints the device executed while it followed the stream: consecutive frame numbers (no frame
    lost or corrupted between them; a HEARTBEAT or CLEAR_FAULT the daemon sent between them takes one and the stream
    goes on across it), no device reboot or new handshake (HELLO, CONFIG, ENABLE) between them, and the device
    following (mode ENABLED in its last STATE, no newly latched watchdog bit). However late a setpoint comes after
    the previous one, a device that did not stop executes it as the next step of the stream, so the pair is judged
    as one control period apart (a restart from the measured state while the device never held was a 4.5x
    acceleration and 69x jerk step that a rule "sent more than 0.1 s apart: a new stream" did not see).

    Restarts after the device stopped: when the device reported that it stopped following (a STATE with mode
    HOLDING, DISABLED or FAULT, or with the watchdog bit newly latched), the host restarts the stream from a state
    the device measured after the stop; setpoints it sent before it learnt of the stop may still reach the device
    after it (late, on a loaded host).
    So within ``RESTART_WINDOW_S`` of device time after a reported stop, the first setpoint that is continuous with
    one of the measured states reported since the stop (position within the distance the reported or commanded
    rate covers in ``stall_s`` plus a period; rate within one period of the acceleration limit, and that
    acceleration within one period of the jerk limit from rest) starts the new segment, judged from that state on
    (from the most favourable of them when it continues several: the log does not say which one the host took).
    One stop allows one restart: a second restart from the same stop, or a setpoint continuous with neither the
    previous setpoint nor a measured state, counts as beyond the limits. A setpoint that continues both the
    previous one within the limits and a measured state (late frames of the old stream resumed the device, and the
    host restarted from a state in motion close to the old stream) may be either: the next pair's jerk is judged
    from the more favourable of the two, and the stop still allows its restart.

    An axis that did not follow may restart from its measured state while the other axis goes on: the daemon's
    tracking-error hold (pivotd.daemon.tracking_error). Such an axis stood still in every state the device reported
    for the last ``control.tracking_error_s`` (rate within one period of the acceleration limit) while the previous
    setpoint was farther than ``control.tracking_error_deg`` from it; its step is judged from its latest measured
    state (counted in ``axis_restarts``). A device that overshot a stale setpoint and was still slowing down is
    not such an axis: its step counts.
    """
    from pivotd.daemon.control import ControlSettings
    from pivotd.firmware_proto.messages import FAULT_WATCHDOG, MODE_ENABLED
    from pivotd.sim.analysis import WIRE_RESOLUTION

    dt = cfg.control.dt
    stall = ControlSettings.stall_s  # the longest gap the control loop continues a stream across [s]
    lim = cfg.gimbal.limits
    lo = np.array([-np.inf if lim.continuous_pan else lim.pan_min, lim.tilt_min]) - 1e-6
    hi = np.array([np.inf if lim.continuous_pan else lim.pan_max, lim.tilt_max]) + 1e-6
    vmax = np.array([cfg.motion.pan.max_velocity, cfg.motion.tilt.max_velocity])
    amax = np.array([cfg.motion.pan.max_acceleration, cfg.motion.tilt.max_acceleration])
    jmax = np.array([cfg.motion.pan.max_jerk, cfg.motion.tilt.max_jerk])
    bound = cfg.control.tracking_error  # [rad] an axis farther than this from its setpoint did not follow ...
    window = cfg.control.tracking_error_s  # [s] ... for this long
    res = WIRE_RESOLUTION
    allow_v, allow_a, allow_j = res / dt, 2 * res / dt, 4 * res / dt**2
    out = SetpointCheck()
    mode = -1
    faults = 0
    prev: tuple[int, np.ndarray, np.ndarray] | None = None  # (seq, position, rate) of the previous setpoint
    prev_acc: list[np.ndarray] = []  # the acceleration of the previous pair (several candidates at a restart)
    last_t = -np.inf
    last_mode = -1
    stop_t: float | None = None  # device time of the latest reported stop within the restart window
    measured: list[tuple[np.ndarray, np.ndarray]] = []  # (position, rate) of the states reported since that stop
    recent: deque[tuple[float, np.ndarray, np.ndarray]] = deque()  # (t, position, rate) of the last states
    stop_restarted = False  # a setpoint continuous with one of them was seen (counted once per stop)

    def restart_accs(pos: np.ndarray, rate: np.ndarray) -> list[np.ndarray]:
        """Accelerations of a restart from each of the ``measured`` states that ``(pos, rate)`` continues (the host
        restarted from one of them, the log does not say which), the most favourable first."""
        found = []
        for m_pos, m_rate in measured:
            acc = (rate - m_rate) / dt
            reach = np.maximum(np.abs(m_rate), np.abs(rate)) * (stall + dt) + 2 * res
            if (np.all(np.abs(pos - m_pos) <= reach) and np.all(np.abs(acc) <= amax + allow_a)
                    and np.all(np.abs(acc) / dt <= jmax + allow_j)):
                found.append(acc)
        return sorted(found, key=lambda a: float(np.max(np.abs(a) / amax)))

    def axis_restart(i: int, t: float, prev_pos: np.ndarray, pos: np.ndarray, rate: np.ndarray) -> float | None:
        """Acceleration of axis ``i`` restarting from one of its latest measured states, if it stood still for the
        tracking-error window up to that state, farther than the bound from the previous setpoint (a tracking-error
        hold; the host decided on a state up to ``AXIS_DECISION_S`` old); or None."""
        states = list(recent)
        for k in range(len(states) - 1, -1, -1):
            m_t, m_pos, m_rate = states[k]
            if t - m_t > AXIS_DECISION_S:
                break
            window_states = [st for st in states[:k + 1] if st[0] >= m_t - window]
            if m_t - states[0][0] < window or any(abs(r[i]) > amax[i] * dt for _, _, r in window_states):
                continue
            acc = (rate[i] - m_rate[i]) / dt
            if (abs(prev_pos[i] - m_pos[i]) > bound and abs(pos[i] - m_pos[i]) <= amax[i] * dt * (stall + dt) + 2 * res
                    and abs(acc) <= amax[i] + allow_a and abs(acc) / dt <= jmax[i] + allow_j):
                return acc
        return None

    with open(path, newline="") as fh:
        for row in csv.DictReader(fh):
            t = float(row["t_s"])
            if t < last_t - 1.0:  # the device clock restarted: a reboot
                prev, prev_acc, stop_t, measured, last_mode, faults = None, [], None, [], -1, 0
                recent.clear()
            last_t = t
            if stop_t is not None and t - stop_t > RESTART_WINDOW_S:
                stop_t, measured = None, []
            if row["dir"] == "tx" and row["type"] == "STATE":
                mode = int(row["mode"])
                new_faults = int(row["faults"] or 0)
                watchdog_edge = bool(new_faults & FAULT_WATCHDOG) and not faults & FAULT_WATCHDOG
                faults = new_faults
                state = (np.array([float(row["pan"]), float(row["tilt"])]),
                         np.array([float(row["pan_rate"]), float(row["tilt_rate"])]))
                recent.append((t, *state))
                while t - recent[0][0] > window + AXIS_DECISION_S + 0.05:
                    recent.popleft()
                if mode != MODE_ENABLED:
                    prev, prev_acc = None, []
                # A watchdog bit newly latched while ENABLED: the device may have held for less than a state period
                # and resumed with the stream, so the next setpoint may continue it or restart from a measured state;
                # both readings stay open (the pair is judged as a continuation, or as the stop's one restart).
                if (mode != MODE_ENABLED and mode != last_mode) or watchdog_edge:  # it stopped following
                    stop_t, measured, stop_restarted = t, [state], False
                elif stop_t is not None:
                    measured.append(state)
                last_mode = mode
                continue
            if row["dir"] != "rx":
                continue
            if row["type"] in ("CLEAR_FAULT", "HEARTBEAT"):
                if prev is not None:
                    # sent beside or within the stream (supervision, a wait for a state): it takes a sequence
                    # number, the device keeps executing the stream and the next setpoint continues it
                    prev = ((prev[0] + 1) & 0xFF, prev[1], prev[2])
                continue
            if row["type"] != "SETPOINT":
                prev, prev_acc = None, []  # HELLO, CONFIG, ENABLE: a new stream follows
                continue
            out.setpoints += 1
            seq = int(row["seq"])
            pos = np.array([float(row["pan"]), float(row["tilt"])])
            rate = np.array([float(row["pan_rate"]), float(row["tilt_rate"])])
            out.beyond_position += int(np.any(pos < lo) or np.any(pos > hi))
            out.worst["velocity"] = max(out.worst["velocity"], float(np.max(np.abs(rate) / vmax)))
            out.beyond_velocity += int(np.any(np.abs(rate) > vmax + allow_v))
            restarts = restart_accs(pos, rate) if measured else []
            restarted = restarts[0] if restarts else None
            if restarted is not None and not stop_restarted:  # a restart after this stop
                out.restarts += 1
                stop_restarted = True
            if prev is not None and seq == (prev[0] + 1) & 0xFF and mode == MODE_ENABLED:
                acc = (rate - prev[2]) / dt
                # the acceleration before may be one of several (a restart, which may also have continued the
                # stream); the jerk is the one of the smallest ratio
                jerks = [(acc - a) / dt for a in prev_acc]
                jerk = min(jerks, key=lambda j: float(np.max(np.abs(j) / jmax))) if jerks else None

                def beyond(acc, jerk):
                    return (np.abs(acc) > amax + allow_a) | (jerk is not None and np.abs(jerk) > jmax + allow_j)

                # a position the rates do not reach in a period (or in a stall the loop continues across) is a step
                stepped = np.abs(pos - prev[1]) > np.maximum(np.abs(prev[2]), np.abs(rate)) * (stall + dt) + 2 * res
                continuous = not np.any(beyond(acc, jerk)) and not np.any(stepped)
                nxt = [acc]
                if restarted is not None and not continuous:  # judged from the measured state it starts at
                    acc, jerk = restarted, restarted / dt
                    nxt = restarts
                    out.restarted_steps += 1
                    stop_t, measured = None, []  # the one restart this stop allows
                elif restarted is not None:  # either the stream continued or it restarted here: both stay open
                    nxt = [acc, *restarts]
                elif not continuous:  # an axis held at the measured state after it did not follow?
                    axis_accs = {i: axis_restart(i, t, prev[1], pos, rate)
                                 for i in np.flatnonzero(beyond(acc, jerk) | stepped)}
                    if all(a is not None for a in axis_accs.values()):
                        acc, jerk = acc.copy(), None if jerk is None else jerk.copy()
                        for i, a in axis_accs.items():
                            acc[i] = a
                            if jerk is not None:
                                jerk[i] = a / dt
                        nxt = [acc]
                        out.axis_restarts += 1
                    else:
                        out.beyond_step += int(any(axis_accs[i] is None for i in np.flatnonzero(stepped)))
                out.checked_pairs += 1
                out.worst["acceleration"] = max(out.worst["acceleration"], float(np.max(np.abs(acc) / amax)))
                out.beyond_acceleration += int(np.any(np.abs(acc) > amax + allow_a))
                if jerk is not None:
                    out.worst["jerk"] = max(out.worst["jerk"], float(np.max(np.abs(jerk) / jmax)))
                    out.beyond_jerk += int(np.any(np.abs(jerk) > jmax + allow_j))
                prev_acc = nxt
            else:
                prev_acc = restarts
                if restarted is not None:  # a new segment from a measured state: the one restart this stop allows
                    stop_t, measured = None, []
            prev = (seq, pos, rate)
    out.worst = {k: round(v, 3) for k, v in out.worst.items()}
    return out


def count_tracebacks(path: Path) -> tuple[int, list[str]]:
    """Tracebacks in a log file and the exception line of the first few."""
    lines = path.read_text(errors="replace").splitlines()
    found: list[str] = []
    n = 0
    for i, line in enumerate(lines):
        if line.startswith("Traceback (most recent call last)"):
            n += 1
            j = i + 1
            while j < len(lines) and (lines[j].startswith(" ") or lines[j].startswith("During handling")):
                j += 1
            if len(found) < 5 and j < len(lines):
                found.append(lines[j][:200])
    return n, found


def rss_growth(samples: list[tuple[float, float]], warmup_s: float) -> dict:
    """RSS growth after warm-up: (median of the last quarter − median of the first quarter after warm-up) /
    the latter; ``samples`` are (seconds since start, RSS [MB])."""
    after = [rss for t, rss in samples if t >= warmup_s]
    if len(after) < 4:
        return {"samples": len(after), "growth": None}
    q = max(1, len(after) // 4)
    first, last = float(np.median(after[:q])), float(np.median(after[-q:]))
    return {"samples": len(after), "baseline_mb": round(first, 1), "final_mb": round(last, 1),
            "max_mb": round(max(after), 1), "growth": round((last - first) / first, 4)}


# ---------------------------------------------------------------------------------------------- hostile bus input
class Vandal:
    """Publishes hostile input on the daemon's pose and path topics from its own ROS node."""

    def __init__(self, session, cfg, rng: random.Random) -> None:
        from pivotd.bus import messages as m
        from pivotd.bus.ros import RosNode

        self.m = m
        self.cfg = cfg
        self.rng = rng
        node = RosNode(session, "soak_vandal", cfg.topics.domain_id)
        self.pose = node.publisher(cfg.topics.pose, cfg.topics.pose_type)
        self.path = node.publisher(cfg.topics.path, m.PATH)
        n = 20_000  # a path of 20 000 poses (1.2 MB)
        self._huge = m.encode_path(time.time(), cfg.topics.frame_id,
                                   np.column_stack([np.linspace(0, 200, n), np.zeros(n), np.zeros(n)]))

    def _pose(self, position: np.ndarray, stamp: float | None = None, quat=(0.0, 0.0, 0.0, 1.0)) -> bytes:
        m, t = self.m, self.cfg.topics
        stamp = time.time() if stamp is None else stamp
        return m.encode_pose(t.pose_type, stamp, t.frame_id, position, np.asarray(quat, float))

    def send(self, kind: str, last_position: np.ndarray) -> None:
        frame = self.cfg.topics.frame_id
        if kind == "nan_pose":
            self.pose.put(self._pose(np.array([np.nan, 0.0, 0.0])))
            self.pose.put(self._pose(last_position, quat=(0.0, 0.0, 0.0, np.nan)))
        elif kind == "teleport":
            self.pose.put(self._pose(last_position + np.array([40.0, -25.0, 0.0])))
        elif kind == "past_pose":
            self.pose.put(self._pose(last_position, stamp=time.time() - 3600.0))
        elif kind == "pose_flood":
            payload = self._pose(last_position)
            for _ in range(2000):
                self.pose.put(payload)
        elif kind == "garbage":
            for _ in range(50):
                self.pose.put(self.rng.randbytes(self.rng.randrange(1, 400)))
        elif kind == "path_empty":
            self.path.put(self.m.encode_path(time.time(), frame, np.zeros((0, 3))))
        elif kind == "path_single":
            self.path.put(self.m.encode_path(time.time(), frame, last_position[None, :]))
        elif kind == "path_far":
            self.path.put(self.m.encode_path(time.time(), frame, np.array([[1e6, 1e6, 0.0], [1e6 + 1, 1e6, 0.0]])))
        elif kind == "path_huge":
            self.path.put(self._huge)
        elif kind == "path_garbage":
            self.path.put(b"\x00\x01\x00\x00" + self.rng.randbytes(300))
        else:
            raise ValueError(f"unknown bus event {kind!r}")

    def off_path(self, seconds: float, offset: float = OFF_PATH_M) -> None:
        """The route's path (the hallway of ``tools/sim_pose --route hallway``) moved ``offset`` [m] to the side,
        published at :data:`OFF_PATH_HZ` for ``seconds``, then the true path once."""
        from pivotd.pivot.scenes import hallway

        true = hallway().path
        t = np.gradient(true[:, :2], axis=0)
        t /= np.linalg.norm(t, axis=1, keepdims=True)
        moved = true.copy()
        moved[:, :2] += offset * np.column_stack([-t[:, 1], t[:, 0]])
        frame = self.cfg.topics.frame_id
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            self.path.put(self.m.encode_path(time.time(), frame, moved))
            time.sleep(1.0 / OFF_PATH_HZ)
        self.path.put(self.m.encode_path(time.time(), frame, true))


# ---------------------------------------------------------------------------------------------- the stack
def _healthy(st: dict) -> bool:
    g = st.get("gimbal") or {}
    return (st.get("state") == "tracking" and st.get("link") == "up" and g.get("mode") == "enabled"
            and not g.get("faults"))


class SoakStack:
    """Daemon (config/demo.yaml) + :class:`SoakDevice` + ``tools/sim_pose`` looping the hallway, Zenoh on loopback,
    logs in ``out``; :meth:`inject` applies one named fault (:data:`EVENT_KINDS`). Use as a context manager."""

    def __init__(self, out: Path, seed: int = 1, changes: dict | None = None, record: bool | Path = False) -> None:
        """``record``: True: the daemon records (``--record``) to a :class:`FifoSink` (fault ``recorder_failure``);
        a path: to that file."""
        from pivotd.config import load_config
        from pivotd.sim.launch import derive_config, free_port

        self.out = out
        self.rng = random.Random(seed)
        self.device = DeviceProcess(out / "gimbal.csv", seed)
        self.endpoint = f"tcp/127.0.0.1:{free_port()}"
        self.config_path = derive_config(DEMO, out / "soak.yaml", {
            "zenoh.listen": [self.endpoint], "gimbal.port": self.device.url, "control.status_hz": 5,
            **(changes or {})})
        self.cfg = load_config(self.config_path)
        self.daemon = self.sim = self.probe = self.vandal = None
        self.daemon_starts = 0
        self.record = record
        self.recording: FifoSink | None = None
        self.rss: list[tuple[float, float]] = []
        self.t_start = time.monotonic()
        self._last_rss = -np.inf
        self.sighups = 0  # SIGHUPs sent to the current daemon

    # ------------------------------------------------------------------ processes
    def start_daemon(self) -> None:
        from pivotd.sim.launch import spawn

        self.daemon_starts += 1
        self.sighups = 0
        log_path = self.out / ("pivotd.log" if self.daemon_starts == 1 else f"pivotd.{self.daemon_starts}.log")
        extra: list[str] = []
        if isinstance(self.record, Path):
            extra = ["--record", str(self.record)]
        elif self.record:
            if self.recording is not None:
                self.recording.close()
            self.recording = FifoSink(self.out / f"recording.{self.daemon_starts}.fifo")
            extra = ["--record", str(self.recording.path)]
        self.daemon = spawn([sys.executable, "-m", "pivotd.cli", "--config", str(self.config_path), *extra], log_path)

    def __enter__(self) -> SoakStack:
        from pivotd.bus.probe import BusProbe
        from pivotd.sim.launch import spawn

        try:
            self.start_daemon()
            self.probe = BusProbe.connect(self.endpoint, self.cfg.topics)
            self.sim = spawn([sys.executable, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--connect",
                              self.endpoint, "--speed", "1.0", "--rate", "50", "--loop", "--quiet",
                              "--wait-subscribers", "30"], self.out / "sim_pose.log")
            self.vandal = Vandal(self.probe.session, self.cfg, self.rng)
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def close(self) -> None:
        for proc in (self.sim, self.daemon):
            if proc is not None and proc.poll() is None:
                _stop(proc, signal.SIGKILL, 10.0)
        if self.probe is not None:
            self.probe.close()
            self.probe = None
        if self.recording is not None:
            self.recording.close()
        self.device.stop()

    def stop_daemon(self, sig: int = signal.SIGTERM, timeout: float = 20.0) -> int | None:
        """Signal the daemon and wait for its exit code (None: still running after ``timeout``, then killed)."""
        return _stop(self.daemon, sig, timeout)

    def daemon_logs(self) -> list[Path]:
        return sorted(self.out.glob("pivotd*.log"))

    # ------------------------------------------------------------------ observation
    @property
    def status(self) -> dict:
        return self.probe.status if self.probe is not None else {}

    def sample_rss(self, every: float = 5.0) -> None:
        """Record the daemon's resident memory (daemon + planner process) at most every ``every`` s."""
        now = time.monotonic()
        if now - self._last_rss >= every and self.daemon is not None and self.daemon.poll() is None:
            self._last_rss = now
            self.rss.append((now - self.t_start, tree_rss_mb(self.daemon.pid)))

    def wait(self, predicate, timeout: float, since: float | None = None) -> float | None:
        """Seconds from ``since`` (wall clock, default now) to the daemon's time stamp of the first status document
        made after ``since`` for which ``predicate(status)`` holds; None when none came within ``timeout``.
        Samples RSS meanwhile."""
        since = time.time() if since is None else since
        t0 = time.monotonic()
        while time.monotonic() - t0 < timeout:
            if self.daemon.poll() is not None:
                raise RuntimeError(f"pivotd exited with {self.daemon.returncode}; see {self.daemon_logs()[-1]}")
            st = self.status
            if st.get("time", 0.0) > since and predicate(st):
                return max(0.0, st["time"] - since)
            self.sample_rss()
            time.sleep(0.02)
        return None

    def wait_healthy(self, timeout: float, since: float | None = None) -> float | None:
        """:meth:`wait` until the daemon tracks with the link up, the gimbal enabled and no fault bit."""
        return self.wait(_healthy, timeout, since)

    # ------------------------------------------------------------------ faults
    def inject(self, kind: str, **params) -> dict:
        """Apply the fault ``kind`` (blocking for its duration) and return its description."""
        event: dict = {"t_s": round(time.monotonic() - self.t_start, 2), "kind": kind, **params}
        device = self.device
        if kind == "unplug":
            device.unplug(params["seconds"])
            time.sleep(params["seconds"])
        elif kind in ("bitflips", "drops", "silent"):
            drop, corrupt = {"bitflips": (0.0, 0.05), "drops": (0.1, 0.0), "silent": (1.0, 0.0)}[kind]
            device.noise(drop, corrupt)
            time.sleep(params.get("seconds", NOISE_SECONDS))
            device.noise(0.0, 0.0)
        elif kind == "reboot":
            device.reboot()
        elif kind == "fault_bit":
            device.fault(params["bit"])
        elif kind == "device_stall":  # the device process gets no CPU for a while: setpoints queue in its socket
            pid = device.pid
            event["pid"] = pid
            if pid:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGSTOP)
                    try:
                        time.sleep(params.get("seconds", 2.0))
                    finally:
                        os.kill(pid, signal.SIGCONT)
        elif kind == "stuck_axis":  # the pan axis held mechanically: no fault bit, the encoder tells the truth
            seconds = params.get("seconds", STUCK_SECONDS)
            device.stuck(params.get("axis", "pan"), seconds)
            time.sleep(seconds)
        elif kind == "stale_pose":  # the pose source stops publishing for a while
            self.sim.send_signal(signal.SIGSTOP)
            time.sleep(params.get("seconds", 2.0))
            self.sim.send_signal(signal.SIGCONT)
        elif kind == "planner_stall":  # the planner process gets no CPU at all for a while
            pid = (self.status.get("planner") or {}).get("worker_pid")
            event["pid"] = pid
            if pid:
                with contextlib.suppress(ProcessLookupError):
                    os.kill(pid, signal.SIGSTOP)
                    time.sleep(params.get("seconds", 3.0))
                    os.kill(pid, signal.SIGCONT)
        elif kind == "off_path":  # the route's path a few metres to the side for a while, then the true path
            t0 = time.time()
            self.vandal.off_path(params.get("seconds", 6.0))
            end = time.time()
            event["off_path_seen"] = any((st.get("planner") or {}).get("path_mode") == "off_path"
                                         for st in list(self.probe.statuses) if t0 < st.get("time", 0) <= end)
            back = self.wait(lambda st: (st.get("planner") or {}).get("path_mode") == "on_path", RECOVERY_TIMEOUT_S,
                             since=end)
            event["on_path_s"] = None if back is None else round(back, 2)
        elif kind == "recorder_failure":  # the recording's file fails mid-run (its reader goes away: EPIPE)
            if self.recording is None or not self.recording.open:
                raise ValueError("recorder_failure needs a SoakStack(record=True) whose recording still runs")
            self.recording.close()
            # the fault ends when the daemon has seen it: its next chunk of the recording failed
            event["recording_failed"] = self.wait(
                lambda st: (st.get("recording") or {}).get("state") == "failed", RECOVERY_TIMEOUT_S) is not None
        elif kind == "reload_storm":  # a burst of SIGHUPs with the config unchanged: reloads coalesce, plans go on
            for _ in range(params.get("count", RELOAD_STORM)):
                with contextlib.suppress(ProcessLookupError):
                    os.kill(self.daemon.pid, signal.SIGHUP)
                self.sighups += 1
                time.sleep(params.get("gap_s", RELOAD_STORM_GAP_S))
        elif kind in BUS_EVENTS:
            position = self.probe.poses[-1][1] if self.probe.poses else np.zeros(3)
            self.vandal.send(kind, np.asarray(position, float))
        else:
            raise ValueError(f"unknown fault {kind!r}")
        return event

    def inject_and_recover(self, kind: str, **params) -> dict:
        """:meth:`inject`, then the recovery time: from the end of the fault to the first status document that
        shows the daemon healthy again (documents at 5 Hz, so a resolution of 0.2 s; those made within
        ``GRACE_S`` of the end may predate the fault's effect and are not judged). After a reload storm, healthy
        also means every SIGHUP the daemon received answered and a plan made after the storm."""
        event = self.inject(kind, **params)
        end = time.time()
        healthy = _healthy
        if kind == "reload_storm":
            plans = (self.status.get("planner") or {}).get("plans", 0)

            def healthy(st: dict) -> bool:  # every SIGHUP it received answered (the kernel merges pending ones)
                answered = st.get("reloads", 0) + st.get("reload_errors", 0) + st.get("reloads_coalesced", 0)
                return (_healthy(st) and 0 < st.get("reload_requests", 0) == answered
                        and (st.get("planner") or {}).get("plans", 0) > plans)
        recovery = self.wait(healthy, RECOVERY_TIMEOUT_S, since=end + GRACE_S)
        event["recovery_s"] = None if recovery is None else round(recovery + GRACE_S, 2)
        log.info("event %s", event)
        return event


EVENT_KINDS = (*DEVICE_EVENTS, *BUS_EVENTS, "silent", "stale_pose", "planner_stall", "off_path", "device_stall",
               "reload_storm", "stuck_axis", *ONCE_EVENTS)


def summarise(stack: SoakStack, events: list[dict], warmup: float, exit_code: int | None) -> dict:
    """Setpoint check, tracebacks, RSS growth and recovery statistics of a finished run."""
    check = check_device_log(stack.cfg, stack.out / "gimbal.csv")
    tracebacks, first = 0, []
    for path in stack.daemon_logs():
        n, lines = count_tracebacks(path)
        tracebacks += n
        first += lines
    recoveries: dict[str, dict] = {}
    for kind in sorted({e["kind"] for e in events}):
        rec = [e["recovery_s"] for e in events if e["kind"] == kind]
        ok = [r for r in rec if r is not None]
        recoveries[kind] = {"n": len(rec), "not_recovered": len(rec) - len(ok),
                            "median_s": round(float(np.median(ok)), 2) if ok else None,
                            "max_s": round(max(ok), 2) if ok else None}
    return {
        "events": len(events),
        "setpoints": check.setpoints, "checked_pairs": check.checked_pairs,
        "restarts": check.restarts, "restarted_steps": check.restarted_steps, "axis_restarts": check.axis_restarts,
        "setpoints_beyond_limits": check.beyond_limits,
        "beyond": {"position": check.beyond_position, "step": check.beyond_step, "velocity": check.beyond_velocity,
                   "acceleration": check.beyond_acceleration, "jerk": check.beyond_jerk},
        "worst_ratio_to_limit": check.worst,
        "tracebacks": tracebacks, "traceback_lines": first[:5],
        "rss": rss_growth(stack.rss, warmup), "warmup_s": warmup,
        "rss_samples": [(round(t, 1), round(v, 1)) for t, v in stack.rss],
        "recovery": recoveries, "not_recovered": sum(r["not_recovered"] for r in recoveries.values()),
        "daemon_exit_code": exit_code, "event_log": events,
    }


def soak(minutes: float, out: Path, seed: int = 1, mean_gap: float = 6.0, warmup: float | None = None,
         max_unplug_s: float | None = None, min_events: int = 0) -> dict:
    """Random faults for ``minutes`` with logs in ``out``; returns the results (see the module docstring).

    ``max_unplug_s``: leave out the unplug durations longer than this [s] (a short run that must not spend
    a minute unplugged; the matrix and its test keep the long one). ``min_events``: go on after ``minutes``
    until that many faults were injected (a short run on a loaded machine spends more of its time recovering)."""
    unplugs = {s: w for s, w in UNPLUG_SECONDS.items() if max_unplug_s is None or s <= max_unplug_s}
    duration = minutes * 60.0
    warmup = min(120.0, max(5.0, 0.1 * duration)) if warmup is None else warmup
    events: list[dict] = []
    with SoakStack(out, seed, record=True) as stack:
        rng = stack.rng
        if stack.wait_healthy(90.0) is None:
            raise RuntimeError(f"pivotd never started tracking; see {out / 'pivotd.log'}")
        kinds = {**DEVICE_EVENTS, **BUS_EVENTS, **RANDOM_EXTRA_EVENTS, **ONCE_EVENTS}

        def running() -> bool:
            return time.monotonic() - stack.t_start < duration or len(events) < min_events

        while running():
            gap_end = time.monotonic() + rng.uniform(0.5, 1.5) * mean_gap
            while time.monotonic() < gap_end:
                stack.sample_rss()
                time.sleep(0.1)
            if not running():
                break
            if stack.recording is not None and not stack.recording.open:
                kinds.pop("recorder_failure", None)  # it happened: the recording stopped for good
            kind = rng.choices(list(kinds), list(kinds.values()))[0]
            params: dict = {}
            if kind == "unplug":
                params["seconds"] = rng.choices(list(unplugs), list(unplugs.values()))[0]
            elif kind == "fault_bit":
                params["bit"] = rng.randrange(8)
            events.append(stack.inject_and_recover(kind, **params))
        stack.sample_rss(every=0.0)
        exit_code = stack.stop_daemon()
    r = summarise(stack, events, warmup, exit_code)
    return {"minutes": minutes, "seed": seed, **r}


#: the deterministic fault matrix of docs/RELIABILITY.md: (kind, parameters), one after the other
MATRIX: tuple[tuple[str, dict], ...] = (
    ("unplug", {"seconds": 0.5}), ("unplug", {"seconds": 5.0}), ("unplug", {"seconds": 60.0}),
    ("drops", {"seconds": 5.0}), ("bitflips", {"seconds": 5.0}), ("silent", {"seconds": 3.0}), ("reboot", {}),
    *(("fault_bit", {"bit": b}) for b in range(8)),
    ("stale_pose", {"seconds": 2.0}), ("nan_pose", {}), ("teleport", {}), ("pose_flood", {}), ("past_pose", {}),
    ("garbage", {}), ("path_empty", {}), ("path_single", {}), ("path_far", {}), ("path_huge", {}),
    ("path_garbage", {}), ("planner_stall", {"seconds": 3.0}), ("off_path", {"seconds": 6.0}),
    ("device_stall", {"seconds": 2.0}), ("reload_storm", {"count": RELOAD_STORM}),
    ("stuck_axis", {"seconds": STUCK_SECONDS}), ("recorder_failure", {}),
)


def matrix(out: Path, seed: int = 1, skip_long: bool = False) -> dict:
    """Every row of :data:`MATRIX` once (``skip_long``: without the 60 s unplug), then SIGKILL mid-motion and a
    restart (time to tracking again), then SIGTERM mid-motion (time to exit); returns the results."""
    rows: list[dict] = []
    with SoakStack(out, seed, record=True) as stack:
        if stack.wait_healthy(90.0) is None:
            raise RuntimeError(f"pivotd never started tracking; see {out / 'pivotd.log'}")
        for kind, params in MATRIX:
            if skip_long and params.get("seconds", 0) > 30:
                continue
            time.sleep(2.0)
            rows.append(stack.inject_and_recover(kind, **params))
        time.sleep(2.0)
        t0 = time.time()
        stack.stop_daemon(signal.SIGKILL)  # daemon and planner process, as systemd stops a unit whose main died
        stack.start_daemon()  # what systemd's Restart=on-failure does (after RestartSec)
        healthy = stack.wait_healthy(RECOVERY_TIMEOUT_S, since=t0)
        rows.append({"kind": "sigkill_restart", "recovery_s": None if healthy is None else round(healthy, 2)})
        time.sleep(2.0)
        t0 = time.monotonic()
        code = stack.stop_daemon(signal.SIGTERM)
        rows.append({"kind": "sigterm", "exit_code": code, "recovery_s": round(time.monotonic() - t0, 2)})
    r = summarise(stack, rows, warmup=1e9, exit_code=code)
    r.pop("rss")
    return {"seed": seed, **r}


def _stop(proc, sig: int, timeout: float) -> int | None:
    """Send ``sig`` (SIGKILL: to the whole process group, planner process included) and wait for the exit code."""
    with contextlib.suppress(ProcessLookupError):
        if sig == signal.SIGKILL:
            os.killpg(proc.pid, sig)
        else:
            proc.send_signal(sig)
    try:
        return proc.wait(timeout=timeout)
    except Exception:
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, signal.SIGKILL)
        proc.wait()
        return None


def passed(r: dict) -> bool:
    """The soak's verdict: no setpoint beyond limits, no traceback, RSS growth < 5 %, every event recovered,
    clean exit after SIGTERM."""
    growth = r.get("rss", {}).get("growth")
    return (r["setpoints_beyond_limits"] == 0 and r["tracebacks"] == 0 and r["not_recovered"] == 0
            and r["daemon_exit_code"] == 0 and (growth is None or growth < 0.05))


def _print_matrix(r: dict) -> None:
    print(f"fault matrix (seed {r['seed']}): {r['events']} faults, {r['setpoints']} setpoints, "
          f"{r['setpoints_beyond_limits']} beyond limits {r['beyond']}, {r['tracebacks']} tracebacks")
    print(f"  {'fault':<16} {'parameters':<12} {'recovery':>9}")
    for e in r["event_log"]:
        params = ", ".join(f"{k}={v}" for k, v in e.items() if k in ("seconds", "bit", "exit_code"))
        rec = "never" if e["recovery_s"] is None else f"{e['recovery_s']} s"
        print(f"  {e['kind']:<16} {params:<12} {rec:>9}")


def _print_soak(r: dict) -> None:
    rss = r["rss"]
    print(f"soak: {r['minutes']:g} min, {r['events']} events (seed {r['seed']}), {r['setpoints']} setpoints "
          f"({r['checked_pairs']} consecutive pairs checked for acceleration and jerk)")
    print(f"  setpoints beyond limits: {r['setpoints_beyond_limits']} {r['beyond']}; worst ratio to limit "
          f"{r['worst_ratio_to_limit']}")
    print(f"  restarts after the device stopped, judged from its measured state: {r['restarts']} "
          f"({r['restarted_steps']} of them after late setpoints of the old stream)")
    print(f"  tracebacks in the daemon log: {r['tracebacks']} {r['traceback_lines'] or ''}")
    print(f"  RSS after {r['warmup_s']:g} s warm-up: {rss.get('baseline_mb')} -> {rss.get('final_mb')} MB "
          f"(growth {rss.get('growth')}, max {rss.get('max_mb')} MB, {rss['samples']} samples)")
    print(f"  {'event':<13} {'n':>4} {'recovery median':>16} {'max':>8} {'not recovered':>14}")
    for kind, rec in r["recovery"].items():
        print(f"  {kind:<13} {rec['n']:>4} {str(rec['median_s']) + ' s':>16} {str(rec['max_s']) + ' s':>8} "
              f"{rec['not_recovered']:>14}")
    print(f"  daemon exit code after SIGTERM: {r['daemon_exit_code']}")


def run(args: argparse.Namespace) -> int:
    if args.minutes <= 0:
        raise SystemExit("pivotd bench soak: --minutes must be > 0")
    with contextlib.ExitStack() as stack:
        out = args.out or Path(stack.enter_context(tempfile.TemporaryDirectory(prefix="pivotd-soak-")))
        out.mkdir(parents=True, exist_ok=True)
        if args.matrix:
            r = matrix(out, args.seed, args.skip_long)
            _print_matrix(r)
        else:
            r = soak(args.minutes, out, args.seed, args.mean_gap, args.warmup)
            _print_soak(r)
    ok = passed(r)
    print(f"  verdict: {'PASS' if ok else 'FAIL'} (0 beyond limits, 0 tracebacks, RSS growth < 5 %, all recovered, "
          "exit 0)")
    if args.json:
        args.json.write_text(json.dumps(r, indent=2))
    return 0 if ok else 1
