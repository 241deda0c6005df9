"""``pivotd bench bus --flood``: the real daemon tracking while a peer floods it with 20 MB messages.

Runs ``pivotd`` (config/demo.yaml, 100 Hz control, in-process simulated gimbal with its message log) while
``tools/sim_pose`` walks the hallway at 50 Hz, in phases side by side in one invocation:

* ``baseline``: no flood;
* ``flood``: every second one ~``--flood-mb`` MB message, alternating a valid ``nav_msgs/Path`` on the path
  topic and a ``PointCloud2`` made of PointField entries on the targets topic (default payload limits);
* ``flood-decoded``: the same with ``topics.max_path_bytes`` raised above the message size, so every path is
  decoded (off Zenoh's thread) and replaces the robot's path.

Each phase reports, from the gimbal's log: setpoint spacing p99 in control periods and the largest gap
[s] while flooding, device watchdog trips; from the daemon: bus drop counters, resident memory growth
(daemon + planner process, max during the phase minus the median before it); then SIGTERM is sent while
the flood goes on and the time to exit and whether the gimbal was parked are reported.
"""

from __future__ import annotations

import json
import signal
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[2]
DEMO = REPO / "config" / "demo.yaml"
HOST_CLOCK_WRAP_S = 2**32 * 1e-6  # SETPOINT host time is monotonic µs modulo 2³²
EXIT_WAIT_S = 90.0  # SIGTERM -> exit longer than this is reported as such (and the daemon killed)


def _host_times(sp_t: np.ndarray, reference: float) -> np.ndarray:
    """SETPOINT host times [s] (monotonic modulo 2³² µs) unwrapped onto this process's monotonic clock near
    ``reference``."""
    t = np.unwrap(sp_t, period=HOST_CLOCK_WRAP_S)
    return t + HOST_CLOCK_WRAP_S * np.round((reference - t[-1]) / HOST_CLOCK_WRAP_S)


def watchdog_trips(faults: np.ndarray, inside: np.ndarray | None = None) -> int:
    """Rising edges of the device's watchdog fault bit in its STATE stream (only at states where ``inside``)."""
    from pivotd.firmware_proto.messages import FAULT_WATCHDOG

    bit = (np.asarray(faults, int) & FAULT_WATCHDOG) != 0
    rising = np.concatenate([bit[:1], bit[1:] & ~bit[:-1]])
    if inside is not None:
        rising &= inside
    return int(np.count_nonzero(rising))


def spacing_stats(times: np.ndarray, period: float) -> dict[str, float]:
    """Setpoint spacing p50/p99 [control periods] and largest gap [s] of sorted send times [s]."""
    gaps = np.diff(times)
    if gaps.size == 0:
        return {"setpoints": int(times.size), "spacing_p50_periods": float("nan"),
                "spacing_p99_periods": float("nan"), "max_gap_s": float("nan")}
    return {"setpoints": int(times.size), "spacing_p50_periods": round(float(np.percentile(gaps, 50)) / period, 3),
            "spacing_p99_periods": round(float(np.percentile(gaps, 99)) / period, 3),
            "max_gap_s": round(float(gaps.max()), 4)}


