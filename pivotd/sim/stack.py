"""One end-to-end run of the real stack: ``pivotd`` + ``tools/sim_pose`` + a simulated gimbal over Zenoh on loopback.

The demo (:mod:`pivotd.sim.demo`) and ``pivotd bench gap`` run the daemon through :func:`run_stack`: a config
(derived into the output directory with the simulator's port and, optionally, another map), a route spec for
``sim_pose`` and a speed; afterwards the bus observations and the device log are analysed
(:func:`pivotd.sim.analysis.analyse_run`) and the recording (``--record OUT/run.mcap``: the file
``OUT/run-<UTC time>.mcap``, the newest there) is read back.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from pivotd.bus.probe import BusProbe
from pivotd.config import Config, load_config
from pivotd.daemon.recorder import resolve_recording
from pivotd.robot_path import Polyline
from pivotd.sim.analysis import analyse_run
from pivotd.sim.launch import REPO, derive_config, free_port, spawn, start_gimbal_simulator
from pivotd.sim.routes import load_route
from pivotd.viz.recording import Recording, read_recording

MIN_TIMEOUT = 90.0  # [s] wall time allowed for the robot's walk at least
#: Where the daemon takes the pose from in a run (``run_stack(pose=...)``, ``make demo POSE=...``): the ``sim_pose``
#: options of each choice. ``topic``: /odom; ``tf``: TF with map -> odom at 5 Hz on /tf, odom -> base_link at the
#: pose rate; ``tf-static``: TF with map -> odom on /tf_static. With TF, /odom is still published (the analysis
#: measures visibility at its poses) but the daemon does not subscribe to it.
POSE_SOURCES = {"topic": (), "tf": ("--tf", "--tf-map-odom-hz", "5"), "tf-static": ("--tf",)}


@dataclass(frozen=True)
class StackRun:
    """What one run left: the derived config it ran with, its recording, the analysis report and series of
    :func:`analyse_run` (per-frame visibility ``n_pivot``/``n_forward`` (T,) among them), the recording read back,
    the daemon's exit code after SIGTERM (None when it had to be killed) and the device's message log."""

    config_path: Path
    cfg: Config
    recording: Path
    report: dict
    series: dict
    run: Recording
    daemon_exit: int | None
    device_log: Path


def config_route(cfg: Config) -> str:
    """The ``sim_pose`` route spec a config names: ``csv:<sim.route>``, or the built-in ``hallway``."""
    return f"csv:{cfg.sim.route}" if cfg.sim is not None and cfg.sim.route is not None else "hallway"


def route_duration(route: str, speed: float, timed: bool = False) -> float:
    """Robot time [s] of route spec ``route`` at ``speed`` [m/s] (its own time span when ``timed``)."""
    data = load_route(route)
    if timed and data.stamps is not None:
        return float(data.stamps[-1] - data.stamps[0])
    return Polyline(data.positions).length / speed


def run_stack(config_path: Path, out_dir: Path, route: str | None = None, map_file: Path | None = None,
              speed: float = 1.2, timeout: float | None = None, backend: str | None = None, timed: bool = False,
              on_status: Callable[[float, dict], None] | None = None, pose: str = "topic") -> StackRun:
    """Run the daemon with config ``config_path`` (its gimbal backend, or ``backend`` against its simulator; its map,
    or ``map_file``) while ``sim_pose`` walks ``route`` (a spec of :func:`pivotd.sim.routes.load_route`; default: the
    config's ``sim.route``, else the hallway) at ``speed`` [m/s], or by its time stamps when ``timed``. ``pose``: where
    the daemon takes the pose from (:data:`POSE_SOURCES`).

    Everything is written to ``out_dir`` (derived config ``demo.yaml``, the recording ``run-<UTC time>.mcap``,
    ``gimbal_log.csv``, logs).
    ``timeout`` [s] bounds the walk (default: 1.5 × the route's duration + 30 s, at least 90 s); ``on_status`` is
    called about once a second with the elapsed time [s] and the daemon's last status.
    """
    out_dir.mkdir(parents=True, exist_ok=True)
    base = load_config(config_path)
    backend = backend or base.gimbal.backend
    route = route or config_route(base)
    if timeout is None:
        timeout = max(MIN_TIMEOUT, 1.5 * route_duration(route, speed, timed) + 30.0)
    device_log = out_dir / "gimbal_log.csv"
    gimbal, port = start_gimbal_simulator(backend, device_log, out_dir / "mock_gimbal.log")
    if pose not in POSE_SOURCES:
        raise ValueError(f"pose must be one of {', '.join(POSE_SOURCES)}, got {pose!r}")
    changes: dict[str, object] = {"gimbal.backend": backend, "gimbal.port": port}
    if pose != "topic":
        changes["topics.pose_source"] = "tf"
    if map_file is not None:
        changes["map.file"] = str(Path(map_file).resolve())
    config_path = derive_config(config_path, out_dir / "demo.yaml", changes)
    cfg = load_config(config_path)
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    py = sys.executable
    recording = out_dir / "run.mcap"
    daemon = spawn([py, "-m", "pivotd.cli", "--config", str(config_path), "--listen", endpoint,
                    "--port", port, "--record", str(recording)], out_dir / "pivotd.log")
    sim = None
    probe = None
    exit_code = None
    try:
        probe = BusProbe.connect(endpoint, cfg.topics)
        start = time.monotonic()
        while not probe.status and time.monotonic() - start < 20:
            if daemon.poll() is not None:
                raise RuntimeError(f"pivotd exited with {daemon.returncode}; see {out_dir / 'pivotd.log'}")
            time.sleep(0.1)
        sim = spawn([py, str(REPO / "tools" / "sim_pose"), "--route", route, "--connect", endpoint,
                     "--speed", str(speed), "--rate", "50", "--wait-subscribers", "10", "--quiet",
                     *(["--timed"] if timed else []), *POSE_SOURCES[pose]], out_dir / "sim_pose.log")
        start = time.monotonic()
        last_print = 0.0
        while sim.poll() is None and time.monotonic() - start < timeout:
            if daemon.poll() is not None:
                raise RuntimeError(f"pivotd exited with {daemon.returncode}; see {out_dir / 'pivotd.log'}")
            now = time.monotonic()
            status = probe.status
            if on_status is not None and now - last_print >= 1.0 and status:
                on_status(now - start, status)
                last_print = now
            time.sleep(0.05)
        if sim.poll() not in (None, 0):
            raise RuntimeError(f"sim_pose exited with {sim.returncode}; see {out_dir / 'sim_pose.log'}")
        time.sleep(0.5)
        daemon.send_signal(signal.SIGTERM)
        try:
            exit_code = daemon.wait(timeout=15)
        except subprocess.TimeoutExpired:
            exit_code = None
    finally:
        for proc in (sim, daemon):
            if proc is not None and proc.poll() is None:
                os.killpg(proc.pid, signal.SIGKILL)
                proc.wait()
        if gimbal is not None:
            gimbal.send_signal(signal.SIGTERM)
            try:
                gimbal.wait(timeout=5)
            except subprocess.TimeoutExpired:
                os.killpg(gimbal.pid, signal.SIGKILL)
                gimbal.wait()
        if probe is not None:
            probe.close()
    obs = probe.observations()
    recording = resolve_recording(recording)  # the file this run wrote: run-<UTC time>.mcap, the newest
    run = read_recording(recording, config_path)
    report, series = analyse_run(cfg, obs, device_log, (run.commanded.angles, run.commanded.rates))
    report["daemon_exit_code"] = exit_code
    report["final_status"] = obs.status
    return StackRun(config_path, cfg, recording, report, series, run, exit_code, device_log)


def frames_below(series: dict, share: float = 0.9) -> float:
    """Share of the frames of :func:`analyse_run`'s ``series`` where the daemon's camera saw fewer than ``share`` ×
    the landmarks a forward-facing camera saw."""
    n_piv, n_fwd = np.asarray(series["n_pivot"], float), np.asarray(series["n_forward"], float)
    return float(np.mean(n_piv < share * n_fwd)) if n_piv.size else float("nan")
