"""Transport URLs (docs/transports.md).

    CAN     socketcan:can0   virtual:bus0   zenoh:<key>?connect=tcp/127.0.0.1:7447&mode=client
            <python-can interface>:<channel>?bitrate=500000        (passed through to can.Bus)
    RS-485  serial:/dev/ttyUSB0?baud=115200&parity=N&bytesize=8&stopbits=1
            pty:<link-path>?baud=38400     zenoh:<key>?listen=tcp/127.0.0.1:7447&role=slave
    DI/DO   virtual:<name>   zenoh:<key>?connect=...   modbus-tcp://<host>:<port>?unit=1

`parse_url(url, kind)` checks the scheme against the kind ("can", "serial", "dio", "pulse") and
returns a `TransportUrl`; every error is a `TransportUrlError` naming the URL and the rule.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from typing import Literal

from can.interfaces import VALID_INTERFACES

Kind = Literal["can", "serial", "dio", "pulse"]

# Schemes every kind accepts besides python-can interfaces (CAN only).
SCHEMES: dict[str, tuple[str, ...]] = {
    "can": ("socketcan", "virtual", "zenoh"),
    "serial": ("serial", "pty", "zenoh"),
    "dio": ("virtual", "zenoh", "modbus-tcp"),
    "pulse": ("virtual", "zenoh"),
}
FORBIDDEN_CAN = {"udp_multicast": "multicast is forbidden on this project's networks"}
ZENOH_PARAMS = {"listen", "connect", "mode"}
SERIAL_PARAMS = {"baud", "parity", "bytesize", "stopbits"}
ZENOH_MODES = ("peer", "client")
PARITIES = ("N", "E", "O", "M", "S")
# Delta ASDA-A3 defaults: P3.001 X=3 -> 38400 bps (L10509-L10544); P3.002=6 -> 8,N,2 RTU
# (L10546-L10557). See docs/manual-choices.md#transport.
DEFAULT_BAUD = 38400
DEFAULT_PARITY = "N"
DEFAULT_BYTESIZE = 8
DEFAULT_STOPBITS = 2.0

_SCHEME_RE = re.compile(r"^([A-Za-z][A-Za-z0-9_+.-]*):(.*)\Z", re.S)
_KEY_BAD = re.compile(r"[*$#?\s]")


class TransportUrlError(ValueError):
    """A transport URL that cannot be used; the message names the URL and the rule."""

    def __init__(self, url: str, problem: str):
        super().__init__(f"transport URL {url!r}: {problem}")
        self.url = url
        self.problem = problem


@dataclass(frozen=True)
class SerialSettings:
    """Character format of a serial line."""

    baud: int = DEFAULT_BAUD
    parity: str = DEFAULT_PARITY
    bytesize: int = DEFAULT_BYTESIZE
    stopbits: float = DEFAULT_STOPBITS

    @property
    def bits_per_char(self) -> float:
        """start + data + parity + stop bits."""
        return 1 + self.bytesize + (0 if self.parity == "N" else 1) + self.stopbits

    @property
    def char_time_s(self) -> float:
        return self.bits_per_char / self.baud

    @property
    def char_time_ns(self) -> int:
        return round(self.bits_per_char * 1_000_000_000 / self.baud)


@dataclass(frozen=True)
class ZenohEndpoints:
    """Where a zenoh session listens / connects, and its mode."""

    mode: str = "peer"
    listen: tuple[str, ...] = ()
    connect: tuple[str, ...] = ()


@dataclass(frozen=True)
class TransportUrl:
    """A parsed transport URL.

    `scheme` e.g. "zenoh"; `target` the channel / key / path / "host:port"; `params` the
    query as strings (a repeated key is joined with ",").
    """

    url: str
    kind: str
    scheme: str
    target: str
    params: dict[str, str] = field(default_factory=dict)

    def error(self, problem: str) -> TransportUrlError:
        return TransportUrlError(self.url, problem)

    # -- typed views ---------------------------------------------------------------
    def int_param(self, name: str, default: int, lo: int, hi: int) -> int:
        raw = self.params.get(name)
        if raw is None:
            return default
        try:
            value = int(raw, 0)
        except ValueError:
            raise self.error(f"{name}={raw!r} is not an integer") from None
        if not lo <= value <= hi:
            raise self.error(f"{name}={value} is outside {lo}..{hi}")
        return value

    def float_param(self, name: str, default: float, lo: float, hi: float) -> float:
        raw = self.params.get(name)
        if raw is None:
            return default
        try:
            value = float(raw)
        except ValueError:
            raise self.error(f"{name}={raw!r} is not a number") from None
        if not lo <= value <= hi:
            raise self.error(f"{name}={value} is outside {lo}..{hi}")
        return value

    def zenoh(self) -> ZenohEndpoints:
        """listen / connect (comma separated, several allowed) and mode=peer|client."""
        mode = self.params.get("mode", "peer")
        if mode not in ZENOH_MODES:
            raise self.error(f"mode={mode!r}: must be one of {', '.join(ZENOH_MODES)}")
        listen = _split(self.params.get("listen", ""))
        connect = _split(self.params.get("connect", ""))
        if not listen and not connect:
            raise self.error("zenoh needs at least one listen= or connect= endpoint")
        if mode == "client" and not connect:
            raise self.error("mode=client needs a connect= endpoint (a router)")
        for ep in (*listen, *connect):  # loopback only (network rules), a real port
            try:
                check_endpoint(ep)
            except ZenohConfigError as e:
                raise self.error(str(e)) from None
        return ZenohEndpoints(mode=mode, listen=listen, connect=connect)

    def serial(self) -> SerialSettings:
        """baud, parity (N/E/O/M/S), bytesize (5-8), stopbits (1, 1.5, 2)."""
        baud = self.int_param("baud", DEFAULT_BAUD, 50, 10_000_000)
        parity = self.params.get("parity", DEFAULT_PARITY).upper()
        if parity not in PARITIES:
            raise self.error(f"parity={parity!r}: must be one of {'/'.join(PARITIES)}")
        bytesize = self.int_param("bytesize", DEFAULT_BYTESIZE, 5, 8)
        stopbits = self.float_param("stopbits", DEFAULT_STOPBITS, 1, 2)
        if stopbits not in (1.0, 1.5, 2.0):
            raise self.error(f"stopbits={stopbits:g}: must be 1, 1.5 or 2")
        return SerialSettings(baud, parity, bytesize, stopbits)

    @property
    def host(self) -> str:
        """modbus-tcp host."""
        return _host_port(self)[0]

    @property
    def port(self) -> int:
        """modbus-tcp port."""
        return _host_port(self)[1]


def _split(value: str) -> tuple[str, ...]:
    return tuple(v.strip() for v in value.split(",") if v.strip())


def _host_port(u: TransportUrl) -> tuple[str, int]:
    host, sep, port = u.target.rpartition(":")
    if not sep or not host:
        raise u.error("needs <host>:<port>")
    host = host.strip("[]")
    try:
        number = int(port)
    except ValueError:
        raise u.error(f"port {port!r} is not a number") from None
    if not 0 < number < 65536:
        raise u.error(f"port {number} is outside 1..65535")
    return host, number


def _parse_query(url: str, query: str) -> dict[str, str]:
    params: dict[str, str] = {}
    for part in query.split("&"):
        if not part:
            continue
        name, sep, value = part.partition("=")
        if not sep or not name:
            raise TransportUrlError(url, f"query part {part!r} is not name=value")
        params[name] = f"{params[name]},{value}" if name in params else value
    return params


_LOOPBACK = re.compile(r"^(?:tcp|tls)/(127\.0\.0\.1|\[::1\]|localhost):([0-9]{1,5}|auto)\Z")
_ANY_TCP = re.compile(r"^(tcp|tls|quic)/(.+):([0-9]{1,5})\Z")


class ZenohConfigError(ValueError):
    """A zenoh endpoint or mode that the project's network rules refuse."""


