"""Property-based fuzzing of ``pivotd plan`` / ``check`` over mutated maps, paths and configs, in-process.

Every case runs the CLI's ``main`` and then the reader alone under tracemalloc (pivotd.bench.fuzz). A case
fails when any exception other than our one-line PivotdError escapes (a traceback), when the exit code is
not 0 or 2, or when the reader's peak traced memory exceeds twice the file's honest size (above a fixed
allowance for constant overheads). RuntimeWarnings raised in pivotd are errors under pytest, so they count
as tracebacks too. ``PIVOTD_FUZZ_SCALE`` multiplies the example counts (default 1: 1100 cases).
"""

from __future__ import annotations

import itertools
import os
from pathlib import Path

import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from pivotd.bench.fuzz import EXTREMES, MUTATIONS, Outcome, Seed, mutate, run_case, write_corpus

SCALE = float(os.environ.get("PIVOTD_FUZZ_SCALE", "1"))
_counter = itertools.count()


@pytest.fixture(scope="module")
def corpus(tmp_path_factory) -> tuple[dict[str, Seed], Path]:
    root = tmp_path_factory.mktemp("fuzz")
    (root / "corpus").mkdir()
    seeds = write_corpus(root / "corpus")
    return {s.name: s for s in seeds}, root


def _run(corpus, name: str, data: bytes) -> Outcome:
    seeds, root = corpus
    work = root / f"case{next(_counter)}"
    work.mkdir()
    return run_case(seeds[name], seeds, data, work)


def _check(out: Outcome, data: bytes) -> None:
    assert out.error is None, f"{out.error} escaped on mutated {out.seed}: {data[:200]!r}"
    assert out.code in (0, 2), out
    assert out.memory_ratio <= 2.0, f"reader peak {out.peak} B for an honest size of {out.honest} B ({out.seed})"


_mutations = st.lists(st.tuples(st.sampled_from(MUTATIONS), st.integers(0, 1 << 30), st.integers(0, 1 << 30)),
                      min_size=1, max_size=3)
MAP_SEEDS = ["npy4", "npy3", "txt", "csv", "csv_header", "pcd_ascii", "pcd_binary", "pcd_binary_compressed",
             "ply_ascii", "ply_le", "ply_be", "colmap_bin_points", "colmap_bin_images",
             "colmap_txt_points", "colmap_txt_images"]


def _fuzz(examples: int) -> settings:
    return settings(max_examples=int(examples * SCALE), deadline=None, derandomize=True, database=None,
                    suppress_health_check=[HealthCheck.function_scoped_fixture, HealthCheck.too_slow])


def _apply(corpus, name: str, ops) -> bytes:
    data = corpus[0][name].files[0].read_bytes()
    for op, pos, value in ops:
        data = mutate(data, op, pos, value)
    return data


@pytest.mark.slow
@_fuzz(750)
@given(name=st.sampled_from(MAP_SEEDS), ops=_mutations)
def test_plan_on_mutated_maps_never_tracebacks(corpus, name, ops):
    data = _apply(corpus, name, ops)
    _check(_run(corpus, name, data), data)


@pytest.mark.slow
@_fuzz(150)
@given(name=st.sampled_from(["path3", "path8", "path_header"]), ops=_mutations)
def test_plan_on_mutated_paths_never_tracebacks(corpus, name, ops):
    data = _apply(corpus, name, ops)
    _check(_run(corpus, name, data), data)


@pytest.mark.slow
@_fuzz(200)
@given(ops=_mutations)
def test_check_on_mutated_configs_never_tracebacks(corpus, ops):
    data = _apply(corpus, "config", ops)
    _check(_run(corpus, "config", data), data)


BINARY_SEEDS = ["npy4", "npy3", "pcd_binary", "pcd_binary_compressed", "ply_le", "ply_be", "colmap_bin_points",
                "colmap_bin_images"]


@pytest.mark.slow
@pytest.mark.parametrize("name", [*MAP_SEEDS, "path3", "path8", "path_header", "config"])
def test_every_header_count_and_extreme_token(corpus, name):
    """Deterministic sweep: numbers of the header / aligned words replaced by each huge count, numeric tokens
    by extreme values, and (binary files) every bit of the first 12 bytes flipped (magic, version, lengths)."""
    data = corpus[0][name].files[0].read_bytes()
    cases = [("count", pos * 977, value) for pos in range(8) for value in range(6)]
    cases += [("token", pos, pos % len(EXTREMES)) for pos in range(12)]
    if name in BINARY_SEEDS:
        cases += [("flip", pos, bit) for pos in range(12) for bit in range(8)]
    for op, pos, value in cases:
        mutated = mutate(data, op, pos, value)
        _check(_run(corpus, name, mutated), mutated)
