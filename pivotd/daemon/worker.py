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
``("plan", id, Plan)``, ``("map", id, MapInfo)``, ``("error", id, message)`` (one line), and while a request
is being computed ``("busy", id, elapsed_s)`` every :data:`HEARTBEAT_S` (a heartbeat, not a reply). Every
reply echoes its request's id, so a reply that arrives after its request timed out is recognised and dropped
instead of being taken as the answer to a later request.

A slow replan is not a dead worker: the parent waits for a replan as long as the heartbeats come, up to
``planner.replan_deadline_s``, and restarts the worker only when it falls silent for :data:`SILENT_AFTER_S`
(dead, stopped, or stuck in native code) or the deadline passes. Killing a worker that is computing would
only reload the map and start the same slow replan again; the planner instead plans less after a replan
slower than ``planner.replan_budget_s`` (:class:`~pivotd.daemon.planner.RecedingHorizonPlanner`).
"""

from __future__ import annotations

import logging
import multiprocessing as mp
import os
import signal
import threading
import time
from dataclasses import dataclass, field

import numpy as np

from pivotd.bus.ratelimit import RateLimitedLog
from pivotd.config import Config
from pivotd.daemon.planner import PathMode, Plan
from pivotd.daemon.wiring import map_files_identity
from pivotd.errors import PivotdError
from pivotd.maps.fingerprint import MapIdentity
from pivotd.maps.formats import LandmarkCloud
from pivotd.maps.store import BASE_LAYER

log = logging.getLogger(__name__)

START_TIMEOUT_S = 60.0
WORKER_NICE = 10  # niceness added to the planner process
HEARTBEAT_S = 0.1  # [s] period of the worker's "busy" messages while it computes a request
SILENT_AFTER_S = 2.0  # [s] a replan whose worker sent nothing for this long is given up (the worker is hung)
#: Most landmarks of the map file's layer in :attr:`MapInfo.preview` (what the daemon republishes on the landmarks
#: topic, ``topics.publish_map``): a larger map is strided, every k-th landmark of the store's order, which is
#: sorted by grid cell, so the sample spans the whole map.
MAX_PREVIEW_POINTS = 100_000


@dataclass(frozen=True)
class MapInfo:
    """landmarks: total count; version: the map's version (the worker's store; :class:`PlannerWorker` reports one
    that increases at every change across reloads and restarts); layers: name -> count; preview: (points (K, 3)
    float32 [m], weights (K,) float32) of the map file's layer, at most :data:`MAX_PREVIEW_POINTS` (strided), in
    the replies that (re)loaded the map file, else None."""

    landmarks: int
    version: int
    layers: dict[str, int]
    preview: tuple[np.ndarray, np.ndarray] | None = field(default=None, compare=False, repr=False)


class WorkerError(PivotdError):
    """The planner worker cannot serve (failed start-up, died, or stopped answering); one line."""


class ReplanTimeoutError(WorkerError):
    """A replan given up (worker silent, or past the deadline); ``elapsed_s`` [s] from the request to giving up."""

    def __init__(self, message: str, elapsed_s: float) -> None:
        super().__init__(message)
        self.elapsed_s = elapsed_s


class _NoAnswerError(WorkerError):
    """No reply in time (deadline passed, or the worker silent)."""


class RequestError(PivotdError):
    """The planner worker is alive but refused a request (bad map, bad config, optimizer error); one line."""


def _map_info(store, preview: bool = False) -> MapInfo:
    snap = store.snapshot()
    return MapInfo(len(snap), snap.version, {name: info.count for name, info in snap.layers.items()},
                   _base_preview(snap) if preview else None)


def _base_preview(snap) -> tuple[np.ndarray, np.ndarray]:
    """The map file's layer of ``snap``, strided to at most :data:`MAX_PREVIEW_POINTS` landmarks (copies)."""
    info = snap.layers.get(BASE_LAYER)
    if info is None or info.count == 0:
        return np.zeros((0, 3), np.float32), np.zeros(0, np.float32)
    step = -(-info.count // MAX_PREVIEW_POINTS)
    return (np.ascontiguousarray(snap.points[info.rows][::step]),
            np.ascontiguousarray(snap.weights[info.rows][::step]))


class _ParentPipe:
    """The worker's end of the pipe: a daemon that is gone (killed, or stopped before the worker was ready) ends
    the worker quietly instead of with a BrokenPipeError traceback."""

    def __init__(self, conn) -> None:
        self._conn = conn
        self._lock = threading.Lock()  # the heartbeat thread sends too
        self._busy: tuple[int, float] | None = None  # (request id, start [monotonic s]) being computed

    def send(self, obj: object) -> None:
        with self._lock:
            self._busy = None  # a reply ends the heartbeats of its request (no "busy" after it)
            self._send(obj)

    def _send(self, obj: object) -> None:
        try:
            self._conn.send(obj)
        except (BrokenPipeError, ConnectionResetError):
            raise SystemExit(0) from None

    def recv(self) -> object:
        return self._conn.recv()

    def begin(self, req_id: int) -> None:
        """Heartbeats for ``req_id`` from now until its reply is sent."""
        with self._lock:
            self._busy = (req_id, time.monotonic())

    def heartbeat_forever(self) -> None:
        """Thread body: a "busy" message every :data:`HEARTBEAT_S` while a request is being computed (the parent
        reads them while it waits for that request, so they never pile up in the pipe)."""
        while True:
            time.sleep(HEARTBEAT_S)
            with self._lock:
                if self._busy is not None:
                    req_id, t0 = self._busy
                    try:
                        self._conn.send(("busy", req_id, time.monotonic() - t0))
                    except (OSError, ValueError):
                        return


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
    from pivotd.daemon.logqueue import install as install_log_queue

    install_log_queue(log_level, fmt="%(asctime)s %(levelname)s %(name)s[worker]: %(message)s")  # never blocks
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
    conn.send(("ready", 0, _map_info(store, preview=True)))
    threading.Thread(target=conn.heartbeat_forever, name="pivotd-planner-heartbeat", daemon=True).start()
    rl = RateLimitedLog(log)  # a failing replan fails again at every request: one traceback per 5 s
    layers: dict[str, tuple[LandmarkCloud, float]] = {}
    path_args: tuple = (None, None, 0)
    while True:
        try:
            msg = conn.recv()
        except (EOFError, OSError):
            return
        kind, req_id, args = msg[0], msg[1], msg[2:]
        if kind in ("replan", "layer", "reload"):
            conn.begin(req_id)
        try:
            if kind == "replan":
                position, quat, anchor, now = args
                conn.send(("plan", req_id, planner.replan(store.snapshot(), position, quat, anchor, now)))
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
                conn.send(("map", req_id, _map_info(store, preview=reload_map)))
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
        self._map_changes = 0  # maps the worker loaded or changed: the map version the daemon reports
        self.map_identity: MapIdentity = ()  # the map files as they were when the worker last read them
        # The map file's landmarks as last (re)loaded, strided (MapInfo.preview), and how many loads so far.
        self.map_preview: tuple[np.ndarray, np.ndarray] = (np.zeros((0, 3), np.float32), np.zeros(0, np.float32))
        self.map_previews = 0
        self._proc = None
        self._conn = None
        self._next_id = 0
        self.stale_replies = 0  # replies that arrived after their request had timed out (dropped)
        self.late = 0  # replans answered after planner.replan_budget_s
        self.timeouts = 0  # replans given up (silent worker or past planner.replan_deadline_s)
        self.off_path_replans = 0  # plans made for the pose alone because the robot was too far from the path
        self.path_mode: PathMode | None = None  # that of the last plan
        self._rl = RateLimitedLog(log)
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
        self._set_map_info(payload)
        self.map_identity = identity

    @property
    def pid(self) -> int | None:
        return None if self._proc is None else self._proc.pid

    def _new_id(self) -> int:
        self._next_id += 1
        return self._next_id

    def _request(self, kind: str, *args, timeout: float, silent_after: float | None = None) -> tuple[str, object]:
        """Send one request and wait for the reply carrying its id; returns (reply kind, payload).

        Gives up (WorkerError) ``timeout`` [s] after sending, or once the worker sent neither the reply nor a
        heartbeat for ``silent_after`` [s] (None: heartbeats do not matter)."""
        with self._lock:
            req_id = self._new_id()
            start = time.monotonic()
            deadline = start + timeout
            heard = start
            try:
                self._conn.send((kind, req_id, *args))
                while True:
                    now = time.monotonic()
                    until = deadline if silent_after is None else min(deadline, heard + silent_after)
                    if until - now <= 0 or not self._conn.poll(until - now):
                        if silent_after is not None and time.monotonic() < deadline:
                            raise _NoAnswerError(f"planner worker is silent: no answer to {kind!r} and no "
                                                 f"heartbeat for {silent_after:.1f} s")
                        raise _NoAnswerError(f"planner worker did not answer {kind!r} within {timeout:.1f} s")
                    reply_kind, reply_id, payload = self._conn.recv()
                    if reply_kind == "busy":
                        if reply_id == req_id:
                            heard = time.monotonic()
                        continue
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
               timeout: float | None = None, now: float | None = None) -> Plan:
        """The worker's plan for the pose (received at ``now`` [s, monotonic], for the robot's speed); waits while
        the worker computes (heartbeats), up to ``timeout`` [s] (default ``planner.replan_deadline_s``). Raises
        ReplanTimeoutError when given up (the worker is then in an unknown state: restart it), WorkerError when it
        is gone, RequestError when it refused."""
        pl = self._cfg.planner
        timeout = pl.replan_deadline if timeout is None else timeout
        t0 = time.monotonic()
        try:
            kind, payload = self._request("replan", position, quat, anchor, now, timeout=timeout,
                                          silent_after=SILENT_AFTER_S)
        except _NoAnswerError as exc:
            self.timeouts += 1
            raise ReplanTimeoutError(str(exc), time.monotonic() - t0) from None
        if kind != "plan":
            raise RequestError(payload)
        self._note_path_mode(payload)
        elapsed = time.monotonic() - t0
        if elapsed > pl.replan_budget:
            self.late += 1
            self._rl.warning("late", f"planner: a replan took {elapsed:.1f} s (planner.replan_budget_s "
                             f"{pl.replan_budget:.1f} s); the worker is alive, the next replans plan less")
        return payload

    def _note_path_mode(self, plan: Plan) -> None:
        """Count off-path plans; one log line when the robot leaves the path and one when it is back."""
        mode, before = plan.path_mode, self.path_mode
        self.path_mode = mode
        if mode is PathMode.OFF_PATH:
            self.off_path_replans += 1
            if before is not PathMode.OFF_PATH:
                log.warning("planner: the robot is %.1f m from the path (planner.max_path_offset %.1f m): planning "
                            "for where it is until it is back", plan.path_offset, self._cfg.planner.max_path_offset)
        elif before is PathMode.OFF_PATH and mode is PathMode.ON_PATH:
            log.info("planner: the robot is back on the path (%.1f m from it): following the path again",
                     plan.path_offset)

    def set_layer(self, name: str, cloud: LandmarkCloud, weight_multiplier: float, timeout: float = 60.0) -> MapInfo:
        kind, payload = self._request("layer", name, cloud, weight_multiplier, timeout=timeout)
        if kind != "map":
            raise RequestError(payload)
        return self._set_map_info(payload)

    def reload(self, cfg: Config, timeout: float = 120.0, reload_map: bool = True) -> MapInfo:
        """Load ``cfg``'s planner settings, and its map if ``reload_map`` (else the worker keeps the map it has); on a
        refusal (RequestError) the worker keeps the running ones. On WorkerError (no answer in time) its state is
        unknown: restart it."""
        identity = map_files_identity(cfg) if reload_map else self.map_identity
        kind, payload = self._request("reload", cfg, reload_map, timeout=timeout)
        if kind != "map":
            raise RequestError(payload)
        self._cfg = cfg
        self.map_identity = identity
        return self._set_map_info(payload, changed=reload_map)

    def _set_map_info(self, info: MapInfo, changed: bool = True) -> MapInfo:
        """Keep the worker's map description with a version that increases at every change of the map (each
        store the worker builds, at start, restart or reload, counts from 1 again); a reload that kept the map
        keeps its version."""
        self._map_changes += int(changed)
        if info.preview is not None:
            self.map_preview = info.preview
            self.map_previews += 1
        self.map_info = MapInfo(info.landmarks, self._map_changes, info.layers)
        return self.map_info

    def close(self, timeout: float = 2.0) -> None:
        if self._proc is None:
            return
        # A replan under way (another thread waiting for it) holds the lock: do not wait for it, end the worker.
        if self._lock.acquire(timeout=timeout):
            try:
                self._conn.send(("stop", self._new_id()))
            except (OSError, BrokenPipeError):
                pass
            finally:
                self._lock.release()
        self._proc.join(timeout)
        if self._proc.is_alive():
            self._proc.kill()
            self._proc.join(1)
        self._conn.close()
        self._proc = None
