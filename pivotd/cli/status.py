"""``pivotd status``: ask running daemons for their status over Zenoh and print it as a table (or JSON).

Each daemon answers queries on its status key ``pivot/<name>/status`` (a queryable next to the published
status, :class:`~pivotd.bus.pivot_bus.PivotBus`); ``--all`` queries ``pivot/*/status``, so one command on a
fleet's router lists every robot. No answer within ``--timeout`` is a one-line error (exit 2).
"""

from __future__ import annotations

import argparse
import json
import re
import sys
import time
from typing import Any, TextIO

from pivotd.bus.topics import status_key_for
from pivotd.errors import InputError, PivotdError

DEFAULT_CONNECT = "tcp/127.0.0.1:7447"  # Zenoh's default router port (zenohd, rmw_zenohd)
ALL_KEY = status_key_for("*")
_NA = "-"


def configure(p: argparse.ArgumentParser) -> None:
    who = p.add_mutually_exclusive_group()
    who.add_argument("--name", default=None, help="the daemon's config `name` (default: from --config, else pivotd)")
    who.add_argument("--all", action="store_true", help="every daemon reachable (key pivot/*/status)")
    p.add_argument("--config", default=None, metavar="FILE",
                   help="take the Zenoh endpoints and the name from this pivotd config")
    p.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help=f"Zenoh router or daemon to ask (repeatable; default {DEFAULT_CONNECT})")
    p.add_argument("--timeout", type=float, default=2.0, metavar="S", help="wait this long for answers (default 2)")
    p.add_argument("--json", action="store_true", help="print JSON (the status documents) instead of a table")
    p.add_argument("--watch", type=float, nargs="?", const=1.0, default=None, metavar="S",
                   help="refresh every S seconds (default 1) until Ctrl-C")
    p.add_argument("--count", type=int, default=None, metavar="N", help="with --watch: stop after N refreshes")
    p.set_defaults(log_level="WARNING")  # the table is the output; no session chatter


def run(args: argparse.Namespace) -> int:
    endpoints, name = _target(args)
    if not args.timeout > 0:
        raise InputError(f"--timeout {args.timeout}: must be > 0")
    if args.watch is not None and not args.watch > 0:
        raise InputError(f"--watch {args.watch}: must be > 0")
    key = ALL_KEY if args.all else status_key_for(name)
    from pivotd.bus.session import open_session

    session = open_session("client", connect=endpoints)
    try:
        if args.watch is None:
            docs = query_status(session, key, args.timeout)
            if not docs:
                raise PivotdError(_nobody(key, endpoints, args.timeout))
            _print(docs, args.json, single=not args.all, out=sys.stdout)
            return 0
        return _watch(session, key, endpoints, args)
    finally:
        session.close()


def _target(args: argparse.Namespace) -> tuple[list[str], str]:
    """Endpoints to connect to and the daemon name, from the options and the optional ``--config``."""
    endpoints = list(args.connect)
    name = args.name
    if args.config is not None:
        from pivotd.config import load_config

        cfg = load_config(args.config)
        name = name or cfg.name
        if not endpoints:  # reach the daemon where it listens (on this host) or where it connects
            endpoints = [_local(e) for e in cfg.zenoh.listen] + list(cfg.zenoh.connect)
    from pivotd.bus.session import validate_endpoint
    from pivotd.config.settings import NAME_PATTERN

    endpoints = [validate_endpoint(e, "--connect endpoint") for e in endpoints or [DEFAULT_CONNECT]]
    name = name or "pivotd"
    if not re.fullmatch(NAME_PATTERN, name):
        raise InputError(f"--name {name!r}: a daemon name has letters, digits, '_' and '-' only")
    return endpoints, name


def _local(endpoint: str) -> str:
    """A listen locator as a connect locator on this host (``0.0.0.0``/``[::]`` become loopback)."""
    proto, _, addr = endpoint.partition("/")
    host, _, port = addr.rpartition(":")
    if host in ("0.0.0.0", "[::]"):
        host = "127.0.0.1" if host == "0.0.0.0" else "[::1]"
    return f"{proto}/{host}:{port}"


