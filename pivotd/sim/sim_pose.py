"""``tools/sim_pose``: publish a robot moving along a route as ROS 2 (rmw_zenoh) Odometry/PoseStamped + Path.

The publisher side goes through :class:`pivotd.bus.ros.RosNode` and :mod:`pivotd.bus.messages`, so its
keys, attachments and liveliness tokens are the same rmw_zenoh-conformant ones pivotd uses. Header stamps
are the scheduled sample times (start wall time + k / rate), so a consumer can check timing exactly.
"""

from __future__ import annotations

import argparse
import logging
import signal
import sys
import threading
import time
from dataclasses import dataclass

import numpy as np
import zenoh

from pivotd.bus import messages as m
from pivotd.bus.ros import DURABILITY_TRANSIENT_LOCAL, QoS, RosNode
from pivotd.bus.session import open_session
from pivotd.errors import InputError, PivotdError
from pivotd.geometry import quat_to_matrix
from pivotd.sim.routes import Route, TimedRoute, load_route

log = logging.getLogger("sim_pose")


@dataclass(frozen=True)
class Gap:
    """No poses are published for ``start <= t < start + duration`` [s since the start]."""

    start: float
    duration: float

    def covers(self, t: float) -> bool:
        return self.start <= t < self.start + self.duration


def parse_gap(text: str) -> Gap:
    """``"START:DURATION"`` in seconds -> :class:`Gap`; raises InputError naming the option."""
    try:
        start_s, dur_s = text.split(":")
        gap = Gap(float(start_s), float(dur_s))
    except ValueError:
        raise InputError(f"--gap {text!r}: expected START:DURATION in seconds, e.g. 5:2") from None
    if not (np.isfinite(gap.start) and np.isfinite(gap.duration)) or gap.start < 0 or gap.duration <= 0:
        raise InputError(f"--gap {text!r}: START must be >= 0 and DURATION > 0")
    return gap


