"""``pivotd install-service``: the systemd unit and sysusers file shipped with pivotd (``systemd/``), with the unit's
``ExecStart`` running this installation's ``pivotd`` on the given config; printed, or written with ``--write``.
"""

from __future__ import annotations

import argparse
import re
import sys
from pathlib import Path

from pivotd.data import DataDir, read_text
from pivotd.errors import InputError, PivotdError

DEFAULT_CONFIG = Path("/etc/pivotd/pivotd.yaml")
UNIT_PATH = Path("etc/systemd/system/pivotd.service")  # relative to --prefix
SYSUSERS_PATH = Path("etc/sysusers.d/pivotd.conf")
_EXEC_START = re.compile(r"^ExecStart=.*$", re.MULTILINE)
_EXEC_START_PRE = re.compile(r"^ExecStartPre=.*$", re.MULTILINE)


def pivotd_executable() -> str:
    """The ``pivotd`` console script of the running installation (next to its interpreter, as pip installs it;
    the venv's own path, not resolved through symlinks), else ``<python> -m pivotd.cli``; quoted for systemd."""
    script = Path(sys.executable).parent / "pivotd"
    if script.is_file():
        return _quote(str(script.absolute()))
    return f"{_quote(str(Path(sys.executable).absolute()))} -m pivotd.cli"


def _quote(word: str) -> str:
    """``word`` as one word of a systemd command line (double-quoted when it has blanks, quotes or backslashes)."""
    if not re.search(r'[\s"\\\']', word):
        return word
    return '"' + word.replace("\\", "\\\\").replace('"', '\\"') + '"'


def unit_text(executable: str, config: Path) -> str:
    """The shipped unit with ``ExecStart=<executable> run --config <config>`` and its check before each start,
    ``ExecStartPre=<executable> check --offline --config <config>`` (config made absolute)."""
    unit = read_text(DataDir.SYSTEMD, "pivotd.service")
    config_arg = _quote(str(config.absolute()))
    for pattern, line in ((_EXEC_START, f"ExecStart={executable} run --config {config_arg}"),
                          (_EXEC_START_PRE, f"ExecStartPre={executable} check --offline --config {config_arg}")):
        unit, count = pattern.subn(lambda _, line=line: line, unit)
        if count != 1:
            key = line.split("=", 1)[0]
            raise PivotdError(f"the shipped pivotd.service has {count} {key}= lines, expected 1")
    return unit


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--config", type=Path, default=DEFAULT_CONFIG, metavar="FILE",
                   help=f"the config the service runs with (default {DEFAULT_CONFIG})")
    p.add_argument("--write", action="store_true",
                   help=f"write the files (PREFIX/{UNIT_PATH}, PREFIX/{SYSUSERS_PATH}) instead of printing them")
    p.add_argument("--prefix", type=Path, default=Path("/"), metavar="DIR",
                   help="with --write: the root to write under (default /)")
    p.set_defaults(log_level="WARNING")


def run(args: argparse.Namespace) -> int:
    files = [(UNIT_PATH, unit_text(pivotd_executable(), args.config)),
             (SYSUSERS_PATH, read_text(DataDir.SYSTEMD, "pivotd.sysusers"))]
    if not args.write:
        for rel, text in files:
            sys.stdout.write(f"# /{rel}\n{text}" + ("" if text.endswith("\n") else "\n"))
        return 0
    for rel, text in files:
        dest = args.prefix / rel
        try:
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_text(text, encoding="utf-8")
        except OSError as exc:
            raise InputError(f"{dest}: cannot write: {exc.strerror or exc}") from exc
        sys.stdout.write(f"wrote {dest}\n")
    if args.prefix == Path("/"):
        sys.stdout.write("next: systemd-sysusers && systemctl daemon-reload && systemctl enable --now pivotd\n")
    return 0
