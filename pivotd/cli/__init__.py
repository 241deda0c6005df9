"""pivotd, the PIVOT gimbal controller: run (the default command), check, plan, bench, status, plot, gimbal, init,
install-service.

Each command lives in its own module exposing ``configure(parser)`` and ``run(args) -> int``;
this module only dispatches and turns :class:`~pivotd.errors.PivotdError` into exit code 2.
"""

from __future__ import annotations

import argparse
import difflib
import importlib
import logging
import sys

from pivotd.errors import PivotdError
from pivotd.version import version

# command name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("pivotd.cli.run", "run the daemon (the default command)"),
    "check": ("pivotd.cli.check", "validate a config, load its map, print a summary"),
    "plan": ("pivotd.cli.plan", "optimize viewing directions offline for a map and a path"),
    "bench": ("pivotd.bench", "run a benchmark"),
    "status": ("pivotd.cli.status", "show running daemons' status, asked over Zenoh"),
    "plot": ("pivotd.cli.plot", "draw figures from an MCAP recording"),
    "gimbal": ("pivotd.cli.gimbal", "ping a gimbal, move it to a pose or scan its limits (before tracking)"),
    "init": ("pivotd.cli.init", "write a config template (spot, demo ...) to start from"),
    "install-service": ("pivotd.cli.install_service", "print or write the systemd unit and sysusers file"),
}


class _ArgumentParser(argparse.ArgumentParser):
    def error(self, message: str) -> None:  # one line, exit 2
        self.exit(2, f"{self.prog}: error: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    """The full ``pivotd`` argument parser with every available sub-command."""
    parser = _ArgumentParser(prog="pivotd", description=" ".join(__doc__.split("\n\n")[0].split()))
    parser.add_argument("--version", action="version", version=f"pivotd {version()}")
    subs = parser.add_subparsers(dest="command", parser_class=_ArgumentParser, metavar="COMMAND")
    for name, (module_name, help_text) in COMMANDS.items():
        try:
            module = importlib.import_module(module_name)
        except ModuleNotFoundError as exc:
            if exc.name != module_name:
                raise
            continue
        module.configure(subs.add_parser(name, help=help_text, description=help_text))
    return parser


def unknown_command(name: str) -> str:
    """The one-line error for a command ``name`` pivotd does not have, with the nearest one when there is one."""
    close = difflib.get_close_matches(name, COMMANDS, n=1, cutoff=0.6)
    hint = f" (did you mean {close[0]}?)" if close else f" (commands: {', '.join(COMMANDS)})"
    return f"unknown command {name!r}{hint}"


def main(argv: list[str] | None = None) -> int:
    """Entry point of the ``pivotd`` console script; returns the process exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    if argv and not argv[0].startswith("-") and argv[0] not in COMMANDS:
        print(f"pivotd: error: {unknown_command(argv[0])}", file=sys.stderr)
        return 2
    # `pivotd [--config FILE] ...` without a sub-command means `pivotd run ...`.
    if not argv or (argv[0] not in COMMANDS and argv[0] not in ("-h", "--help", "--version")):
        argv = ["run", *argv]
    args = build_parser().parse_args(argv)
    if args.command is None:
        build_parser().print_help()
        return 2
    logging.basicConfig(
        level=getattr(args, "log_level", None) or "INFO",
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
        stream=sys.stderr,
    )
    if getattr(args, "json", None):  # machine-readable runs: no progress lines on the terminal
        from pivotd.progress import silence

        silence()
    module = importlib.import_module(COMMANDS[args.command][0])
    try:
        return int(module.run(args) or 0)
    except PivotdError as exc:
        print(f"pivotd {args.command}: error: {exc}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        return 130


if __name__ == "__main__":
    sys.exit(main())
