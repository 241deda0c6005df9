"""The planner in its own process: map store + receding-horizon PIVOT behind a pipe.

The optimizer is numpy code that holds the interpreter lock for stretches of a millisecond or more;
in the daemon's process that shows up directly as control-period jitter. The worker process owns
the landmark map and the :class:`~pivotd.daemon.planner.RecedingHorizonPlanner`; the daemon's planner
thread sends it requests and blocks on the pipe (which releases the lock), so the control thread
only ever competes with light work. A crash or hang in the optimizer cannot take the control loop
with it: the daemon restarts the worker.

Messages are tuples over a ``multiprocessing`` pipe. Parent → worker: ``(kind, request_id, *args)`` with
``("replan", id, position, quat, anchor)``, ``("path", id, positions, quats, version)`` (positions None
clears it; no reply), ``("layer", id, name, LandmarkCloud, weight_multiplier)``,
``("reload", id, Config, reload_map)`` (a new planner; the map read again only if ``reload_map``), ``("stop", id)``.
Worker → parent: ``(kind, request_id, payload)`` with ``("ready", 0, MapInfo)``,
``("plan", id, Plan)``, ``("map", id, MapInfo)``, ``("error", id, message)`` (one line). Every reply
echoes its request's id, so a reply that arrives after its request timed out is recognised and dropped
instead of being taken as the answer to a later request.
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from dataclasses import dataclass

import numpy as np

from pivotd.bus.ratelimit import RateLimitedLog
from pivotd.config import Config
from pivotd.daemon.planner import Plan
from pivotd.daemon.wiring import map_files_identity
from pivotd.errors import PivotdError
from pivotd.maps.fingerprint import MapIdentity
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


class _ParentPipe:
    """The worker's end of the pipe: a daemon that is gone (killed, or stopped before the worker was ready) ends
    the worker quietly instead of with a BrokenPipeError traceback."""

    def __init__(self, conn) -> None:
        self._conn = conn

    def send(self, obj: object) -> None:
        try:
            self._conn.send(obj)
        except (BrokenPipeError, ConnectionResetError):
            raise SystemExit(0) from None

    def recv(self) -> object:
        return self._conn.recv()


def _worker_main(conn, cfg: Config, log_level: int) -> None:  # pragma: no cover - runs in the child
    """Child process entry: build map + planner from ``cfg``, then serve requests until told to stop."""
    conn = _ParentPipe(conn)
    # The daemon handles SIGINT/SIGHUP; the worker only ends on "stop", a closed pipe or SIGTERM.
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGHUP, signal.SIG_IGN)
    # Planning is background work: when the CPU is contended the control thread must win.
    os.nice(WORKER_NICE)
    # The optimizer's matrix products are small: BLAS threads only add hand-offs and contend with the
    # control thread (measured 0.7 ms vs 18 ms for one product on a loaded 2-core host).
    from threadpoolctl import threadpool_limits

    threadpool_limits(1)
    logging.basicConfig(level=log_level, format="%(asctime)s %(levelname)s %(name)s[worker]: %(message)s")
    from pivotd.daemon.wiring import build_map_store, build_planner, release_free_memory

    try:
        store = build_map_store(cfg)
        planner = build_planner(cfg)
    except PivotdError as exc:
        conn.send(("error", 0, str(exc)))
        return
    except Exception as exc:
        log.exception("planner worker start-up failed")
        conn.send(("error", 0, f"start-up failed: {exc!r}"))
        return
    conn.send(("ready", 0, _map_info(store)))
    rl = RateLimitedLog(log)  # a failing replan fails again at every request: one traceback per 5 s
    layers: dict[str, tuple[LandmarkCloud, float]] = {}
    path_args: tuple = (None, None, 0)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        kind, req_id, args = msg[0], msg[1], msg[2:]
        try:
            if kind == "replan":
                position, quat, anchor = args
                conn.send(("plan", req_id, planner.replan(store.snapshot(), position, quat, anchor)))
            elif kind == "path":
                path_args = args
                planner.set_path(*path_args)
            elif kind == "layer":
                name, cloud, mult = args
                layers[name] = (cloud, mult)
                store.set_layer(name, cloud, weight_multiplier=mult)
                release_free_memory()
                conn.send(("map", req_id, _map_info(store)))
            elif kind == "reload":
                new_cfg, reload_map = args
                new_store = build_map_store(new_cfg) if reload_map else store
                for name, (cloud, _) in layers.items() if reload_map else ():
                    mult = float(getattr(new_cfg.map.layers, name, 1.0))
                    new_store.set_layer(name, cloud, weight_multiplier=mult)
                new_planner = build_planner(new_cfg)
                new_planner.set_path(*path_args)
                store, planner = new_store, new_planner
                conn.send(("map", req_id, _map_info(store)))
            elif kind == "stop":
                return
            else:
                conn.send(("error", req_id, f"unknown request {kind!r}"))
        except PivotdError as exc:
            conn.send(("error", req_id, str(exc)))
        except Exception as exc:  # keep serving: one bad request must not end the worker
            rl.exception(kind, f"planner worker: {kind} request failed: {exc!r}")
            conn.send(("error", req_id, f"{kind}: {exc!r}"))


class PlannerWorker:
    """Parent-side handle of the planner process. Methods are called from one thread at a time
    (the daemon's planner thread; start-up and reload from the main thread while it is paused)."""

    def __init__(self, cfg: Config, log_level: int = logging.INFO) -> None:
        self._ctx = mp.get_context("spawn")
        self._lock = threading.Lock()
        self._log_level = log_level
        self.restarts = 0
        self.map_info = MapInfo(0, 0, {})
        self.map_identity: MapIdentity = ()  # the map files as they were when the worker last read them
        self._proc = None
        self._conn = None
        self._next_id = 0
        self.stale_replies = 0  # replies that arrived after their request had timed out (dropped)
        self._start(cfg)

    def _start(self, cfg: Config) -> None:
        identity = map_files_identity(cfg)  # before reading: a file replaced meanwhile counts as changed next time
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker_main, args=(child, cfg, self._log_level), name="pivotd-planner",
                                 daemon=True)
        proc.start()
        child.close()
        if not parent.poll(START_TIMEOUT_S):
            proc.kill()
            raise WorkerError(f"planner worker did not start within {START_TIMEOUT_S:.0f} s")
        try:
            kind, _, payload = parent.recv()
        except EOFError:
            proc.join(1)
            raise WorkerError(f"planner worker exited during start-up (exit code {proc.exitcode})") from None
        if kind != "ready":
            proc.join(5)
            raise WorkerError(payload)
        self._proc, self._conn, self._cfg = proc, parent, cfg
        self.map_info, self.map_identity = payload, identity

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id

    def _request(self, kind: str, *args, timeout: float) -> tuple[str, object]:
        """Send one request and wait for the reply carrying its id; returns (reply kind, payload)."""
        with self._lock:
            req_id = self._new_id()
            deadline = time.monotonic() + timeout
            try:
                self._conn.send((kind, req_id, *args))
                while True:
                    remaining = deadline - time.monotonic()
                    if remaining <= 0 or not self._conn.poll(remaining):
                        raise WorkerError(f"planner worker did not answer {kind!r} within {timeout:.1f} s")
                    reply_kind, reply_id, payload = self._conn.recv()
                    if reply_id == req_id:
                        return reply_kind, payload
                    self.stale_replies += 1
                    log.warning("planner worker: dropped a late %r reply to request %d", reply_kind, reply_id)
            except (EOFError, OSError, BrokenPipeError) as exc:
                raise WorkerError(f"planner worker is gone ({exc.__class__.__name__})") from None

    def _send(self, kind: str, *args) -> None:
        with self._lock:
            try:
                self._conn.send((kind, self._new_id(), *args))
            except (OSError, BrokenPipeError) as exc:
                raise WorkerError(f"planner worker is gone ({exc.__class__.__name__})") from None

    def restart(self, cfg: Config | None = None) -> None:
        """Replace a dead or hung worker (the last good config, map layers and path are not kept)."""
        self.close()
        self.restarts += 1
        self._start(cfg or self._cfg)

    def set_path(self, positions: np.ndarray | None, quats: np.ndarray | None, version: int) -> None:
        self._send("path", positions, quats, version)

    def replan(self, position: np.ndarray, quat: np.ndarray, anchor: np.ndarray | None,
               timeout: float = 2.0) -> Plan:
        kind, payload = self._request("replan", position, quat, anchor, timeout=timeout)
        if kind != "plan":
            raise RequestError(payload)
        return payload

    def set_layer(self, name: str, cloud: LandmarkCloud, weight_multiplier: float, timeout: float = 60.0) -> MapInfo:
        kind, payload = self._request("layer", name, cloud, weight_multiplier, timeout=timeout)
        if kind != "map":
            raise RequestError(payload)
        self.map_info = payload
        return payload

    def reload(self, cfg: Config, timeout: float = 120.0, reload_map: bool = True) -> MapInfo:
        """Load ``cfg``'s planner settings, and its map if ``reload_map`` (else the worker keeps the map it has); on a
        refusal (RequestError) the worker keeps the running ones. On WorkerError (no answer in time) its state is
        unknown: restart it."""
        identity = map_files_identity(cfg) if reload_map else self.map_identity
        kind, payload = self._request("reload", cfg, reload_map, timeout=timeout)
        if kind != "map":
            raise RequestError(payload)
        self._cfg = cfg
        self.map_info, self.map_identity = payload, identity
        return payload

    def close(self, timeout: float = 2.0) -> None:
        if self._proc is None:
            return
        try:
            with self._lock:
                self._conn.send(("stop", self._new_id()))
        except (OSError, BrokenPipeError):
            pass
        self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1)
        self._conn.close()
        self._proc = None