def _nobody(key: str, endpoints: list[str], timeout: float) -> str:
    return f"no pivotd answered on {key} within {timeout:g} s (asked via {', '.join(endpoints)})"


def query_status(session: Any, key: str, timeout: float) -> dict[str, dict]:
    """Ask ``key`` (may hold ``*``) and collect every answer: {daemon name: status document}, sorted by name.

    Answers that are not JSON objects are kept as ``{"state": "invalid", "error": ...}`` so a broken daemon
    still shows up."""
    docs: dict[str, dict] = {}
    for reply in session.get(key, timeout=timeout):
        if reply.ok is None:
            continue
        sample = reply.ok
        reply_key = str(sample.key_expr)
        try:
            doc = json.loads(sample.payload.to_bytes())
            if not isinstance(doc, dict):
                raise ValueError("not a JSON object")
        except ValueError as exc:
            doc = {"state": "invalid", "error": f"{reply_key}: {exc}"}
        name = str(doc.get("name") or _name_of_key(reply_key))
        docs[name] = doc
    return dict(sorted(docs.items()))


def _name_of_key(key: str) -> str:
    parts = key.split("/")
    return parts[1] if len(parts) == 3 else key


def _watch(session: Any, key: str, endpoints: list[str], args: argparse.Namespace) -> int:
    n = 0
    clear = sys.stdout.isatty() and not args.json
    while args.count is None or n < args.count:
        started = time.monotonic()
        docs = query_status(session, key, args.timeout)
        if clear:
            sys.stdout.write("\x1b[H\x1b[2J")
        if docs:
            _print(docs, args.json, single=not args.all, out=sys.stdout)
        elif args.json:
            print(json.dumps({"error": _nobody(key, endpoints, args.timeout)}))
        else:
            print(f"{time.strftime('%H:%M:%S')} {_nobody(key, endpoints, args.timeout)}")
        sys.stdout.flush()
        n += 1
        if args.count is not None and n >= args.count:
            break
        time.sleep(max(0.0, args.watch - (time.monotonic() - started)))
    return 0


def _print(docs: dict[str, dict], as_json: bool, single: bool, out: TextIO) -> None:
    if as_json:
        doc: Any = next(iter(docs.values())) if single and len(docs) == 1 else docs
        out.write(json.dumps(doc, sort_keys=True) + "\n")
    else:
        out.write(format_table(docs) + "\n")


# ---------------------------------------------------------------------------- the table
def _get(doc: dict, *path: str) -> Any:
    node: Any = doc
    for p in path:
        if not isinstance(node, dict):
            return None
        node = node.get(p)
    return node


def _num(value: Any, fmt: str) -> str:
    return _NA if not isinstance(value, int | float) or isinstance(value, bool) else format(value, fmt)


def dropped_inputs(doc: dict) -> dict[str, int]:
    """Input messages dropped per topic (sum of the bus counters ``dropped_<reason>``), topics with drops only."""
    out = {}
    for topic, counters in (_get(doc, "bus") or {}).items():
        if isinstance(counters, dict):
            n = sum(int(v) for k, v in counters.items() if k.startswith("dropped_") and isinstance(v, int | float))
            if n:
                out[str(topic)] = n
    return out


def link_drops(doc: dict) -> dict[str, int]:
    """Frames the gimbal link's decoder dropped, per reason (``link_counters.drop_<reason>``: framing after a
    resync, length, crc, version, unknown_type, payload), reasons with drops only."""
    counters = _get(doc, "link_counters") or {}
    return {k[len("drop_"):]: int(v) for k, v in sorted(counters.items())
            if k.startswith("drop_") and isinstance(v, int | float) and not isinstance(v, bool) and v}


def _link_drops_cell(doc: dict) -> str:
    counters = _get(doc, "link_counters")
    if not isinstance(counters, dict) or not any(k.startswith("drop_") for k in counters):
        return _NA  # no framed serial link (stopped, or a link without a frame decoder)
    return str(sum(link_drops(doc).values()))


def _faults(doc: dict) -> str:
    names = _get(doc, "gimbal", "fault_names") or []
    now = ",".join(str(n) for n in names) if names else "none"
    episodes = doc.get("fault_episodes")
    return now if not episodes else f"{now} ({episodes} seen)"


