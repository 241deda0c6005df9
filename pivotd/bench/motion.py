"""``pivotd bench motion``: cost of one control cycle's gimbal work (kinematics, retarget, Ruckig step).

Measures, single-threaded, the per-call time of :func:`world_direction_to_joints`,
:meth:`MotionGenerator.step` towards rest targets, :meth:`MotionGenerator.set_target` + ``step`` with a new
random moving target every cycle, a full cycle as the control loop runs it (kinematics + set_target with
velocity/acceleration feed-forward on a smooth moving plan + step), and a held rest target with ±0.02°
noise every cycle, with the 0.05° deadband and without (a re-plan every cycle). Reports medians and 99th
percentiles, the full cycle as a fraction of the control period at 100 and 200 Hz, and the tracking
error against the plan after a 3 s warm-up.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
import time
from collections.abc import Callable

import numpy as np

from pivotd.progress import with_progress


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true", help="fewer cycles (a few seconds)")
    parser.add_argument("--json", metavar="FILE", help="also write the results as JSON")


def _time_calls(fn: Callable[[int], object], count: int) -> np.ndarray:
    """Per-call durations [s] of fn(i) for i in range(count)."""
    out = np.empty(count)
    clock = time.perf_counter
    for i in range(count):
        t0 = clock()
        fn(i)
        out[i] = clock() - t0
    return out


def _stats(samples: np.ndarray) -> dict[str, float]:
    return {
        "median_us": float(np.median(samples) * 1e6),
        "p99_us": float(np.percentile(samples, 99) * 1e6),
        "calls": int(samples.size),
    }


def measure(cycles: int, seed: int = 0) -> dict[str, object]:
    """Run the measurements with ``cycles`` calls each; returns a JSON-ready dict."""
    from pivotd.gimbal.kinematics import JointLimits, Mount, world_direction_to_joints
    from pivotd.gimbal.motion import AxisLimits, MotionGenerator

    rng = np.random.default_rng(seed)
    dt = 0.01
    limits = JointLimits(math.radians(-170), math.radians(170), math.radians(-45), math.radians(60))
    pan = AxisLimits(math.radians(120), math.radians(360), math.radians(2400))
    tilt = AxisLimits(math.radians(90), math.radians(270), math.radians(1800))
    mount = Mount.from_xyz_rpy([0.25, 0.0, 0.2], [0.0, 0.0, 0.0])

    quats = rng.normal(size=(cycles, 4)) * [0.05, 0.05, 1.0, 1.0]
    quats /= np.linalg.norm(quats, axis=1, keepdims=True)
    dirs = rng.normal(size=(cycles, 3))
    dirs[:, 2] = -0.3 * np.abs(dirs[:, 2])
    dirs /= np.linalg.norm(dirs, axis=1, keepdims=True)
    previous = [0.0]

    def kinematics(i: int) -> None:
        previous[0] = world_direction_to_joints(dirs[i], quats[i], mount, limits, previous[0])[0]

    gen = MotionGenerator(dt, pan, tilt, limits)
    gen.set_target([1.0, 0.3])

    def step_only(i: int) -> None:
        if i % 300 == 0:
            gen.set_target(rng.uniform([-2.5, -0.6], [2.5, 0.9]))
        gen.step()

    gen2 = MotionGenerator(dt, pan, tilt, limits)
    targets = rng.uniform([-2.5, -0.6], [2.5, 0.9], size=(cycles, 2))
    velocities = rng.uniform(-0.5, 0.5, size=(cycles, 2))

    def replan_step(i: int) -> None:
        gen2.set_target(targets[i], velocities[i])
        gen2.step()

    # The control loop: a smooth plan (pan sweep, tilt wave) under a slowly yawing body; the joint-space
    # feed-forward velocity is the derivative of the joint targets, as the planner provides it.
    def plan_at(t: float) -> tuple[np.ndarray, np.ndarray]:
        heading = 2.0 * math.sin(0.2 * t)
        d = np.array([math.cos(heading), math.sin(heading), -0.2 + 0.1 * math.sin(t)])
        yaw = 0.3 * math.sin(0.1 * t)
        return d, np.array([0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2)])

    joint_path = np.array(
        [world_direction_to_joints(*plan_at(i * dt), mount, limits)[:2] for i in range(cycles + 2)]
    )
    joint_velocity = np.gradient(joint_path, dt, axis=0)
    joint_acceleration = np.gradient(joint_velocity, dt, axis=0)
    def make_cycle(deadband: float) -> tuple[Callable[[int], None], MotionGenerator]:
        gen3 = MotionGenerator(dt, pan, tilt, limits, deadband=deadband)
        prev3 = [0.0]

        def cycle(i: int) -> None:
            d, q = plan_at(i * dt)
            p, tl, _ = world_direction_to_joints(d, q, mount, limits, prev3[0])
            prev3[0] = p
            gen3.set_target([p, tl], joint_velocity[i], joint_acceleration[i])
            out = gen3.step()
            errors[deadband][i] = np.abs(out.position - joint_path[i + 1]).max()

        return cycle, gen3

    errors = {math.radians(0.05): np.zeros(cycles + 1)}
    cycle, _ = make_cycle(math.radians(0.05))

    def make_noisy_hold(deadband: float) -> tuple[Callable[[int], None], MotionGenerator]:
        gen5 = MotionGenerator(dt, pan, tilt, limits, deadband=deadband)
        noise = rng.uniform(-1.0, 1.0, size=(cycles + 1, 2)) * math.radians(0.02)
        centre = np.array([0.4, 0.2])

        def hold_cycle(i: int) -> None:
            gen5.set_target(centre + noise[i])
            gen5.step()

        return hold_cycle, gen5

    noisy_hold, gen5 = make_noisy_hold(math.radians(0.05))
    noisy_hold_no_deadband, gen6 = make_noisy_hold(0.0)

    results = {}
    for name, fn in with_progress((
        ("kinematics", kinematics),
        ("step", step_only),
        ("set_target_and_step", replan_step),
        ("control_cycle", cycle),
        ("noisy_hold", noisy_hold),
        ("noisy_hold_no_deadband", noisy_hold_no_deadband),
    ), "motion timings"):
        fn(0)  # warm-up
        results[name] = _stats(_time_calls(fn, cycles))
    warm = min(300, cycles // 2)
    errs = errors[math.radians(0.05)][warm:cycles]
    cyc = results["control_cycle"]
    cyc["tracking_error_max_deg"] = float(np.degrees(errs.max()))
    cyc["tracking_error_median_deg"] = float(np.degrees(np.median(errs)))
    cyc["fraction_of_period_100hz"] = cyc["median_us"] * 1e-6 / 0.01
    cyc["fraction_of_period_200hz"] = cyc["median_us"] * 1e-6 / 0.005
    for name, g in (("noisy_hold", gen5), ("noisy_hold_no_deadband", gen6)):
        results[name]["replans_per_cycle"] = g.replans / (cycles + 1)
    results["deadband_speedup"] = results["noisy_hold_no_deadband"]["median_us"] / results["noisy_hold"]["median_us"]
    return {"benchmark": "motion", "cycles": cycles, "results": results}


def run(args: argparse.Namespace) -> int:
    cycles = 2000 if args.quick else 20000
    report = measure(cycles)
    for name, stats in report["results"].items():
        if not isinstance(stats, dict):
            sys.stdout.write(f"{name:26s} {stats:.2f}x (noisy hold: median cycle time without / with the deadband)\n")
            continue
        extra = ""
        if name == "control_cycle":
            extra = (
                f"  ({stats['fraction_of_period_100hz'] * 100:.2f}% of a 100 Hz period, "
                f"{stats['fraction_of_period_200hz'] * 100:.2f}% at 200 Hz; tracking error median "
                f"{stats['tracking_error_median_deg']:.3f}°, max {stats['tracking_error_max_deg']:.3f}°)"
            )
        elif "replans_per_cycle" in stats:
            extra = f"  ({stats['replans_per_cycle']:.3f} re-plans per cycle)"
        sys.stdout.write(f"{name:26s} median {stats['median_us']:8.1f} µs  p99 {stats['p99_us']:8.1f} µs{extra}\n")
    if args.json:
        with open(args.json, "w", encoding="utf-8") as fh:
            json.dump(report, fh, indent=2)
    return 0


if __name__ == "__main__":
    from pivotd.bench import pin_single_thread

    pin_single_thread()
    parser = argparse.ArgumentParser(prog="python -m pivotd.bench.motion", description=__doc__.splitlines()[0])
    configure(parser)
    sys.exit(run(parser.parse_args()))
