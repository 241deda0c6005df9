"""Zenoh mTLS and access control from the config's ``zenoh.security`` section (docs/SECURITY.md).

:func:`security_overlay` turns the section into the Zenoh config keys it sets: ``transport/link/tls``
(mutual TLS with one CA) and ``access_control``. The access-control policy denies by default and allows:
everything pivotd sends, everything it receives except publications, and publications on the input key
expressions (:func:`input_key_exprs`: pose, path, landmarks, targets) from the listed peers only. A peer
matches when it matches every ``allow_*`` list that is set (any entry within a list).

:func:`exposure_warning` reads a finished Zenoh config and says when a non-loopback endpoint lets peers in
without mutual TLS and access control.
"""

from __future__ import annotations

import ipaddress
import json
from collections.abc import Iterable

import zenoh

from pivotd.bus.security_settings import ZenohSecurity
from pivotd.bus.topics import CLOCK_TOPIC, BusTopics, bridge_key

#: Zenoh message types of access-control rules (Zenoh 1.x).
ACL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "reply", "declare_queryable", "liveliness_token",
                "liveliness_query", "declare_liveliness_subscriber")
_PUBLICATIONS = ("put", "delete")
_SECURE_PROTOCOLS = ("tls", "quic")


def input_key_exprs(topics: BusTopics) -> list[str]:
    """Key expressions covering every rmw_zenoh data key of pivotd's input topics (any type, any hash), or with
    ``topics.wire: ros2dds_bridge`` their zenoh-bridge-ros2dds keys."""
    names = (topics.pose, topics.path, topics.landmarks, topics.targets,
             *((topics.tf, topics.tf_static) if topics.pose_from_tf else ()),
             *((CLOCK_TOPIC,) if topics.use_sim_time else ()))
    if topics.bridged:
        return sorted({bridge_key(name) for name in names})
    return sorted({f"{topics.domain_id}/{name.strip('/')}/**" for name in names})


def tls_settings(sec: ZenohSecurity) -> dict[str, object]:
    """``transport/link/tls`` for mutual TLS: the same certificate and key when listening and connecting."""
    key, cert = str(sec.key), str(sec.cert)
    return {"root_ca_certificate": str(sec.ca), "listen_private_key": key, "listen_certificate": cert,
            "connect_private_key": key, "connect_certificate": cert, "enable_mtls": True,
            "verify_name_on_connect": sec.verify_name_on_connect}


def access_control(sec: ZenohSecurity, input_keys: Iterable[str]) -> dict[str, object]:
    """``access_control``: only the peers named by ``sec.allow_*`` may publish on ``input_keys``."""
    publishers: dict[str, object] = {"id": "input-publishers"}
    for field, values in (("cert_common_names", sec.allow_cert_common_names),
                          ("interfaces", sec.allow_interfaces), ("zids", sec.allow_zids)):
        if values:
            publishers[field] = list(values)
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [
            {"id": "own-messages", "permission": "allow", "flows": ["egress"], "messages": list(ACL_MESSAGES),
             "key_exprs": ["**"]},
            {"id": "incoming-non-publications", "permission": "allow", "flows": ["ingress"],
             "messages": [m for m in ACL_MESSAGES if m not in _PUBLICATIONS], "key_exprs": ["**"]},
            {"id": "input-publications", "permission": "allow", "flows": ["ingress"],
             "messages": list(_PUBLICATIONS), "key_exprs": list(input_keys)},
        ],
        "subjects": [{"id": "anyone"}, publishers],
        "policies": [
            {"id": "everyone", "rules": ["own-messages", "incoming-non-publications"], "subjects": ["anyone"]},
            {"id": "inputs", "rules": ["input-publications"], "subjects": ["input-publishers"]},
        ],
    }


def security_overlay(sec: ZenohSecurity, input_keys: Iterable[str]) -> dict[str, object]:
    """The Zenoh config keys (``/``-separated paths) that ``sec`` sets; empty when the section is unused."""
    out: dict[str, object] = {}
    if sec.tls:
        out["transport/link/tls"] = tls_settings(sec)
    if sec.access_control:
        out["access_control"] = access_control(sec, input_keys)
    return out


def _endpoints(config: zenoh.Config, key: str) -> list[str]:
    raw = json.loads(config.get_json(f"{key}/endpoints"))
    if isinstance(raw, dict):  # per-mode lists: {"router": [...], "peer": [...], "client": [...]}
        mode = json.loads(config.get_json("mode")) or "peer"
        raw = raw.get(mode, [])
    return [str(e) for e in raw or []]


def is_loopback(endpoint: str) -> bool:
    """True when ``endpoint`` (``proto/host:port[#…]``) is on the loopback interface or is not an IP link."""
    proto, _, addr = endpoint.partition("/")
    if proto not in ("tcp", "udp", "tls", "quic", "ws"):
        return proto in ("unixsock-stream", "unixpipe", "vsock")
    host = addr.split("#", 1)[0].rpartition(":")[0].strip("[]")
    if host == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False  # a host name: may resolve to any interface


def exposure_warning(config: zenoh.Config) -> str | None:
    """One line naming the non-loopback endpoints through which unauthenticated peers could publish pivotd's
    inputs (not TLS/QUIC with mutual authentication, or no access control); None when there is none."""
    tls = json.loads(config.get_json("transport/link/tls"))
    mtls = bool(tls.get("enable_mtls")) and bool(tls.get("root_ca_certificate") or
                                                     tls.get("root_ca_certificate_base64"))
    acl = bool(json.loads(config.get_json("access_control")).get("enabled"))
    exposed = [f"{what} {e}" for what in ("listen", "connect") for e in _endpoints(config, what)
               if not is_loopback(e) and not (e.partition("/")[0] in _SECURE_PROTOCOLS and mtls and acl)]
    if not exposed:
        return None
    missing = [name for name, ok in (("mutual TLS", mtls), ("access control", acl)) if not ok]
    lacking = " and ".join(missing) if missing else "a tls/ or quic/ endpoint"
    return (f"zenoh {', '.join(exposed)} is reachable from other hosts without {lacking}: any peer there can "
            "publish the pose, path and map layers (set zenoh.security, see docs/SECURITY.md)")
