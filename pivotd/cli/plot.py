"""``pivotd plot RUN.mcap``: figures of a recorded run (``pivotd --record``) as PNG.

The recording names the run's config (map, FoV, mount, limits); ``--config`` replaces it when the file has
moved. ``--figure`` picks one figure (docs/CLI.md); the default draws them all on one page.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from pivotd.viz.figures import FIGURES


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("recording", metavar="RUN.mcap", help="an MCAP file written by `pivotd --record`")
    p.add_argument("-o", "--out", default=None, metavar="OUT.png", help="output PNG (default: RUN.png beside it)")
    p.add_argument("--figure", choices=(*FIGURES, "all"), default="all", help="which figure (default: all)")
    p.add_argument("--config", default=None, metavar="FILE", help="the run's config, if not the recorded one")
    p.add_argument("--dpi", type=int, default=110, help="resolution of the PNG (default 110)")


def run(args: argparse.Namespace) -> int:
    from pivotd.errors import InputError
    from pivotd.viz.figures import build_figure, require_pyplot, save_figure
    from pivotd.viz.recording import read_recording

    if not 20 <= args.dpi <= 600:
        raise InputError(f"--dpi {args.dpi}: must be within 20..600")
    require_pyplot()  # fail before reading a long recording
    recording = read_recording(args.recording, args.config)
    out = Path(args.out) if args.out else Path(args.recording).with_suffix(".png")
    save_figure(build_figure(recording, args.figure), out, dpi=args.dpi)
    print(out)
    return 0
