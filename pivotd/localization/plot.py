"""Figure of the localization benchmark: each scene's route from above with the frames coloured by
success per policy (first seed), the success curves (share of frames vs translation threshold at the
matching rotation threshold, first seed), and why frames fail: the landmarks in the image over time per
policy with its failing frames marked (first seed). Needs matplotlib (the ``plot`` extra)."""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np

from pivotd.errors import InputError
from pivotd.localization.metrics import PRIMARY, THRESHOLDS, threshold_label


def require_matplotlib():
    """matplotlib.pyplot with the Agg backend, or InputError naming the extra that provides it."""
    try:
        import matplotlib
    except ImportError:
        raise InputError("matplotlib is not installed: pip install 'pivotd[plot]'") from None
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def plot_results(results: Sequence, summaries: dict, out: Path) -> None:
    """Write the figure for ``results`` (SceneResult per scene) to ``out`` (PNG)."""
    plt = require_matplotlib()
    policies = list(results[0].frame_ok) if results else []
    cols = len(policies) + 2
    fig, axes = plt.subplots(len(results), cols, figsize=(3.2 * cols, 3.0 * len(results)), squeeze=False)
    key = f"success_{threshold_label(PRIMARY)}"
    for row, res in enumerate(results):
        for col, pol in enumerate(policies):
            ax = axes[row, col]
            if res.walls is not None and len(res.walls):
                ax.scatter(res.walls[:, 0], res.walls[:, 1], s=0.3, c="0.7", linewidths=0)
            ax.plot(res.route[:, 0], res.route[:, 1], "-", c="0.4", lw=0.6)
            ok = res.frame_ok[pol]
            c = res.centres
            ax.scatter(c[ok, 0], c[ok, 1], s=5, c="tab:green", linewidths=0)
            ax.scatter(c[~ok, 0], c[~ok, 1], s=9, c="tab:red", linewidths=0)
            share = 100 * summaries[res.scene][pol][key]["mean"]
            ax.set_title(f"{res.scene}: {pol} {share:.0f} %", fontsize=8)
            ax.set_aspect("equal")
            ax.tick_params(labelsize=6)
        ax = axes[row, cols - 2]
        grid = np.logspace(-3, 0, 60)
        ratio = THRESHOLDS[PRIMARY][1] / THRESHOLDS[PRIMARY][0]  # degrees per metre along the curve
        for pol in policies:
            et, er = res.errors[pol]
            ax.plot(grid, [np.mean((et <= g) & (er <= ratio * g)) for g in grid], label=pol)
        ax.set_xscale("log")
        ax.set_xlabel(f"translation threshold [m] (rotation {ratio:g}°/m)", fontsize=7)
        ax.set_ylabel("frames localized", fontsize=7)
        ax.set_ylim(0, 1.02)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6)
        ax = axes[row, cols - 1]
        for pol in policies:
            seen = np.maximum(res.in_view[pol], 0.8)  # 0 drawn at the bottom of the log axis
            line = ax.plot(res.times, seen, lw=0.7, label=pol)[0]
            bad = ~res.frame_ok[pol]
            ax.scatter(res.times[bad], seen[bad], s=6, color=line.get_color(), marker="x", linewidths=0.6)
        ax.set_yscale("log")
        ax.set_xlabel("time [s] (×: frame outside 0.25 m / 2°)", fontsize=7)
        ax.set_ylabel("landmarks in the image", fontsize=7)
        ax.tick_params(labelsize=6)
        ax.legend(fontsize=6)
    fig.suptitle("frames within 0.25 m / 2° (green) and outside (red), first seed", fontsize=9)
    fig.tight_layout()
    fig.savefig(out, dpi=110)
    plt.close(fig)
