#!/usr/bin/env python3
"""Main job on the embedded default: offline PIVOT plan on the FIF ycorridor data."""

import sys
from pathlib import Path

from pivotd.cli import main

DATA = Path(__file__).resolve().parent.parent / "tests" / "data" / "fif"

if __name__ == "__main__":
    sys.exit(
        main(["plan", "--map", str(DATA / "ycorridor_6x20_points_w.txt"), "--path", str(DATA / "ycorridor_6x20.csv"),
              "--fov-deg", "30", "--lambda", "0.6", "--json"])
    )
