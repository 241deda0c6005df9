"""``pivotd bench NAME``: benchmarks that report medians and ratios measured in one run.

Each benchmark is a module ``pivotd.bench.<name>`` exposing ``configure(parser)`` and
``run(args) -> int``. BLAS is pinned to one thread before numpy is imported.
"""

from __future__ import annotations

import argparse
import importlib
import os

BENCHES: dict[str, str] = {
    "montecarlo": "the paper's Monte Carlo evaluation: PIVOT vs brute force",
    "maps": "map loading, retained-set queries and occlusion tests at scale",
    "proto": "serial protocol codec throughput, link round trip, lossy-link soak",
    "horizon": "receding-horizon replanning latency",
    "dense": "replans and planner memory on a densely packed map vs the same count spread thinly",
    "control": "control-loop jitter and pose-to-setpoint latency",
    "motion": "per-cycle cost of gimbal kinematics and Ruckig setpoint generation",
    "bus": "Zenoh/ROS 2 bus codec costs and loopback delivery latency",
    "achievable": "a recorded run's view against the best view the configured gimbal can execute on its route",
    "localization": "simulated visual localization success per camera policy (needs pivotd[bench])",
    "fuzz": "pivotd plan/check over mutated maps, paths and configs: tracebacks, time, reader memory",
    "soak": "full stack under random device faults and hostile bus input: limits, tracebacks, RSS, recovery",
    "gap": "the running daemon against the achievable view on seeded scene families, end to end",
}


def pin_single_thread() -> None:
    """Pin BLAS/OpenMP thread pools to one thread (effective before numpy loads them)."""
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS", "NUMEXPR_NUM_THREADS"):
        os.environ.setdefault(var, "1")
    try:
        from threadpoolctl import threadpool_limits
    except ImportError:
        return
    threadpool_limits(1)


def configure(parser: argparse.ArgumentParser) -> None:
    subs = parser.add_subparsers(dest="bench", required=True)
    for name, help_text in BENCHES.items():
        try:
            module = importlib.import_module(f"pivotd.bench.{name}")
        except ModuleNotFoundError as exc:
            if exc.name != f"pivotd.bench.{name}":
                raise
            continue
        module.configure(subs.add_parser(name, help=help_text, description=help_text))


def run(args: argparse.Namespace) -> int:
    pin_single_thread()
    module = importlib.import_module(f"pivotd.bench.{args.bench}")
    return int(module.run(args) or 0)