def run_phase(name: str, seconds: float, flood_mb: float | None, tmp: Path, changes: dict | None = None,
              forged_poses: int = 0, repo: Path | None = None,
              until: Callable[[dict], bool] | None = None, until_timeout: float = 120.0) -> dict:
    """One daemon run: ``seconds`` of tracking (with a flood when ``flood_mb``), then SIGTERM mid-flood.

    ``forged_poses``: that many poses 700 m away from the robot are also published (one every 0.5 s), which the
    daemon's pose gate must refuse. ``repo``: run the daemon of another checkout (e.g. an earlier commit); the
    flood, the pose source and the measurements stay this checkout's. ``until``: after ``seconds``, the flood (one
    message a second) and the forged poses (one every 0.5 s) go on until ``until(status)`` holds for a status
    document, at most ``until_timeout`` [s] longer (tests: a loaded machine may drop or delay a large message, and
    the newest-only pose inbox may replace a forged pose by the robot's next one before it is judged)."""
    from pivotd.bench.control import _tree_rss_mb
    from pivotd.bus import large_messages as payloads
    from pivotd.bus import messages as m
    from pivotd.bus.ros import RosNode
    from pivotd.bus.session import open_session
    from pivotd.cli.status import query_status
    from pivotd.config import load_config
    from pivotd.sim.analysis import read_device_log
    from pivotd.sim.launch import derive_config, free_port, spawn, stop_processes

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    device_log = tmp / f"gimbal_{name}.csv"
    cfg_path = derive_config(DEMO, tmp / f"{name}.yaml", {"zenoh.listen": [endpoint],
                                                          "gimbal.port": f"mock://?log={device_log}",
                                                          "control.status_hz": 2, **(changes or {})})
    cfg = load_config(cfg_path)
    py = sys.executable
    daemon = spawn([py, "-m", "pivotd.cli", "--config", str(cfg_path), "--log-level", "WARNING"],
                   tmp / f"pivotd_{name}.log", repo)
    sim = None
    session = open_session(connect=[endpoint])
    node = RosNode(session, "flooder")
    out: dict = {"phase": name}
    try:
        def status() -> dict | None:
            return next(iter(query_status(session, cfg.status_key, 2.0).values()), None)

        def wait_state(key: str, value: str, limit: float) -> None:
            t0 = time.monotonic()
            while (st := status()) is None or st.get(key) != value:
                if daemon.poll() is not None or time.monotonic() - t0 > limit:
                    raise RuntimeError(f"pivotd never reached {key}={value}; see {tmp}/pivotd_{name}.log")
                time.sleep(0.2)

        wait_state("link", "up", 60)
        sim = spawn([py, str(REPO / "tools" / "sim_pose"), "--route", "hallway", "--connect", endpoint, "--speed",
                     "1.0", "--rate", "50", "--loop", "--quiet", "--wait-subscribers", "10"], tmp / f"sim_{name}.log")
        wait_state("state", "tracking", 30)
        before = []
        for _ in range(8):
            before.append(_tree_rss_mb(daemon.pid)[0])
            time.sleep(0.25)
        floods = []
        if flood_mb:
            size = int(flood_mb * 1e6)
            floods = [(node.publisher(cfg.topics.path, m.PATH), payloads.large_path(size)),
                      (node.publisher(cfg.topics.targets, m.POINT_CLOUD2), payloads.cloud_with_fields(size))]
        forger = node.publisher(cfg.topics.pose, cfg.topics.pose_type) if forged_poses else None
        publishers = [pub for pub, _ in floods] + ([forger] if forger is not None else [])
        t_match = time.monotonic()  # the daemon's subscribers are known to these publishers before the first put
        while not all(pub.matched() for pub in publishers) and time.monotonic() - t_match < 30.0:
            time.sleep(0.05)
        forged = m.encode_pose(cfg.topics.pose_type, 0.0, "map", np.array([500.0, 500.0, 0.0]),
                               np.array([0.0, 0.0, 0.0, 1.0]))
        t_start = time.monotonic()
        peak, k, next_put = 0.0, 0, t_start
        sent = forged_sent = 0
        st: dict | None = None
        checked = -1  # flood messages sent when ``until`` was last asked
        while True:
            now = time.monotonic()
            if now - t_start >= seconds:
                if until is None or now - t_start >= seconds + until_timeout:
                    break
                if checked != k and now >= next_put - 0.5:  # half-way to the next flood message: enough?
                    checked, st = k, status()
                    if st is not None and until(st):
                        break
                now = time.monotonic()
            more = forged_sent < forged_poses or now - t_start >= seconds  # (on while ``until`` waits)
            if forger is not None and more and now - t_start >= 0.5 * (forged_sent + 1):
                forger.put(forged)
                forged_sent += 1
            if floods and now >= next_put:
                pub, payload = floods[k % len(floods)]
                pub.put(payload)
                sent += 1
                k += 1
                next_put += 1.0
            peak = max(peak, _tree_rss_mb(daemon.pid)[0])
            time.sleep(0.1)
        t_end = time.monotonic()
        st = (status() if until is None else st) or {}
        if floods:  # SIGTERM right after a flood message, as the next one arrives
            floods[k % len(floods)][0].put(floods[k % len(floods)][1])
        t_term = time.monotonic()
        daemon.send_signal(signal.SIGTERM)
        try:
            out["exit_code"] = daemon.wait(timeout=EXIT_WAIT_S)
            out["exit_s"] = round(time.monotonic() - t_term, 2)
        except subprocess.TimeoutExpired:
            daemon.kill()
            daemon.wait()
            out["exit_code"], out["exit_s"] = None, f">{EXIT_WAIT_S:g}"
        dev = read_device_log(device_log)
        host = _host_times(dev.sp_time, t_end)
        window = np.sort(host[(host >= t_start) & (host <= t_end)])
        out.update(spacing_stats(window, 1.0 / cfg.control.rate_hz))
        # device clock -> host clock: every setpoint was sent (host time) just before it was received (device time)
        offset = float(np.median(host - dev.sp_rx_time))
        st_host = dev.st_time + offset
        out["watchdog_trips"] = watchdog_trips(dev.st_faults, (st_host >= t_start) & (st_host <= t_end + 0.3))
        out["messages_sent"] = sent
        out["forged_sent"] = forged_sent
        out["pose_gate"] = st.get("pose_gate")
        out["rss_before_mb"] = round(statistics.median(before), 1)
        out["rss_growth_mb"] = round(peak - statistics.median(before), 1)
        bus = st.get("bus", {})
        out["bus"] = {t: dict(c) for t, c in bus.items() if t in (cfg.topics.path, cfg.topics.targets)}
        disabled = [row for row in dev.other if row[0] == "rx:ENABLE" and "on=0" in row[2]]
        park = np.array([cfg.gimbal.park_pan, cfg.gimbal.park_tilt])
        out["final_pan_tilt_deg"] = np.round(np.degrees(dev.st_pos[-1]), 2).tolist()
        out["parked"] = bool(disabled) and bool(np.all(np.abs(dev.st_pos[-1] - park) < np.radians(1.0)))
        if cfg.control.realtime_priority > 0:  # the daemon warns when SCHED_FIFO could not be applied
            log_text = (tmp / f"pivotd_{name}.log").read_text(errors="replace")
            out["realtime_applied"] = "not applied" not in log_text
        return out
    finally:
        node.close()
        stop_processes((sim, daemon))
        session.close()


