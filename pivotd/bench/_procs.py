"""Process trees and their memory, read from /proc (Linux), for the benches that run the daemon."""

from __future__ import annotations

import contextlib
from pathlib import Path


def process_tree(pid: int) -> list[int]:
    """``pid`` and all its descendants: children of any of its threads (a planner process restarted by a
    thread of the daemon included), grandchildren and so on."""
    parents: dict[int, int] = {}
    for entry in Path("/proc").iterdir():
        if entry.name.isdigit():
            with contextlib.suppress(OSError, ValueError, IndexError):
                stat = (entry / "stat").read_text()
                parents[int(entry.name)] = int(stat[stat.rindex(")") + 2:].split()[1])
    tree, frontier = [pid], [pid]
    while frontier:
        parent = frontier.pop()
        for child, ppid in parents.items():
            if ppid == parent and child not in tree:
                tree.append(child)
                frontier.append(child)
    return tree


def rss_mb(pid: int) -> tuple[float, float]:
    """Resident and peak resident memory [MB] of process ``pid`` (0, 0 when it is gone)."""
    fields = {}
    with contextlib.suppress(OSError):
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            key, _, value = line.partition(":")
            fields[key] = value.strip()
    if "VmRSS" not in fields or "VmHWM" not in fields:
        return 0.0, 0.0
    return int(fields["VmRSS"].split()[0]) / 1024.0, int(fields["VmHWM"].split()[0]) / 1024.0
