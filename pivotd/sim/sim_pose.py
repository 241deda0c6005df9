"""``tools/sim_pose``: publish a robot moving along a route as ROS 2 (rmw_zenoh) Odometry/PoseStamped + Path.

The publisher side goes through :class:`pivotd.bus.ros.RosNode` and :mod:`pivotd.bus.messages`, so its
keys, attachments and liveliness tokens are the same rmw_zenoh-conformant ones pivotd uses. Header stamps
are the scheduled sample times (start wall time + k / rate), so a consumer can check timing exactly.

With ``--tf`` it also publishes the robot as a localization and an odometry node would (:class:`TfPublisher`):
``odom -> base_link`` on ``/tf`` at the pose rate and ``map -> odom`` either once on ``/tf_static``, or with
``--tf-map-odom-hz`` on ``/tf`` at that (slower) rate, moved by a small correction at each publication; their
composition is exactly the pose published on the pose topics.
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
from pivotd.geometry import matrix_to_quat, quat_to_matrix, yaw_to_matrix
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
                 pose_type: str = m.POSE_STAMPED, tf: dict | None = None) -> None:
        self.node = RosNode(session, node_name, domain_id, humble=humble)
        self.tf = TfPublisher(self.node, frame_id, base_frame=child_frame_id, **tf) if tf is not None else None
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

    def publish_tf(self, t: float, stamp: float, position: np.ndarray, quat: np.ndarray) -> None:
        """The body pose as TF (``--tf``), at ``t`` [s since the start]."""
        if self.tf is not None:
            self.tf.publish(t, stamp, position, quat)

    def publish_path(self, stamp: float, positions: np.ndarray, quats: np.ndarray | None) -> None:
        if self.path is not None:
            self.path.put(m.encode_path(stamp, self.frame_id, positions, quats))

    def all_matched(self) -> bool:
        """True when every enabled publisher has at least one matching subscriber."""
        return all(p.matched() for p in self._publishers())

    def _publishers(self) -> list:
        return [p for p in (self.odom, self.pose, self.path) if p is not None] + (
            self.tf.publishers() if self.tf is not None else [])

    def close(self) -> None:
        for pub in self._publishers():
            if pub is not None:
                pub.close()
        self.node.close()


#: ``map -> odom`` of ``--tf`` at the start: (x, y, z) [m] and yaw [rad] (an odometry frame started elsewhere).
TF_MAP_ODOM_XYZ, TF_MAP_ODOM_YAW = np.array([2.0, -1.5, 0.0]), np.deg2rad(20.0)
#: Amplitudes of the correction a dynamic ``map -> odom`` goes through: [m] per axis, [rad] of yaw.
TF_CORRECTION_M, TF_CORRECTION_YAW = 0.05, np.deg2rad(1.0)


class TfPublisher:
    """``map -> odom`` (static on ``/tf_static``, or on ``/tf`` every ``1 / map_odom_hz`` s with a correction that
    changes at each publication) and ``odom -> base_link`` on ``/tf`` such that their composition is the body pose;
    both in one message when they are due together, so that every prefix of the stream composes to a true pose.
    ``future`` [s] stamps ``map -> odom`` ahead, as slam_toolbox's ``transform_timeout`` and AMCL's
    ``transform_tolerance`` do."""

    def __init__(self, node: RosNode, map_frame: str = "map", odom_frame: str = "odom",
                 base_frame: str = "base_link", map_odom_hz: float = 0.0, future: float = 0.0) -> None:
        self.map_frame, self.odom_frame, self.base_frame = map_frame, odom_frame, base_frame
        self.map_odom_hz, self.future = float(map_odom_hz), float(future)
        self.tf = node.publisher("/tf", m.TF_MESSAGE, QoS(depth=100))
        # a static broadcaster's QoS: transient local, depth 1 (tf2_ros StaticBroadcasterQoS)
        self.tf_static = node.publisher("/tf_static", m.TF_MESSAGE, QoS(durability=DURABILITY_TRANSIENT_LOCAL,
                                                                      depth=1)) if not map_odom_hz else None
        self._next, self._k = 0.0, 0
        self._R_mo, self._t_mo = yaw_to_matrix(TF_MAP_ODOM_YAW), TF_MAP_ODOM_XYZ.copy()

    def _map_odom(self, stamp: float) -> tuple[float, str, str, np.ndarray, np.ndarray]:
        return (stamp, self.map_frame, self.odom_frame, self._t_mo, matrix_to_quat(self._R_mo))

    def start(self, stamp: float) -> None:
        """Publish the static ``map -> odom`` (nothing for a dynamic one)."""
        if self.tf_static is not None:
            self.tf_static.put(m.encode_transforms([self._map_odom(stamp)]))

    def publish(self, t: float, stamp: float, position: np.ndarray, quat: np.ndarray) -> None:
        """The transforms due at ``t`` [s since the start] for the body pose (position (3,), quat (4,)) in the map."""
        out = []
        if self.tf_static is None and t >= self._next:
            k = self._k
            self._t_mo = TF_MAP_ODOM_XYZ + TF_CORRECTION_M * np.array([np.sin(0.7 * k), np.cos(0.5 * k) - 1.0, 0.0])
            self._R_mo = yaw_to_matrix(TF_MAP_ODOM_YAW + TF_CORRECTION_YAW * np.sin(0.3 * k))
            out.append(self._map_odom(stamp + self.future))
            self._k += 1
            self._next += 1.0 / self.map_odom_hz
        R_ob = self._R_mo.T @ quat_to_matrix(quat)
        t_ob = self._R_mo.T @ (np.asarray(position, float) - self._t_mo)
        out.append((stamp, self.odom_frame, self.base_frame, t_ob, matrix_to_quat(R_ob)))
        self.tf.put(m.encode_transforms(out))

    def publishers(self) -> list:
        return [p for p in (self.tf, self.tf_static) if p is not None]


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
    p.add_argument("--tf", action="store_true",
                   help="also publish odom -> base_link on /tf at the pose rate and map -> odom (static on /tf_static, "
                        "or see --tf-map-odom-hz); the pose topics stay on unless disabled")
    p.add_argument("--tf-map-odom-hz", type=float, default=0.0, metavar="HZ",
                   help="with --tf: publish map -> odom on /tf at HZ (a localizer's correction moving it a little each "
                        "time) instead of once on /tf_static (default 0: static)")
    p.add_argument("--tf-future", type=float, default=0.0, metavar="S",
                   help="with --tf-map-odom-hz: stamp map -> odom S s ahead (slam_toolbox's transform_timeout, AMCL's "
                        "transform_tolerance; default 0)")
    p.add_argument("--odom-frame", default="odom", help="with --tf: the odometry frame (default odom)")
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
    for name in ("tf_map_odom_hz", "tf_future"):
        v = getattr(args, name)
        if not np.isfinite(v) or v < 0:
            raise InputError(f"--{name.replace('_', '-')} must be >= 0, got {v}")
    if (args.tf_map_odom_hz or args.tf_future) and not args.tf:
        raise InputError("--tf-map-odom-hz and --tf-future need --tf")
    if args.tf_future and not args.tf_map_odom_hz:
        raise InputError("--tf-future needs --tf-map-odom-hz (a static map -> odom has no time to be ahead of)")
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
                            pose_type=args.pose_type,
                            tf={"odom_frame": args.odom_frame, "map_odom_hz": args.tf_map_odom_hz,
                                "future": args.tf_future} if args.tf else None)
        path_quats = route.quats if route.quats is not None else np.array([route.at(s).quat for s in route.arc])
        if args.wait_subscribers > 0:
            deadline = time.monotonic() + args.wait_subscribers
            while not pub.all_matched() and time.monotonic() < deadline and not stop.is_set():
                stop.wait(0.02)
            if not args.quiet:
                log.info("subscribers %s", "matched" if pub.all_matched() else "not all matched; starting anyway")
        period = 1.0 / args.rate
        t0_wall, t0 = time.time(), time.monotonic()
        if pub.tf is not None:
            pub.tf.start(t0_wall)
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
                pub.publish_tf(t, stamp, position, pose.quat)
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


if __name__ == "__main__":
    sys.exit(main())
