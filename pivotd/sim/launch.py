"""Starting pivotd and its simulators as subprocesses: derived configs, free loopback ports, process groups.

Shared by the demo, the control benchmark and the end-to-end tests.
"""

from __future__ import annotations

import os
import socket
import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def derive_config(base: Path, out: Path, changes: dict[str, object]) -> Path:
    """Write a copy of config ``base`` to ``out`` with dotted-key ``changes`` (``"gimbal.port": "mock://"``).

    Relative paths of the base config (``map.file``, ``map.filters.occupancy_file``, ``zenoh.config_file``)
    are made absolute so the copy can live anywhere.
    """
    import yaml

    doc = yaml.safe_load(Path(base).read_text())
    for dotted in ("map.file", "map.filters.occupancy_file", "zenoh.config_file"):
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.get(k) or {}
        value = node.get(keys[-1]) if isinstance(node, dict) else None
        if value:
            node[keys[-1]] = str((Path(base).parent / value).resolve())
    for dotted, value in changes.items():
        node = doc
        keys = dotted.split(".")
        for k in keys[:-1]:
            node = node.setdefault(k, {})
        node[keys[-1]] = value
    out.write_text(yaml.safe_dump(doc, sort_keys=False))
    return out


def free_port() -> int:
    """A TCP port on 127.0.0.1 that was free a moment ago."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def spawn(args: list[str], log_path: Path) -> subprocess.Popen:
    """Start ``args`` in its own session (process group) from the repository root, output to ``log_path``."""
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO), env.get("PYTHONPATH", "")]).rstrip(os.pathsep)
    env.pop("NOTIFY_SOCKET", None)
    fh = open(log_path, "w")  # noqa: SIM115 - owned by the child for its lifetime
    return subprocess.Popen(args, stdout=fh, stderr=subprocess.STDOUT, stdin=subprocess.DEVNULL, env=env,
                            cwd=str(REPO), start_new_session=True)
