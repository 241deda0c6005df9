"""``pivotd bench bus``: codec costs and loopback delivery latency of the Zenoh/ROS 2 bus.

Reports medians (and p99 for latencies) measured in one run, single process, two Zenoh peer
sessions connected over TCP on 127.0.0.1 (scouting off):

* codec: encode JointState, decode Odometry, encode view plan (N poses), decode PointCloud2 (N points),
  encode the live markers of a plan (pivotd's CDR writer vs rosbags objects, side by side),
  decode a 4 MiB Path with pivotd's reader and with rosbags' generic decoder (side by side)
* latency: remote Odometry put -> PivotBus ``on_pose`` callback (CDR decode + validation included),
  and PivotBus.publish_joint_state -> a raw subscriber in the other session.
"""

from __future__ import annotations

import argparse
import json
import logging
import queue
import socket
import statistics
import time
from collections.abc import Callable
from pathlib import Path

import numpy as np

from pivotd.progress import with_progress


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="fewer repeats and smaller clouds")
    parser.add_argument("--json", default=None, metavar="FILE", help="also write the results as JSON")
    parser.add_argument("--flood", type=float, default=None, metavar="SECONDS",
                        help="instead: the daemon tracking while flooded with large messages, SECONDS per phase "
                             "(pivotd.bench.flood)")
    parser.add_argument("--flood-mb", type=float, default=20.0, help="size of each flood message [MB]")
    parser.add_argument("--flood-compare-with", type=Path, default=None, metavar="DIR",
                        help="with --flood: a checkout of another commit whose daemon also runs the no-flood and "
                             "default-limits phases, interleaved (phases '@other')")
    parser.add_argument("--realtime-priority", type=int, default=0, metavar="N",
                        help="with --flood: also run the no-flood and default-limits phases with the control "
                             "thread at SCHED_FIFO priority N (phases '-fifo'; needs CAP_SYS_NICE)")