#: table columns: (heading, function of the daemon's name and status document -> cell text)
COLUMNS: tuple[tuple[str, Any], ...] = (
    ("NAME", lambda name, d: name),
    ("STATE", lambda name, d: str(d.get("state", _NA))),
    ("LINK", lambda name, d: str(d.get("link", _NA))),
    ("POSE AGE", lambda name, d: _NA if d.get("pose_age_s") is None else f"{d['pose_age_s']:.2f} s"),
    ("VISIBLE", lambda name, d: _num(_get(d, "planner", "visible_now"), "d")),
    ("PLANS", lambda name, d: _num(_get(d, "planner", "plans"), "d")),
    ("SOLVE p50/p99 ms", lambda name, d: f"{_num(_get(d, 'planner', 'solve_ms_p50'), '.1f')}/"
                                         f"{_num(_get(d, 'planner', 'solve_ms_p99'), '.1f')}"),
    ("JITTER p99 ms", lambda name, d: _num(_get(d, "control", "jitter_ms_p99"), ".2f")),
    ("FAULTS", lambda name, d: _faults(d)),
    ("DROPPED", lambda name, d: str(sum(dropped_inputs(d).values()))),
    ("LINK DROPS", lambda name, d: _link_drops_cell(d)),
)


def format_table(docs: dict[str, dict]) -> str:
    """One row per daemon (columns :data:`COLUMNS`), then one line per input topic with dropped messages and
    the last error of each daemon that has one."""
    rows = [[heading for heading, _ in COLUMNS]]
    rows += [[str(cell(name, doc)) for _, cell in COLUMNS] for name, doc in docs.items()]
    widths = [max(len(r[i]) for r in rows) for i in range(len(COLUMNS))]
    lines = ["  ".join(c.ljust(w) for c, w in zip(r, widths, strict=True)).rstrip() for r in rows]
    for name, doc in docs.items():
        for topic, n in dropped_inputs(doc).items():
            reasons = {k[len("dropped_"):]: v for k, v in doc["bus"][topic].items() if k.startswith("dropped_") and v}
            lines.append(f"{name}: {topic}: {n} dropped ({', '.join(f'{k} {v}' for k, v in sorted(reasons.items()))})")
        drops = link_drops(doc)
        if drops:
            detail = ", ".join(f"{k} {v}" for k, v in drops.items())
            lines.append(f"{name}: gimbal link: {sum(drops.values())} frames dropped ({detail})")
        lines += [f"{name}: {line}" for line in health_lines(doc)]
    return "\n".join(lines)


def _last_error_line(doc: dict) -> str | None:
    """``last error (12.3 s ago[, resolved]): message``; a plain string from a daemon of an older version."""
    error = doc.get("last_error") or doc.get("error")
    if not error:
        return None
    if not isinstance(error, dict):
        return f"last error: {error}"
    when = ""
    if isinstance(error.get("time"), int | float) and isinstance(doc.get("time"), int | float):
        when = f"{max(0.0, doc['time'] - error['time']):.1f} s ago"
    if error.get("resolved_time") is not None:
        when = f"{when}, resolved" if when else "resolved"
    return f"last error ({when}): {error.get('message')}" if when else f"last error: {error.get('message')}"


def health_lines(doc: dict) -> list[str]:
    """What a daemon reports beside its row: a dead thread, a failed recording, dropped log records, stalls of the
    host, the last error."""
    out = []
    if doc.get("threads_dead"):
        out.append(f"threads died: {', '.join(doc['threads_dead'])} (nothing is controlled)")
    rec = doc.get("recording") or {}
    if rec.get("state") == "failed":
        out.append(f"recording failed: {rec.get('error')} ({rec.get('path')}; {rec.get('messages', 0)} messages "
                   f"recorded, {rec.get('dropped', 0)} not)")
    dropped = (doc.get("logging") or {}).get("dropped", 0)
    if dropped:
        out.append(f"{dropped} log records dropped (the log output was not read fast enough)")
    stalls = (doc.get("link_counters") or {}).get("host_stalls", 0)
    if stalls:
        out.append(f"host stalled {stalls} times while the gimbal link was up (not counted as link losses)")
    error = _last_error_line(doc)
    if error:
        out.append(error)
    return out

