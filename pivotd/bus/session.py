"""Opening a Zenoh session from pivotd's settings (mode, endpoints, optional config file, scouting).

In client mode nothing works without a router, and a router that comes up after pivotd (at boot, or after a
restart of the router) is normal: :func:`open_session_waiting` says once that it waits and for which endpoints,
and retries with backoff, each attempt bounded (``connect/timeout_ms``) so that the caller stays responsive to
signals between attempts. Zenoh's own unbounded retry (``connect/timeout_ms: -1``) would block the caller inside
``zenoh.open`` for as long as the router stays away.
"""

from __future__ import annotations

import json
import logging
import re
import time
from collections.abc import Callable, Iterable
from pathlib import Path

import zenoh

from pivotd.bus.security import exposure_warning, security_overlay
from pivotd.bus.security_settings import ZenohSecurity
from pivotd.errors import ConfigError

log = logging.getLogger(__name__)

MODES = ("peer", "client")
# Like rmw_zenoh's default session config: peers accept direct connections from this host only; other
# hosts are reached through the router (``connect``) or explicit ``listen`` endpoints.
DEFAULT_PEER_LISTEN = "tcp/127.0.0.1:0"
# <protocol>/<address>[#<config>], e.g. tcp/127.0.0.1:7447, tls/robot.local:7447, udp/[::1]:7447
#: Client mode: how long one attempt to reach a router lasts [s], and the backoff between attempts [s] (doubling).
CONNECT_ATTEMPT_S = 1.0
CONNECT_BACKOFF_S = (0.5, 4.0)
_NO_ROUTER = "Unable to connect to any of"  # the start of Zenoh's error when no connect endpoint answered
_ENDPOINT = re.compile(r"^(tcp|udp|tls|quic|ws|unixsock-stream|unixpipe|serial|vsock)/[^\s/]\S*$")


class RouterUnreachableError(ConfigError):
    """Client mode: no router answered on the connect endpoints (the settings are fine; it may come up later)."""


def validate_endpoint(endpoint: str, what: str = "endpoint") -> str:
    """Return ``endpoint`` stripped; raise :class:`ConfigError` naming it when it is not ``proto/address``."""
    ep = str(endpoint).strip()
    if not _ENDPOINT.match(ep):
        raise ConfigError(f"invalid Zenoh {what} {endpoint!r} (expected e.g. tcp/127.0.0.1:7447)")
    proto, _, addr = ep.partition("/")
    if proto in ("tcp", "udp", "tls", "quic", "ws"):
        host, sep, port = addr.split("#", 1)[0].rpartition(":")
        if not sep or not host or not port.isdigit() or not 0 <= int(port) <= 65535:
            raise ConfigError(f"invalid Zenoh {what} {endpoint!r}: needs host:port with a port 0-65535")
    return ep


def build_config(mode: str = "peer", connect: Iterable[str] = (), listen: Iterable[str] = (),
                 config_file: str | Path | None = None, multicast_scouting: bool = False,
                 security: ZenohSecurity | None = None, input_keys: Iterable[str] = (),
                 max_message_bytes: int | None = None) -> zenoh.Config:
    """A :class:`zenoh.Config` from a base file (TLS, auth, …) overlaid with the given settings.

    Without a file and without ``listen`` endpoints, a peer listens on :data:`DEFAULT_PEER_LISTEN`.
    ``security`` (the config's ``zenoh.security``) adds mutual TLS and access control; ``input_keys`` are
    the key expressions only its listed peers may publish on (:func:`pivotd.bus.security.input_key_exprs`).
    ``max_message_bytes`` bounds what Zenoh reassembles from a link (larger messages are dropped inside Zenoh,
    uncounted; Zenoh's own default is 1 GiB).
    """
    if mode not in MODES:
        raise ConfigError(f"invalid Zenoh mode {mode!r} (expected one of {', '.join(MODES)})")
    connect = [validate_endpoint(e, "connect endpoint") for e in connect]
    listen = [validate_endpoint(e, "listen endpoint") for e in listen]
    if config_file is not None:
        path = Path(config_file)
        if not path.is_file():
            raise ConfigError(f"{path}: Zenoh config file not found")
        try:
            config = zenoh.Config.from_file(str(path))
        except zenoh.ZError as exc:
            raise ConfigError(f"{path}: invalid Zenoh config: {_one_line(exc)}") from exc
    else:
        config = zenoh.Config()
    try:
        config.insert_json5("mode", json.dumps(mode))
        if connect:
            config.insert_json5("connect/endpoints", json.dumps(connect))
        if listen:
            config.insert_json5("listen/endpoints", json.dumps(listen))
        elif config_file is None and mode == "peer":
            config.insert_json5("listen/endpoints", json.dumps([DEFAULT_PEER_LISTEN]))
        config.insert_json5("scouting/multicast/enabled", json.dumps(bool(multicast_scouting)))
        if config_file is None:  # as rmw_zenoh's default config: transient-local publishers timestamp samples
            config.insert_json5("timestamping/enabled", "true")
            # No shared memory (rmw_zenoh's default too): with it, a peer on the same host hands over its large
            # messages in its own 16 MiB pool, which this process then maps (resident memory it does not bound),
            # and this process keeps a pool of its own for what it publishes.
            config.insert_json5("transport/shared_memory/enabled", "false")
        if max_message_bytes is not None:
            config.insert_json5("transport/link/rx/max_message_size", json.dumps(int(max_message_bytes)))
        if security is not None:
            for key, value in security_overlay(security, input_keys).items():
                config.insert_json5(key, json.dumps(value))
    except zenoh.ZError as exc:
        raise ConfigError(f"invalid Zenoh setting: {_one_line(exc)}") from exc
    return config


