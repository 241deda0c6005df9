"""Shared fixtures: repository paths, FIF data."""

from pathlib import Path

import pytest

REPO = Path(__file__).resolve().parent.parent
FIF = REPO / "tests" / "data" / "fif"


@pytest.fixture
def fif_dir() -> Path:
    return FIF
