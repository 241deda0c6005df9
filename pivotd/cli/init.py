"""``pivotd init``: write a config template shipped with pivotd (``config/*.yaml``) where the daemon will read it.

A template whose ``map.file`` names a file shipped next to it (the demo's hallway map) gets that file copied next
to the new config too, so the result passes ``pivotd check`` as it is. Nothing is overwritten without ``--force``.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path, PurePosixPath
from typing import TYPE_CHECKING

import yaml

from pivotd.data import DataDir, data_dir
from pivotd.errors import InputError

if TYPE_CHECKING:
    from importlib.abc import Traversable

DEFAULT_CONFIG = Path("/etc/pivotd/pivotd.yaml")  # what systemd/pivotd.service runs with
DEFAULT_TEMPLATE = "spot"


def templates() -> dict[str, Traversable]:
    """Template name (the file's stem: ``spot``, ``demo`` …) -> the shipped YAML file, sorted by name."""
    found = {Path(f.name).stem: f for f in data_dir(DataDir.CONFIG).iterdir() if f.name.endswith(".yaml")}
    return dict(sorted(found.items()))


def description(text: str) -> str:
    """A template's description: the first sentence of its leading comment."""
    words = []
    for line in text.splitlines():
        if not line.startswith("#"):
            break
        words.append(line.lstrip("#").strip())
    comment = " ".join(words)
    end = comment.find(". ")
    return comment if end < 0 else comment[:end + 1]


def shipped_map(template: Traversable) -> Traversable | None:
    """The file a template's relative ``map.file`` names when it is shipped next to the template, else None."""
    doc = yaml.safe_load(template.read_text(encoding="utf-8")) or {}
    name = (doc.get("map") or {}).get("file") if isinstance(doc, dict) else None
    if not isinstance(name, str) or PurePosixPath(name).is_absolute():
        return None
    shipped = data_dir(DataDir.CONFIG).joinpath(*PurePosixPath(name).parts)
    return shipped if shipped.is_file() else None


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG, metavar="FILE",
                   help=f"where to write the config (default {DEFAULT_CONFIG})")
    p.add_argument("--template", default=DEFAULT_TEMPLATE, metavar="NAME",
                   help=f"the template to start from (default {DEFAULT_TEMPLATE}; --list shows them)")
    p.add_argument("--force", action="store_true", help="overwrite existing files")
    p.add_argument("--list", action="store_true", help="list the templates and exit")
    p.set_defaults(log_level="WARNING")


def run(args: argparse.Namespace) -> int:
    shipped = templates()
    if args.list:
        width = max(map(len, shipped))
        for name, f in shipped.items():
            sys.stdout.write(f"{name:<{width}}  {description(f.read_text(encoding='utf-8'))}\n")
        return 0
    if args.template not in shipped:
        raise InputError(f"--template: no template {args.template!r} (templates: {', '.join(shipped)})")
    template = shipped[args.template]
    writes = [(template, args.config)]
    if (extra := shipped_map(template)) is not None:
        writes.append((extra, args.config.parent / extra.name))
    existing = [str(dest) for _, dest in writes if dest.exists()]
    if existing and not args.force:
        raise InputError(f"{', '.join(existing)}: exists (--force overwrites)")
    for source, dest in writes:
        if dest.is_dir():
            raise InputError(f"{dest}: is a directory (--config names the file to write)")
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(source.read_bytes())
        except OSError as exc:
            raise InputError(f"{dest}: cannot write: {exc.strerror or exc}") from exc
        sys.stdout.write(f"wrote {dest}\n")
    sys.stdout.write(f"next: edit {args.config}, then `pivotd check --config {args.config}`\n")
    return 0
