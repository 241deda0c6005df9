#!/usr/bin/env python3
"""Main job on the embedded default: pivotd + simulated robot + mock gimbal (see pivotd/sim/demo.py)."""

import sys

from pivotd.sim.demo import main

if __name__ == "__main__":
    sys.exit(main())