class PosePublisher:
    """Publisher facade of the simulator: Odometry and/or PoseStamped (or PoseWithCovarianceStamped) poses and the
    route's Path."""

    def __init__(self, session: zenoh.Session, domain_id: int = 0, odom_topic: str | None = "/odom",
                 pose_topic: str | None = None, path_topic: str | None = "/plan", frame_id: str = "map",
                 child_frame_id: str = "base_link", node_name: str = "sim_pose", humble: bool = False,
                 pose_type: str = m.POSE_STAMPED) -> None:
        self.node = RosNode(session, node_name, domain_id, humble=humble)
        self.frame_id = frame_id
        self.child_frame_id = child_frame_id
        self.odom = self.node.publisher(odom_topic, m.ODOMETRY, QoS(depth=10)) if odom_topic else None
        self.pose_type = pose_type
        self.pose = self.node.publisher(pose_topic, pose_type, QoS(depth=10)) if pose_topic else None
        # latched like a planner's path: a pivotd that starts later gets it at once
        self.path = self.node.publisher(path_topic, m.PATH, QoS(durability=DURABILITY_TRANSIENT_LOCAL, depth=1)) if (
            path_topic) else None

    def publish_pose(self, stamp: float, position: np.ndarray, quat: np.ndarray, velocity_world: np.ndarray) -> None:
        """Publish the body pose (map frame) and, for Odometry, its velocity in the body frame."""
        if self.odom is not None:
            v_body = quat_to_matrix(quat).T @ np.asarray(velocity_world, float)
            self.odom.put(m.encode_odometry(stamp, self.frame_id, self.child_frame_id, position, quat, v_body))
        if self.pose is not None:
            self.pose.put(m.encode_pose(self.pose_type, stamp, self.frame_id, position, quat))

    def publish_path(self, stamp: float, positions: np.ndarray, quats: np.ndarray | None) -> None:
        if self.path is not None:
            self.path.put(m.encode_path(stamp, self.frame_id, positions, quats))

    def all_matched(self) -> bool:
        """True when every enabled publisher has at least one matching subscriber."""
        return all(p.matched() for p in (self.odom, self.pose, self.path) if p is not None)

    def close(self) -> None:
        for pub in (self.odom, self.pose, self.path):
            if pub is not None:
                pub.close()
        self.node.close()


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="sim_pose", description=__doc__.splitlines()[0])
    p.add_argument("--route", default="hallway", help="'hallway' or 'csv:FILE' (default: hallway)")
    p.add_argument("--speed", type=float, default=1.0, help="speed along the route [m/s] (default 1.0)")
    p.add_argument("--timed", action="store_true",
                   help="play the route by its time stamps and attitudes (rows t,x,y,z,qw,qx,qy,qz; a repeated "
                        "position is a turn in place); --speed is then unused")
    p.add_argument("--rate", type=float, default=20.0, help="pose rate [Hz] (default 20)")
    p.add_argument("--pose-noise", type=float, default=0.0, metavar="M", help="position noise std-dev [m]")
    p.add_argument("--gap", action="append", default=[], metavar="START:DURATION",
                   help="publish no pose for DURATION s from START s (repeatable)")
    p.add_argument("--duration", type=float, default=None, metavar="S",
                   help="stop after S seconds (default: at the route's end, or never with --loop)")
    p.add_argument("--loop", action="store_true", help="restart at the beginning after the end")
    p.add_argument("--path-period", type=float, default=2.0, metavar="S", help="re-publish the path every S s")
    p.add_argument("--wait-subscribers", type=float, default=0.0, metavar="S",
                   help="wait up to S s for subscribers of every topic before starting the clock")
    p.add_argument("--mode", choices=("peer", "client"), default="peer", help="Zenoh mode (default peer)")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT", help="e.g. tcp/127.0.0.1:7447")
    p.add_argument("--listen", action="append", default=[], metavar="ENDPOINT")
    p.add_argument("--zenoh-config", default=None, metavar="FILE", help="Zenoh config file (TLS, auth, ...)")
    p.add_argument("--multicast-scouting", action="store_true", help="enable Zenoh multicast scouting")
    p.add_argument("--domain-id", type=int, default=0)
    p.add_argument("--humble", action="store_true", help="publish with ROS 2 Humble keys (no type hash)")
    p.add_argument("--odom-topic", default="/odom", help="nav_msgs/Odometry topic ('' disables)")
    p.add_argument("--pose-topic", default="", help="geometry_msgs/PoseStamped topic ('' disables, the default)")
    p.add_argument("--pose-type", default=m.POSE_STAMPED, choices=(m.POSE_STAMPED, m.POSE_WITH_COVARIANCE_STAMPED),
                   help="message type of --pose-topic (default geometry_msgs/msg/PoseStamped)")
    p.add_argument("--path-topic", default="/plan", help="nav_msgs/Path topic ('' disables)")
    p.add_argument("--frame-id", default="map")
    p.add_argument("--child-frame-id", default="base_link")
    p.add_argument("--seed", type=int, default=0, help="noise seed")
    p.add_argument("--quiet", action="store_true", help="print nothing")
    return p


def _check_args(args: argparse.Namespace) -> list[Gap]:
    for name in ("speed", "rate", "path_period"):
        v = getattr(args, name)
        if not np.isfinite(v) or v <= 0:
            raise InputError(f"--{name.replace('_', '-')} must be > 0, got {v}")
    if not np.isfinite(args.wait_subscribers) or args.wait_subscribers < 0:
        raise InputError(f"--wait-subscribers must be >= 0, got {args.wait_subscribers}")
    if not np.isfinite(args.pose_noise) or args.pose_noise < 0:
        raise InputError(f"--pose-noise must be >= 0, got {args.pose_noise}")
    if args.duration is not None and (not np.isfinite(args.duration) or args.duration <= 0):
        raise InputError(f"--duration must be > 0, got {args.duration}")
    return [parse_gap(g) for g in args.gap]