def open_session(mode: str = "peer", connect: Iterable[str] = (), listen: Iterable[str] = (),
                 config_file: str | Path | None = None, multicast_scouting: bool = False,
                 security: ZenohSecurity | None = None, input_keys: Iterable[str] = (),
                 max_message_bytes: int | None = None, connect_timeout_s: float | None = None,
                 warn: bool = True) -> zenoh.Session:
    """Open a Zenoh session; raises :class:`ConfigError` with a one-line reason on bad settings.

    A ``connect`` endpoint that is well-formed but unreachable does not fail in peer mode (Zenoh
    keeps retrying); in client mode Zenoh fails when no router answers, reported as :class:`RouterUnreachableError`
    (a ConfigError), at once or, with ``connect_timeout_s`` [s], after retrying for that long.
    ``warn``: log the exposure warning of these settings, if any (pivotd.bus.security.exposure_warning).
    """
    config = build_config(mode, connect, listen, config_file, multicast_scouting, security, input_keys,
                          max_message_bytes)
    if warn and (warning := exposure_warning(config)) is not None:
        log.warning("%s", warning)
    if mode == "client" and connect_timeout_s is not None:
        try:
            config.insert_json5("connect/timeout_ms", json.dumps(max(1, round(connect_timeout_s * 1e3))))
            config.insert_json5("connect/exit_on_failure", "true")
        except zenoh.ZError as exc:
            raise ConfigError(f"invalid Zenoh setting: {_one_line(exc)}") from exc
    try:
        session = zenoh.open(config)
    except zenoh.ZError as exc:
        where = ", ".join([*(f"listen {e}" for e in listen), *(f"connect {e}" for e in connect)]) or mode
        text = _one_line(exc)
        unreachable = mode == "client" and text.startswith(_NO_ROUTER)
        raise (RouterUnreachableError if unreachable else ConfigError)(
            f"cannot open Zenoh session ({where}): {text}") from exc
    log.info("zenoh session %s open (%s, connect=%s, listen=%s)", session.info.zid(), mode, list(connect),
             list(listen))
    return session


def open_session_waiting(wait: Callable[[float], bool], mode: str = "peer", connect: Iterable[str] = (),
                         attempt_s: float = CONNECT_ATTEMPT_S,
                         backoff_s: tuple[float, float] = CONNECT_BACKOFF_S, **settings) -> zenoh.Session | None:
    """:func:`open_session`; in client mode, while no router answers, log once that it waits and for which
    endpoints, then try again: each attempt lasts at most ``attempt_s`` [s], and between attempts ``wait(seconds)``
    is called with a delay doubling from ``backoff_s[0]`` to ``backoff_s[1]`` [s]. ``wait`` returns True when the
    caller is stopping: then None is returned. Bad settings raise :class:`ConfigError` at once, as from
    :func:`open_session` (``settings``: its other keyword arguments)."""
    connect = list(connect)
    delay, t0, attempts = backoff_s[0], time.monotonic(), 0
    while True:
        attempts += 1
        try:
            session = open_session(mode, connect, connect_timeout_s=attempt_s, warn=attempts == 1, **settings)
        except RouterUnreachableError as exc:
            if attempts == 1:
                log.warning("waiting for the Zenoh router at %s (client mode; no router answers yet: retrying "
                            "with backoff up to %.0f s)", ", ".join(connect), backoff_s[1])
            log.debug("%s (attempt %d)", exc, attempts)
            if wait(delay):
                return None
            delay = min(2.0 * delay, backoff_s[1])
            continue
        if attempts > 1:
            log.info("Zenoh router at %s reached after %.1f s (%d attempts)", ", ".join(connect),
                     time.monotonic() - t0, attempts)
        return session


def _one_line(exc: BaseException) -> str:
    """Zenoh's error text on one line, without its Rust source locations."""
    text = re.sub(r"\s+at \S+\.rs:\d+\.?", "", " ".join(str(exc).split()))
    return text[:300]
