"""The gateway's zenoh key layout (docs/gateway.md). One prefix per bench: `<lab>/<bench>`.

    <lab>/<bench>/can/<bus>             CAN frames (hil.transport.zenoh_can wire format)
    <lab>/<bench>/rs485/<port>/m2s|s2m  RS-485 chunks with character times (serial_line)
    <lab>/<bench>/dio/<drive>/<line>    DI<n>, STO_A, STO_B, DO<n>, FDBK = b"1" / b"0"
    <lab>/<bench>/health                bus health: queryable + periodic publication
    <lab>/<bench>/lease                 lease queryable (acquire / renew / release / status)
    <lab>/<bench>/lease/alive/<id>      the holder's liveliness token
    <lab>/<bench>/info                  what the gateway exports (queryable)
"""

from __future__ import annotations

import re

_CHUNK = re.compile(r"^[A-Za-z0-9_.-]+\Z")


class KeyError_(ValueError):
    """A lab, bench or bus name that cannot be one chunk of a zenoh key."""


def check_chunk(what: str, name: str) -> str:
    """`name` if usable as one key chunk (letters, digits, _ . -), else KeyError_."""
    if not isinstance(name, str) or not _CHUNK.match(name):
        raise KeyError_(f"{what} {name!r}: must be one zenoh key chunk of letters, digits, "
                        "'_', '.' or '-' (no '/', '*', '$', '#', '?', spaces)")
    return name


def prefix(lab: str, bench: str) -> str:
    return f"{check_chunk('lab', lab)}/{check_chunk('bench', bench)}"


def can(pfx: str, bus: str) -> str:
    return f"{pfx}/can/{bus}"


def rs485(pfx: str, port: str) -> str:
    return f"{pfx}/rs485/{port}"


def dio(pfx: str, name: str) -> str:
    return f"{pfx}/dio/{name}"


def health(pfx: str) -> str:
    return f"{pfx}/health"


def lease(pfx: str) -> str:
    return f"{pfx}/lease"


def lease_alive(pfx: str, alive_id: str = "*") -> str:
    return f"{pfx}/lease/alive/{alive_id}"


def info(pfx: str) -> str:
    return f"{pfx}/info"