def run(args: argparse.Namespace, stop: threading.Event | None = None) -> int:
    """Publish until the route ends, ``--duration`` passes or ``stop`` is set; returns the exit code."""
    gaps = _check_args(args)
    data = load_route(args.route)
    route = Route(data.positions, data.quats)
    timed = None
    if args.timed:
        if data.stamps is None or data.quats is None:
            raise InputError(f"--timed: route {args.route!r} has no time stamps (expected rows t,x,y,z,qw,qx,qy,qz)")
        timed = TimedRoute(data.positions, data.quats, data.stamps)
    stop = stop or threading.Event()
    rng = np.random.default_rng(args.seed)
    session = open_session(args.mode, args.connect, args.listen, args.zenoh_config, args.multicast_scouting)
    pub = None
    try:
        pub = PosePublisher(session, args.domain_id, args.odom_topic or None, args.pose_topic or None,
                            args.path_topic or None, args.frame_id, args.child_frame_id, humble=args.humble,
                            pose_type=args.pose_type)
        path_quats = route.quats if route.quats is not None else np.array([route.at(s).quat for s in route.arc])
        if args.wait_subscribers > 0:
            deadline = time.monotonic() + args.wait_subscribers
            while not pub.all_matched() and time.monotonic() < deadline and not stop.is_set():
                stop.wait(0.02)
            if not args.quiet:
                log.info("subscribers %s", "matched" if pub.all_matched() else "not all matched; starting anyway")
        period = 1.0 / args.rate
        t0_wall, t0 = time.time(), time.monotonic()
        next_path, next_print, k, sent = 0.0, 0.0, 0, 0
        while not stop.is_set():
            t = k * period  # scheduled time since start [s]
            if args.duration is not None and t > args.duration:
                break
            if timed is not None:
                s = t % timed.duration if args.loop else t  # route time [s]
                if s > timed.duration and args.duration is None:
                    break
            else:
                s = args.speed * t
                if args.loop and route.length > 0:
                    s = s % route.length
                elif s > route.length and args.duration is None:
                    break
            stamp = t0_wall + t
            if t >= next_path:
                pub.publish_path(stamp, route.positions, path_quats)
                next_path += args.path_period
            in_gap = any(g.covers(t) for g in gaps)
            if not in_gap:
                pose = timed.at_time(s) if timed is not None else route.at(s, args.speed)
                position = pose.position + (rng.normal(0.0, args.pose_noise, 3) if args.pose_noise else 0.0)
                pub.publish_pose(stamp, position, pose.quat, pose.velocity)
                sent += 1
            if t >= next_print:
                if not args.quiet:
                    unit, end = ("s", timed.duration) if timed is not None else ("m", route.length)
                    log.info("t=%.1fs s=%.2f%s/%.2f%s poses=%d%s", t, s, unit, end, unit, sent,
                             " (gap)" if in_gap else "")
                next_print += 1.0
            k += 1
            stop.wait(max(0.0, t0 + k * period - time.monotonic()))  # absolute deadlines: no drift
    finally:
        if pub is not None:
            pub.close()
        session.close()
    return 0


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``tools/sim_pose``: exit 0 on normal end or SIGTERM/SIGINT, 2 on bad input."""
    args = build_parser().parse_args(argv)
    logging.basicConfig(level=logging.WARNING if args.quiet else logging.INFO, format="%(message)s",
                        stream=sys.stdout)
    logging.getLogger("pivotd").setLevel(logging.WARNING)
    stop = threading.Event()

    def on_signal(signum: int, frame: object) -> None:
        stop.set()

    signal.signal(signal.SIGTERM, on_signal)
    signal.signal(signal.SIGINT, on_signal)
    try:
        return run(args, stop)
    except PivotdError as exc:
        print(f"sim_pose: error: {exc}", file=sys.stderr)
        return 2
