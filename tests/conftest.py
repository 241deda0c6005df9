"""Shared fixtures: repository paths, FIF data; the exhaustive-reference tests marked slow."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
FIF = REPO / "tests" / "data" / "fif"

# Exhaustive references that take seconds of CPU each; like the subprocess and real-time tests (marked in
# their modules) they run in `make test` and are left out of `make test-fast`.
EXHAUSTIVE_REFERENCE_TESTS = {
    "test_chain_is_the_exhaustive_optimum_on_a_small_grid",
    "test_reference_respects_the_step_and_bounds_the_free_plan",
}


def pytest_collection_modifyitems(items: list[pytest.Item]) -> None:
    for item in items:
        if getattr(item, "originalname", item.name) in EXHAUSTIVE_REFERENCE_TESTS:
            item.add_marker(pytest.mark.slow)


@pytest.fixture
def fif_dir() -> Path:
    return FIF


@pytest.fixture(autouse=True)
def _no_ros_domain_from_the_shell(monkeypatch: pytest.MonkeyPatch) -> None:
    """A config without ``topics.domain_id`` takes ``ROS_DOMAIN_ID`` from the environment: keep the shell's out."""
    monkeypatch.delenv("ROS_DOMAIN_ID", raising=False)