def run_flood(seconds: float, flood_mb: float, json_path: str | None, compare_with: Path | None = None,
              realtime_priority: int = 0) -> int:
    """All phases, printed as a table (and written as JSON to ``json_path``). ``compare_with``: a checkout of
    another commit; its daemon runs the no-flood and the default-limits phases too, each right after this one's.
    ``realtime_priority`` > 0: the no-flood and default-limits phases run again with the control thread at that
    SCHED_FIFO priority (``control.realtime_priority``, as config/spot.yaml deploys it)."""
    big = int(flood_mb * 1e6) * 2
    phases: list[tuple[str, float | None, dict | None, Path | None]] = [("baseline", None, None, None)]
    if compare_with is not None:
        phases.append(("baseline@other", None, None, compare_with))
    phases.append(("flood", flood_mb, None, None))
    if compare_with is not None:
        phases.append(("flood@other", flood_mb, None, compare_with))
    phases.append(("flood-decoded", flood_mb, {"topics.max_path_bytes": big}, None))
    if realtime_priority > 0:
        rt = {"control.realtime_priority": int(realtime_priority)}
        phases += [("baseline-fifo", None, rt, None), ("flood-fifo", flood_mb, rt, None)]
    results = []
    with tempfile.TemporaryDirectory(prefix="pivotd-flood-") as tmp_s:
        for name, mb, changes, repo in phases:
            results.append(run_phase(name, seconds, mb, Path(tmp_s), changes, repo=repo))
    print(f"daemon at 100 Hz control tracking the hallway; {seconds:g} s per phase; flood: one {flood_mb:g} MB "
          "message per second (Path / PointCloud2 of PointFields, alternating); SIGTERM sent mid-flood")
    print(f"  {'phase':<15} {'spacing p50/p99':>16} {'max gap':>8} {'watchdog':>8} {'RSS +':>7} {'exit':>6} "
          f"{'parked':>6}  drops")
    for r in results:
        drops = "; ".join(f"{t} " + ", ".join(f"{k[8:]} {v}" for k, v in c.items() if k.startswith("dropped_"))
                          + f", accepted {c.get('accepted', 0)}" for t, c in r["bus"].items()) or "-"
        print(f"  {r['phase']:<15} {r['spacing_p50_periods']:>7}/{r['spacing_p99_periods']:<7}T "
              f"{r['max_gap_s']:>6} s {r['watchdog_trips']:>8} {r['rss_growth_mb']:>4} MB {r['exit_s']:>4} s "
              f"{'yes' if r['parked'] else 'NO':>6}  {drops}")
        if r.get("realtime_applied") is False:
            print(f"  {'':<15} control.realtime_priority was NOT applied (no CAP_SYS_NICE): normal scheduling")
    print("  goals while flooding: spacing p99 <= 2 periods, no gap > 0.25 s, no watchdog trip, RSS growth "
          "<= 50 MB, SIGTERM parks and exits within a few seconds")
    if json_path:
        Path(json_path).write_text(json.dumps(results, indent=2))
    return 0
