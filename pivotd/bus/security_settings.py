"""The ``zenoh.security`` settings (mutual TLS, access control) as a frozen dataclass.

Like :mod:`pivotd.bus.topics` it depends on nothing but the standard library, so the config loads without
Zenoh; :mod:`pivotd.bus.security` turns it into Zenoh's config keys.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path


@dataclass(frozen=True)
class ZenohSecurity:
    """Mutual TLS and access control of the Zenoh session (docs/SECURITY.md).

    ``ca``, ``cert``, ``key``: PEM files of the CA that signs every peer's certificate, and this node's
    certificate and private key (all three or none; TLS is on with them). ``allow_*``: the peers that may
    publish pivotd's inputs, by certificate common name, local network interface and Zenoh id; access
    control is on when any list is set, and a peer must match every list that is set.
    """

    ca: Path | None = None
    cert: Path | None = None
    key: Path | None = None
    verify_name_on_connect: bool = True
    allow_cert_common_names: tuple[str, ...] = ()
    allow_interfaces: tuple[str, ...] = ()
    allow_zids: tuple[str, ...] = ()

    @property
    def tls(self) -> bool:
        """True when the session uses mutual TLS (certificates are set)."""
        return self.ca is not None

    @property
    def access_control(self) -> bool:
        """True when only listed peers may publish the inputs."""
        return bool(self.allow_cert_common_names or self.allow_interfaces or self.allow_zids)