def _median_us(fn: Callable[[], object], repeats: int) -> float:
    fn()
    times = []
    for _ in range(repeats):
        t = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t)
    return 1e6 * statistics.median(times)


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def codec_results(quick: bool) -> dict[str, float]:
    from pivotd.bus import messages as m

    reps = 200 if quick else 2000
    odom = m.encode_odometry(1.0, "map", "base_link", [1, 2, 3], [0, 0, 0, 1])
    out = {
        "encode_joint_state_us": _median_us(lambda: m.encode_joint_state(1.0, ["pan", "tilt"], [0.1, 0.2],
                                                                          [0.0, 0.0]), reps),
        "decode_odometry_us": _median_us(lambda: m.decode_pose(odom, m.ODOMETRY, "/odom"), reps),
    }
    rng = np.random.default_rng(0)
    n_plan = 100
    pos, dirs = rng.normal(size=(n_plan, 3)), rng.normal(size=(n_plan, 3))
    out[f"encode_view_plan_{n_plan}_us"] = _median_us(lambda: m.encode_view_plan(1.0, "map", pos, dirs),
                                                       max(20, reps // 20))
    out.update(_marker_results(rng, max(20, reps // 20)))
    for n in ((10_000, 100_000) if quick else (10_000, 100_000, 1_000_000)):
        cloud = m.encode_cloud(1.0, "map", rng.normal(size=(n, 3)), rng.uniform(0, 1, n))
        out[f"decode_cloud_{n}_us"] = _median_us(lambda c=cloud, k=n: m.decode_cloud(c, "/c", max_points=k),
                                                 5 if quick else 15)
    # A path at the default size limit (4 MiB, ~58k poses): pivotd's CDR reader vs rosbags' generic decoder.
    from pivotd.bus.large_messages import large_path

    path = large_path(4 * 1024 * 1024)
    out["decode_path_4MiB_us"] = _median_us(lambda: m.decode_path(path, "/p"), 3 if quick else 7)
    out["decode_path_4MiB_rosbags_us"] = _median_us(lambda: m.deserialize(path, m.PATH, "/p"), 1 if quick else 3)
    return out


def _marker_results(rng: np.random.Generator, reps: int) -> dict[str, float]:
    """The live markers of a 20-waypoint plan with 200 landmarks in view: the fast CDR writer and rosbags."""
    from pivotd.bus.marker_cdr import encode_marker_array, encode_marker_array_reference
    from pivotd.bus.markers import MarkerStyle, plan_marker_specs, reach_directions
    from pivotd.gimbal.kinematics import JointLimits, Mount

    pos, dirs = rng.normal(size=(20, 3)), rng.normal(size=(20, 3))
    dirs /= np.linalg.norm(dirs, axis=1)[:, None]
    reach = reach_directions(np.array([0.0, 0.0, 0.0, 1.0]), Mount(), JointLimits())
    specs = plan_marker_specs(MarkerStyle(fov=1.0), pos, dirs, rng.normal(size=(200, 3)), reach)
    fast = _median_us(lambda: encode_marker_array(1, 0, "map", specs), reps)
    slow = _median_us(lambda: encode_marker_array_reference(1, 0, "map", specs), max(5, reps // 4))
    return {"encode_plan_markers_20_us": fast, "encode_plan_markers_20_rosbags_us": slow,
            "encode_plan_markers_speedup": slow / fast}


def latency_results(quick: bool) -> dict[str, float]:
    from pivotd.bus import messages as m
    from pivotd.bus.pivot_bus import PivotBus
    from pivotd.bus.ros import RosNode
    from pivotd.bus.session import open_session
    from pivotd.bus.topics import BusTopics

    count = 200 if quick else 2000
    endpoint = f"tcp/127.0.0.1:{_free_port()}"
    a = open_session(listen=[endpoint])
    b = open_session(connect=[endpoint])
    arrivals: queue.Queue = queue.Queue()
    bus = PivotBus(a, BusTopics(), on_pose=lambda s: arrivals.put(time.perf_counter()))
    node = RosNode(b, "bench")
    out: dict[str, float] = {}
    try:
        odom = node.publisher("/odom", m.ODOMETRY)
        _wait(odom.matched)
        payload = m.encode_odometry(1.0, "map", "base_link", [1, 2, 3], [0, 0, 0, 1])
        out.update(_latencies("pose_to_callback", count, lambda: odom.put(payload), arrivals))
        joint_rx: queue.Queue = queue.Queue()
        sub = b.declare_subscriber("0/pivot/joint_states/*/*", lambda s: joint_rx.put(time.perf_counter()))
        _wait(bus.joint_state_publisher.matched)
        out.update(_latencies("joint_state_to_subscriber", count,
                              lambda: bus.publish_joint_state(1.0, 0.1, 0.2, 0.0, 0.0), joint_rx))
        sub.undeclare()
    finally:
        bus.close()
        node.close()
        b.close()
        a.close()
    return out


def _wait(pred: Callable[[], bool], timeout: float = 10.0) -> None:
    end = time.monotonic() + timeout
    while not pred():
        if time.monotonic() > end:
            raise RuntimeError("bench sessions did not match on loopback")
        time.sleep(0.01)


def _latencies(name: str, count: int, send: Callable[[], None], arrivals: queue.Queue) -> dict[str, float]:
    lat = []
    for _ in range(count):
        t = time.perf_counter()
        send()
        lat.append(arrivals.get(timeout=5.0) - t)
        time.sleep(0.001)
    us = np.array(lat) * 1e6
    return {f"{name}_median_us": float(np.median(us)), f"{name}_p99_us": float(np.percentile(us, 99))}


def run(args: argparse.Namespace) -> int:
    if args.flood is not None:
        from pivotd.bench.flood import run_flood

        other = args.flood_compare_with
        if other is not None and not (other / "pivotd" / "cli" / "__main__.py").is_file():
            raise SystemExit(f"pivotd bench bus: --flood-compare-with {other}: not a pivotd checkout")
        if not 0 <= args.realtime_priority <= 99:
            raise SystemExit(f"pivotd bench bus: --realtime-priority {args.realtime_priority}: must be 0..99")
        return run_flood(args.flood, args.flood_mb, args.json, other, args.realtime_priority)
    results: dict[str, float | bool] = {"quick": bool(args.quick)}
    for stage in with_progress((codec_results, latency_results), "bus benchmarks"):
        results.update(stage(args.quick))
    for key, value in results.items():
        if key != "quick":
            print(f"{key:<40} {value:12.1f}")
    if args.json:
        with open(args.json, "w") as f:
            json.dump(results, f, indent=1)
    return 0


if __name__ == "__main__":
    import sys

    from pivotd.bench import pin_single_thread

    pin_single_thread()
    logging.basicConfig(level=logging.WARNING)
    p = argparse.ArgumentParser(prog="python -m pivotd.bench.bus", description=__doc__.splitlines()[0])
    configure(p)
    sys.exit(run(p.parse_args()))