def check_endpoint(endpoint: str, *, allow_remote: bool = False) -> str:
    """Return `endpoint` if it is tcp/ or tls/ on 127.0.0.1, [::1] or localhost with a port
    (0-65535, or `auto`: a free port chosen at run time); else raise ZenohConfigError."""
    m = _LOOPBACK.match(endpoint)
    if m and (m.group(2) == "auto" or int(m.group(2)) < 65536):
        return endpoint
    if allow_remote and _ANY_TCP.match(endpoint):
        return endpoint
    rule = ("must be tcp/127.0.0.1:<port>, tcp/[::1]:<port> or tcp/localhost:<port>"
            + ("" if allow_remote else " (pass allow_remote=True for other hosts)"))
    raise ZenohConfigError(f"zenoh endpoint {endpoint!r}: {rule}")


def check_zenoh_key(url: str, key: str) -> None:
    """A zenoh key expression usable as a bus key: no wildcards, no empty chunks."""
    if not key:
        raise TransportUrlError(url, "zenoh needs a key, e.g. zenoh:bench/can0")
    if _KEY_BAD.search(key):
        raise TransportUrlError(url, f"zenoh key {key!r} must not contain * $ # ? or spaces")
    if key.startswith("/") or key.endswith("/") or "//" in key:
        raise TransportUrlError(url, f"zenoh key {key!r} has an empty chunk (leading, "
                                     "trailing or double '/')")


