"""The planner in its own process: map store + receding-horizon PIVOT behind a pipe.

The optimizer is numpy code that holds the interpreter lock for stretches of a millisecond or more;
in the daemon's process that shows up directly as control-period jitter. The worker process owns
the landmark map and the :class:`~pivotd.daemon.planner.RecedingHorizonPlanner`; the daemon's planner
thread sends it requests and blocks on the pipe (which releases the lock), so the control thread
only ever competes with light work. A crash or hang in the optimizer cannot take the control loop
with it: the daemon restarts the worker.

Messages (tuples over a ``multiprocessing`` pipe, parent → worker):
``("replan", position, quat, anchor)``, ``("path", positions, quats, version)`` (positions None
clears it), ``("layer", name, LandmarkCloud, weight_multiplier)``, ``("reload", Config)``,
``("stop",)``. Worker → parent: ``("ready", MapInfo)``, ``("plan", Plan)``, ``("map", MapInfo)``,
``("error", message)`` (one line).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
from dataclasses import dataclass

import numpy as np

from pivotd.config import Config
from pivotd.daemon.planner import Plan
from pivotd.errors import PivotdError
from pivotd.maps.formats import LandmarkCloud

log = logging.getLogger(__name__)

START_TIMEOUT_S = 60.0
WORKER_NICE = 10  # niceness added to the planner process


@dataclass(frozen=True)
class MapInfo:
    """landmarks: total count; version: store version; layers: name -> count."""

    landmarks: int
    version: int
    layers: dict[str, int]


class WorkerError(PivotdError):
    """The planner worker cannot serve (failed start-up, died, or stopped answering); one line."""


class RequestError(PivotdError):
    """The planner worker is alive but refused a request (bad map, bad config, optimizer error); one line."""


def _map_info(store) -> MapInfo:
    snap = store.snapshot()
    return MapInfo(len(snap), snap.version, {name: info.count for name, info in snap.layers.items()})


def _worker_main(conn, cfg: Config, log_level: int) -> None:  # pragma: no cover - runs in the child
    """Child process entry: build map + planner from ``cfg``, then serve requests until told to stop."""
    # The daemon handles SIGINT/SIGHUP; the worker only ends on "stop", a closed pipe or SIGTERM.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    # Planning is background work: when the CPU is contended the control thread must win.
    os.nice(WORKER_NICE)
    logging.basicConfig(level=log_level, format="%(asctime)s %(levelname)s %(name)s[worker]: %(message)s")
    from pivotd.daemon.wiring import build_map_store, build_planner, release_free_memory

    try:
        store = build_map_store(cfg)
        planner = build_planner(cfg)
    except PivotdError as exc:
        conn.send(("error", str(exc)))
        return
    conn.send(("ready", _map_info(store)))
    layers: dict[str, tuple[LandmarkCloud, float]] = {}
    path_args: tuple = (None, None, 0)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        kind = msg[0]
        try:
            if kind == "replan":
                _, position, quat, anchor = msg
                conn.send(("plan", planner.replan(store.snapshot(), position, quat, anchor)))
            elif kind == "path":
                path_args = msg[1:]
                planner.set_path(*path_args)
            elif kind == "layer":
                _, name, cloud, mult = msg
                layers[name] = (cloud, mult)
                store.set_layer(name, cloud, weight_multiplier=mult)
                release_free_memory()
                conn.send(("map", _map_info(store)))
            elif kind == "reload":
                new_cfg: Config = msg[1]
                new_store = build_map_store(new_cfg)
                for name, (cloud, _) in layers.items():
                    mult = float(getattr(new_cfg.map.layers, name, 1.0))
                    new_store.set_layer(name, cloud, weight_multiplier=mult)
                new_planner = build_planner(new_cfg)
                new_planner.set_path(*path_args)
                store, planner = new_store, new_planner
                conn.send(("map", _map_info(store)))
            elif kind == "stop":
                return
            else:
                conn.send(("error", f"unknown request {kind!r}"))
        except PivotdError as exc:
            conn.send(("error", str(exc)))
        except Exception as exc:  # keep serving: one bad request must not end the worker
            conn.send(("error", f"{kind}: {exc!r}"))


class PlannerWorker:
    """Parent-side handle of the planner process. Methods are called from one thread at a time
    (the daemon's planner thread; start-up and reload from the main thread while it is paused)."""

    def __init__(self, cfg: Config, log_level: int = logging.INFO) -> None:
        self._ctx = mp.get_context("spawn")
        self._lock = threading.Lock()
        self._log_level = log_level
        self.restarts = 0
        self.map_info = MapInfo(0, 0, {})
        self._proc = None
        self._conn = None
        self._start(cfg)

    def _start(self, cfg: Config) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker_main, args=(child, cfg, self._log_level), name="pivotd-planner",
                                 daemon=True)
        proc.start()
        child.close()
        if not parent.poll(START_TIMEOUT_S):
            proc.kill()
            raise WorkerError(f"planner worker did not start within {START_TIMEOUT_S:.0f} s")
        try:
            kind, payload = parent.recv()
        except EOFError:
            proc.join(1)
            raise WorkerError(f"planner worker exited during start-up (exit code {proc.exitcode})") from None
        if kind != "ready":
            proc.join(5)
            raise WorkerError(payload)
        self._proc, self._conn, self._cfg = proc, parent, cfg
        self.map_info = payload

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def _request(self, msg: tuple, timeout: float) -> tuple:
        with self._lock:
            try:
                self._conn.send(msg)
                if not self._conn.poll(timeout):
                    raise WorkerError(f"planner worker did not answer {msg[0]!r} within {timeout:.1f} s")
                return self._conn.recv()
            except (EOFError, OSError, BrokenPipeError) as exc:
                raise WorkerError(f"planner worker is gone ({exc.__class__.__name__})") from None

    def _send(self, msg: tuple) -> None:
        with self._lock:
            try:
                self._conn.send(msg)
            except (OSError, BrokenPipeError) as exc:
                raise WorkerError(f"planner worker is gone ({exc.__class__.__name__})") from None

    def restart(self, cfg: Config | None = None) -> None:
        """Replace a dead or hung worker (the last good config, map layers and path are not kept)."""
        self.close()
        self.restarts += 1
        self._start(cfg or self._cfg)

    def set_path(self, positions: np.ndarray | None, quats: np.ndarray | None, version: int) -> None:
        self._send(("path", positions, quats, version))

    def replan(self, position: np.ndarray, quat: np.ndarray, anchor: np.ndarray | None,
               timeout: float = 2.0) -> Plan:
        kind, payload = self._request(("replan", position, quat, anchor), timeout)
        if kind != "plan":
            raise RequestError(payload)
        return payload

    def set_layer(self, name: str, cloud: LandmarkCloud, weight_multiplier: float, timeout: float = 60.0) -> MapInfo:
        kind, payload = self._request(("layer", name, cloud, weight_multiplier), timeout)
        if kind != "map":
            raise RequestError(payload)
        self.map_info = payload
        return payload

    def reload(self, cfg: Config, timeout: float = 120.0) -> MapInfo:
        """Load ``cfg``'s map and planner settings; on error the worker keeps the running ones."""
        kind, payload = self._request(("reload", cfg), timeout)
        if kind != "map":
            raise RequestError(payload)
        self._cfg = cfg
        self.map_info = payload
        return payload

    def close(self, timeout: float = 2.0) -> None:
        if self._proc is None:
            return
        try:
            with self._lock:
                self._conn.send(("stop",))
        except (OSError, BrokenPipeError):
            pass
        self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1)
        self._conn.close()
        self._proc = None
