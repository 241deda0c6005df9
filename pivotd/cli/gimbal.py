"""``pivotd gimbal --config FILE ping | goto PAN TILT | scan``: check a gimbal's signs and range before tracking.

``ping`` connects as the daemon does and prints the measured pose; ``goto`` moves to one pose [deg] inside the
configured joint limits (a target outside them is refused before anything moves) along a Ruckig trajectory
with the configured motion limits, at the control rate; ``scan`` visits each axis' limits (less a margin) and
its zero in turn. Every command disables the gimbal before it exits, as the daemon does (docs/CLI.md).
"""

from __future__ import annotations

import argparse
import math
import sys
import time
from collections.abc import Iterator

from pivotd.config import Config, load_config
from pivotd.errors import InputError, PivotdError
from pivotd.gimbal.interface import GimbalInterface, GimbalMode, GimbalState, LinkState

DEFAULT_TIMEOUT_S = 10.0  # [s] to connect, and to settle at a target after the trajectory ended
DEFAULT_TOLERANCE_DEG = 0.5  # [deg] how close the measured pose must come to a target
DEFAULT_MARGIN_DEG = 5.0  # [deg] scan: how far inside the limits it turns


class GimbalCommandError(PivotdError):
    """The gimbal did not connect, refused to enable, faulted or did not reach a target."""


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", required=True, metavar="FILE", help="pivotd YAML config (its gimbal section)")
    parser.add_argument("--port", help="overrides gimbal.port")
    parser.add_argument("--timeout", type=float, default=DEFAULT_TIMEOUT_S, metavar="S",
                        help=f"seconds to connect, and to settle at each target (default {DEFAULT_TIMEOUT_S:g})")
    parser.add_argument("--log-level", help="override logging.level (DEBUG, INFO, WARNING, ERROR)")
    subs = parser.add_subparsers(dest="action", metavar="ACTION", required=True)
    subs.add_parser("ping", help="connect and print the measured pose")
    goto = subs.add_parser("goto", help="move to PAN TILT [deg] inside the joint limits")
    goto.add_argument("pan", type=float, metavar="PAN", help="pan [deg], positive left")
    goto.add_argument("tilt", type=float, metavar="TILT", help="tilt [deg], positive down")
    goto.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_DEG, metavar="DEG",
                      help=f"reached within this many degrees per axis (default {DEFAULT_TOLERANCE_DEG:g})")
    scan = subs.add_parser("scan", help="visit each axis' limits (less --margin) and its zero")
    scan.add_argument("--margin", type=float, default=DEFAULT_MARGIN_DEG, metavar="DEG",
                      help=f"stay this many degrees inside the limits (default {DEFAULT_MARGIN_DEG:g})")
    scan.add_argument("--tolerance", type=float, default=DEFAULT_TOLERANCE_DEG, metavar="DEG",
                      help=f"reached within this many degrees per axis (default {DEFAULT_TOLERANCE_DEG:g})")


def run(args: argparse.Namespace) -> int:
    import logging

    from pivotd.daemon.wiring import build_gimbal

    if not (math.isfinite(args.timeout) and args.timeout > 0):
        raise InputError(f"--timeout: must be > 0, got {args.timeout:g}")
    cfg = load_config(args.config).with_overrides(port=args.port)
    if not args.log_level:
        logging.getLogger().setLevel(cfg.logging.level.upper())
    targets = list(_targets(cfg, args))  # refused before anything connects
    link = build_gimbal(cfg)
    link.start()
    try:
        state = connect(link, cfg, args.timeout)
        _print(f"gimbal {cfg.gimbal.backend} at {cfg.gimbal.port}: up, {_pose(state)}, {_mode(state)}")
        for pan, tilt in targets:
            state = goto(link, cfg, pan, tilt, math.radians(args.tolerance), args.timeout)
            _print(f"reached {_pose(state)} (target pan {math.degrees(pan):.2f}°, tilt {math.degrees(tilt):.2f}°)")
    finally:
        link.stop()
    return 0


def _targets(cfg: Config, args: argparse.Namespace) -> Iterator[tuple[float, float]]:
    """The poses [rad] the action visits, each checked against the joint limits."""
    if args.action == "goto":
        yield check_target(cfg, math.radians(args.pan), math.radians(args.tilt))
    elif args.action == "scan":
        lim, m = cfg.gimbal.limits, math.radians(args.margin)
        if not (math.isfinite(args.margin) and args.margin >= 0):
            raise InputError(f"--margin: must be ≥ 0, got {args.margin:g}")
        spans = [("tilt", lim.tilt_max - lim.tilt_min)] + ([] if lim.continuous_pan else [
            ("pan", lim.pan_max - lim.pan_min)])
        for axis, span in spans:
            if 2 * m > span:
                raise InputError(f"--margin: {args.margin:g}° leaves nothing of the {axis} range "
                                 f"({math.degrees(span):g}°, gimbal.limits of {cfg.source})")
        if lim.continuous_pan:
            pan_poses = [-math.pi / 2, math.pi / 2, 0.0]
        else:
            pan_poses = [lim.pan_min + m, lim.pan_max - m, lim.clamp(0.0, 0.0)[0]]
        tilt_zero = lim.clamp(0.0, 0.0)[1]
        for pan in pan_poses:
            yield check_target(cfg, pan, tilt_zero, "--margin")
        for tilt in (lim.tilt_min + m, lim.tilt_max - m, tilt_zero):
            yield check_target(cfg, pan_poses[-1], tilt, "--margin")


