"""Secure by default: loopback unless told otherwise; off loopback only TLS with client
certificates (mutual TLS), optionally narrowed to certificate common names (zenoh ACL).

zenoh 1.x keys used (`transport/link/tls`): root_ca_certificate, listen_certificate,
listen_private_key, connect_certificate, connect_private_key, enable_mtls. With
`enable_mtls` the listener rejects peers without a certificate signed by the root CA at
the TLS handshake; `access_control` (default deny, allow for `cert_common_names`) leaves
an authenticated but unlisted peer connected but answered by nothing.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from pathlib import Path

_LOOPBACK = re.compile(r"^(tcp|tls)/(127\.0\.0\.1|\[::1\]|localhost):[0-9]{1,5}\Z")
# Every message kind zenoh's ACL knows (1.x); the allow rule covers them all.
ACL_MESSAGES = ("put", "delete", "declare_subscriber", "query", "declare_queryable", "reply",
                "liveliness_token", "declare_liveliness_subscriber", "liveliness_query")


class GatewaySecurityError(ValueError):
    """A listen/connect setup the gateway refuses (names the endpoint and the rule)."""


@dataclass(frozen=True)
class TlsFiles:
    """PEM files: the CA that signs every peer, and this node's certificate and key."""

    root_ca: Path
    cert: Path
    key: Path

    def check(self) -> TlsFiles:
        for what, p in (("root CA", self.root_ca), ("certificate", self.cert),
                        ("private key", self.key)):
            if not Path(p).is_file():
                raise GatewaySecurityError(f"TLS {what} {p}: no such file")
        return self

    def section(self) -> dict[str, object]:
        """`transport/link/tls` for a node that listens and connects with mutual TLS."""
        ca, cert, key = (str(Path(p).resolve()) for p in (self.root_ca, self.cert, self.key))
        return {"root_ca_certificate": ca, "listen_certificate": cert,
                "listen_private_key": key, "connect_certificate": cert,
                "connect_private_key": key, "enable_mtls": True}


def is_loopback(endpoint: str) -> bool:
    return bool(_LOOPBACK.match(endpoint))


def acl_section(allow_cn: list[str] | tuple[str, ...]) -> dict[str, object]:
    """zenoh `access_control`: deny everything except peers whose certificate CN is listed."""
    return {
        "enabled": True,
        "default_permission": "deny",
        "rules": [{"id": "hil-gateway-allow", "messages": list(ACL_MESSAGES),
                   "flows": ["egress", "ingress"], "permission": "allow",
                   "key_exprs": ["**"]}],
        "subjects": [{"id": "hil-gateway-peers", "cert_common_names": list(allow_cn)}],
        "policies": [{"rules": ["hil-gateway-allow"], "subjects": ["hil-gateway-peers"]}],
    }


def check_exposure(listen: list[str], connect: list[str], tls: TlsFiles | None,
                   allow_cn: list[str] | tuple[str, ...] = ()) -> bool:
    """Refuse an exposed gateway without TLS + client authentication.

    Returns True if some endpoint leaves loopback (the caller then passes allow_remote)."""
    for ep in (*listen, *connect):
        if not ep.startswith(("tcp/", "tls/")):
            raise GatewaySecurityError(f"endpoint {ep!r}: only tcp/ (loopback) or tls/ "
                                       "endpoints are supported")
    if any(ep.startswith("tls/") for ep in (*listen, *connect)) and tls is None:
        raise GatewaySecurityError("tls/ endpoints need --tls-ca, --tls-cert and --tls-key")
    if allow_cn and tls is None:
        raise GatewaySecurityError("--allow-cn needs TLS (certificate common names)")
    remote = [ep for ep in (*listen, *connect) if not is_loopback(ep)]
    if not remote:
        return False
    plain = [ep for ep in remote if ep.startswith("tcp/")]
    if plain:
        raise GatewaySecurityError(
            f"refusing to expose the bench on {', '.join(plain)} without TLS: off loopback "
            "the gateway needs tls/<host>:<port> endpoints with --tls-ca, --tls-cert and "
            "--tls-key (mutual TLS, recipe in docs/gateway.md)")
    if tls is None:  # pragma: no cover - caught above
        raise GatewaySecurityError("TLS files are required off loopback")
    return True