def can_bitrate(url: str) -> int:
    """A CAN bus's bit rate from its URL (`?bitrate=`), else 1 Mbit/s (the A3's CANopen)."""
    return parse_url(url, "can").int_param("bitrate", 1_000_000, 10_000, 1_000_000)


def parse_url(url: str, kind: Kind) -> TransportUrl:
    """Parse and check a transport URL for a CAN bus, a serial line or a DI/DO set."""
    if kind not in SCHEMES:
        raise ValueError(f"transport kind {kind!r}: must be one of {', '.join(SCHEMES)}")
    if not isinstance(url, str) or not url.strip():
        raise TransportUrlError(str(url), f"empty {kind} URL")
    m = _SCHEME_RE.match(url.strip())
    if not m:
        raise TransportUrlError(url, f"must look like <scheme>:<target>[?name=value&...] "
                                     f"(schemes for {kind}: {_schemes_text(kind)})")
    scheme, rest = m.group(1).lower(), m.group(2)
    target, _, query = rest.partition("?")
    params = _parse_query(url, query)
    if scheme == "modbus-tcp":
        if not target.startswith("//"):
            raise TransportUrlError(url, "modbus-tcp must look like modbus-tcp://<host>:<port>")
        target = target[2:].rstrip("/")
    if not target:
        raise TransportUrlError(url, f"{scheme}: needs a target after ':'")
    allowed = SCHEMES[kind]
    if scheme not in allowed:
        if kind == "can" and scheme in FORBIDDEN_CAN:
            raise TransportUrlError(url, f"interface {scheme}: {FORBIDDEN_CAN[scheme]}")
        if kind != "can" or scheme in ("pty", "modbus-tcp"):
            raise TransportUrlError(url, f"scheme {scheme!r} is not a {kind} transport "
                                         f"(use one of {_schemes_text(kind)})")
        if scheme not in VALID_INTERFACES:
            raise TransportUrlError(url, f"{scheme!r} is neither {', '.join(allowed)} "
                                         "nor a python-can interface (can.VALID_INTERFACES)")
    u = TransportUrl(url=url, kind=kind, scheme=scheme, target=target, params=params)
    _check(u)
    return u


def _schemes_text(kind: str) -> str:
    extra = ", <python-can interface>" if kind == "can" else ""
    return ", ".join(SCHEMES[kind]) + extra


def _check(u: TransportUrl) -> None:
    """Per-scheme parameter checks (unknown parameters are errors except for python-can)."""
    if u.scheme == "zenoh":
        check_zenoh_key(u.url, u.target)
        extra = {"serial": SERIAL_PARAMS | {"role"}, "can": set(), "dio": set(),
                 "pulse": set()}[u.kind]
        _only(u, ZENOH_PARAMS | extra)
        u.zenoh()
        if u.kind == "serial":
            u.serial()
            role = u.params.get("role", "master")
            if role not in ("master", "slave"):
                raise u.error(f"role={role!r}: must be master or slave")
    elif u.scheme in ("serial", "pty"):
        _only(u, SERIAL_PARAMS)
        u.serial()
    elif u.scheme == "modbus-tcp":
        _only(u, {"unit", "poll_ms", "timeout"})
        _host_port(u)
        u.int_param("unit", 1, 0, 255)
        u.float_param("poll_ms", 5.0, 0.5, 10_000)
        u.float_param("timeout", 1.0, 0.01, 60)
    elif u.scheme == "virtual" and u.kind in ("dio", "pulse"):
        _only(u, set())
    elif u.scheme == "virtual" and u.kind == "can":  # the in-process bus: its bit time only
        _only(u, {"bitrate"})
        u.int_param("bitrate", 1_000_000, 10_000, 1_000_000)


def _only(u: TransportUrl, allowed: set[str]) -> None:
    unknown = sorted(set(u.params) - allowed)
    if unknown:
        names = ", ".join(sorted(allowed)) or "none"
        raise u.error(f"unknown parameter(s) {', '.join(unknown)} for {u.scheme} "
                      f"(allowed: {names})")