def check_target(cfg: Config, pan: float, tilt: float, what: str = "goto") -> tuple[float, float]:
    """(pan, tilt) [rad] when inside the configured joint limits; an InputError naming the limit otherwise."""
    lim = cfg.gimbal.limits
    for axis, value, lo, hi in (("pan", pan, lim.pan_min, lim.pan_max), ("tilt", tilt, lim.tilt_min, lim.tilt_max)):
        if axis == "pan" and lim.continuous_pan:
            continue
        if not (math.isfinite(value) and lo - 1e-9 <= value <= hi + 1e-9):
            raise InputError(f"{what}: {axis} {math.degrees(value):g}° is outside gimbal.limits {axis} "
                             f"[{math.degrees(lo):g}, {math.degrees(hi):g}]° of {cfg.source}")
    return pan, tilt


def connect(link: GimbalInterface, cfg: Config, timeout: float) -> GimbalState:
    """Wait for the link and a first measured state; a GimbalCommandError with the link's reason otherwise."""
    where = f"gimbal {cfg.gimbal.backend} at {cfg.gimbal.port}"
    deadline = time.monotonic() + timeout
    up = link.wait_up(timeout)
    while up and link.state is None and time.monotonic() < deadline:
        time.sleep(0.01)
    if not up or link.state is None:
        raise GimbalCommandError(f"{where}: {link.link_state} after {timeout:g} s: {link.last_error or 'no state'}")
    return link.state


def goto(link: GimbalInterface, cfg: Config, pan: float, tilt: float, tolerance: float,
         timeout: float) -> GimbalState:
    """Enable, then move from the measured pose to (``pan``, ``tilt``) [rad] along the Ruckig trajectory of the
    configured motion limits, one setpoint per control period; the measured state once within ``tolerance``
    [rad] of the target on both axes (waiting up to ``timeout`` [s] after the trajectory ended)."""
    from pivotd.daemon.wiring import build_motion

    if not link.set_enabled(True, timeout=timeout):
        raise GimbalCommandError(f"the gimbal did not enable: {_mode(link.state)}; {link.last_error or ''}")
    state = _healthy(link)
    gen = build_motion(cfg)
    gen.reset((state.pan, state.tilt))
    gen.set_target((pan, tilt))
    next_tick = time.monotonic()
    settle_deadline: float | None = None
    while True:
        sample = gen.step()
        link.send_setpoint(float(sample.position[0]), float(sample.position[1]), float(sample.velocity[0]),
                           float(sample.velocity[1]))
        link.send_heartbeat()
        state = _healthy(link)
        if gen.settled:
            if abs(state.pan - pan) <= tolerance and abs(state.tilt - tilt) <= tolerance:
                return state
            settle_deadline = settle_deadline or time.monotonic() + timeout
            if time.monotonic() > settle_deadline:
                raise GimbalCommandError(f"target not reached within {timeout:g} s: {_pose(state)}, "
                                         f"target pan {math.degrees(pan):.2f}°, tilt {math.degrees(tilt):.2f}°")
        next_tick += gen.dt
        time.sleep(max(0.0, next_tick - time.monotonic()))


def _healthy(link: GimbalInterface) -> GimbalState:
    state = link.state
    if state is None or link.link_state != LinkState.UP:
        raise GimbalCommandError(f"gimbal link {link.link_state}: {link.last_error or 'no state'}")
    if state.mode == GimbalMode.FAULT:
        raise GimbalCommandError(f"gimbal fault (bits 0x{state.faults:x}) at {_pose(state)}")
    return state


def _pose(state: GimbalState) -> str:
    return f"pan {math.degrees(state.pan):.2f}°, tilt {math.degrees(state.tilt):.2f}°"


def _mode(state: GimbalState | None) -> str:
    if state is None:
        return "no state"
    try:
        return f"mode {GimbalMode(state.mode).name.lower()}"
    except ValueError:
        return f"mode {state.mode}"


def _print(line: str) -> None:
    sys.stdout.write(line + "\n")
    sys.stdout.flush()
