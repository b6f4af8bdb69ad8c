"""Runner side of a gateway: take a bench's lease, then use its buses with `zenoh:` URLs.

    with acquire("lab", "bench1", holder="ci-42", connect=["tcp/127.0.0.1:7447"]) as lease:
        bus = open_can(lease.can_url("can0"))        # frames carry the lease token
        ...
    # released: the gateway drives the bench to its safe state

While a `Lease` is held, every zenoh transport in this process that puts under
`<lab>/<bench>/` attaches the lease token (hil.transport.zenoh_net.lease_token), which is
how the gateway tells the holder's frames from anyone else's. The lease is kept alive by a
liveliness token (the gateway notices at once when this process dies) and by renewals
every timeout/4 (a hung process loses it after the timeout). `lease.lost` is set if the
gateway ends it, or when it answered no renewal for the lease timeout (gateway killed or
paused, zenoh link lost: `lost_reason` says so). `lease.on_fault` hears the start and end of
either (the plan session records them on /faults, docs/faults.md).
"""

from __future__ import annotations

import contextlib
import getpass
import json
import os
import secrets
import socket
import threading
import time
from collections.abc import Iterable
from datetime import datetime
from typing import Any

import zenoh

from hil.gateway import keys
from hil.transport.zenoh_net import (
    close_session,
    make_config,
    open_session,
    set_lease_token,
    wait_connected,
)
from hil.units import S


class LeaseRefused(RuntimeError):
    """Someone else holds the bench: `holder` and `since` (UTC datetime) name them."""

    def __init__(self, bench: str, holder: str, since_ns: int | None, reason: str = "held"):
        self.bench, self.holder, self.since_ns, self.reason = bench, holder, since_ns, reason
        self.since = datetime.fromtimestamp(since_ns / S).astimezone() if since_ns else None
        when = self.since.isoformat(timespec="seconds") if self.since else "?"
        if reason.startswith("bad request"):  # refused for what it asked, not held: no
            super().__init__(f"bench {bench} refused the lease request: {reason}")  # holder
        else:
            super().__init__(f"bench {bench} is leased by {holder} since {when}"
                             + ("" if reason == "held" else f" ({reason})"))


class GatewayUnreachable(ConnectionError):
    """No gateway answered for a bench."""


def default_holder() -> str:
    try:
        user = getpass.getuser()
    except (KeyError, OSError):
        user = "?"
    return f"{user}@{socket.gethostname()}:{os.getpid()}"


def _endpoints(value: str | Iterable[str]) -> list[str]:
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return list(value)


def _query(session: zenoh.Session, key: str, payload: dict | None,
           timeout_s: float) -> dict | None:
    """First OK reply as JSON, or None. Retried until `timeout_s`: right after a session
    connects, the gateway's queryable may not be declared to it yet (the get then ends at
    once with no reply)."""
    body = json.dumps(payload) if payload is not None else None
    deadline = time.monotonic() + timeout_s
    while True:
        left = deadline - time.monotonic()
        for reply in session.get(key, payload=body, timeout=max(left, 0.01)):
            if reply.ok is not None:
                return json.loads(reply.ok.payload.to_bytes())
        if time.monotonic() + 0.01 >= deadline:
            return None
        time.sleep(0.01)


class Lease:
    """A held bench lease (context manager); see the module docstring."""

    def __init__(self, lab: str, bench: str, holder: str, connect: list[str], mode: str,
                 session: zenoh.Session, own_session: bool, timeout_s: float) -> None:
        self.lab, self.bench, self.holder = lab, bench, holder
        self.prefix = keys.prefix(lab, bench)
        self.connect, self.mode = connect, mode
        self.session = session
        self._own_session = own_session
        self.query_timeout_s = timeout_s
        self.token = secrets.token_bytes(16)
        self.alive_id = secrets.token_hex(8)
        self.since_ns = 0
        self.lease_timeout_s = 0.0
        self.lost = threading.Event()
        self.lost_reason = ""
        self._stop = threading.Event()
        self._alive: Any = None
        self._thread: threading.Thread | None = None
        self.released = False
        # on_fault(kind, active, t_ns, reason): the lease ends (`lease_lost`: the gateway
        # ended it; `link_lost`: no answer for the lease timeout, from the first unanswered
        # renewal) and that fault ends (the gateway answers again, or the lease is released)
        self.on_fault: Any = None
        self._fault: tuple[str, int] | None = None

    # -- protocol ----------------------------------------------------------------------------
    def _acquire(self) -> None:
        self._alive = self.session.liveliness().declare_token(
            keys.lease_alive(self.prefix, self.alive_id))
        ans = _query(self.session, keys.lease(self.prefix),
                     {"op": "acquire", "holder": self.holder, "token": self.token.hex(),
                      "alive": self.alive_id}, self.query_timeout_s)
        if ans is None:
            raise GatewayUnreachable(f"no gateway answered for bench {self.prefix} at "
                                     f"{', '.join(self.connect)} within "
                                     f"{self.query_timeout_s:g} s")
        if not ans.get("granted"):
            raise LeaseRefused(self.prefix, str(ans.get("holder", "?")), ans.get("since_ns"),
                               str(ans.get("reason", "held")))
        self.since_ns = int(ans["since_ns"])
        self.lease_timeout_s = float(ans["timeout_s"])
        set_lease_token(self.prefix, self.token)
        self._thread = threading.Thread(target=self._keepalive, daemon=True,
                                        name=f"lease-keepalive {self.prefix}")
        self._thread.start()

    def _keepalive(self) -> None:
        period = max(0.01, self.lease_timeout_s / 4)
        answered = time.monotonic()  # last renew the gateway answered
        unanswered_ns: int | None = None  # wall time of the first renew not answered since
        while not self._stop.wait(period):
            asked_ns = time.time_ns()
            ans = self._ask({"op": "renew", "token": self.token.hex()})
            if self._stop.is_set():
                return
            if ans is not None and not ans.get("granted"):
                self._lose(f"the gateway ended the lease (now: {ans.get('holder') or 'free'})",
                           "lease_lost", asked_ns)
                return
            if ans is not None:
                answered, unanswered_ns = time.monotonic(), None
                continue
            unanswered_ns = unanswered_ns or asked_ns
            if (silent := time.monotonic() - answered) > self.lease_timeout_s:
                # the gateway itself is gone: killed, paused, or the zenoh link lost; by
                # now it has expired the lease on its side too if it still runs
                self._lose(f"no answer from the gateway for {silent:.1f} s (gateway killed "
                           f"or paused, or the zenoh link to "
                           f"{', '.join(self.connect) or 'it'} lost)", "link_lost",
                           unanswered_ns)
                self._probe(period)
                return

    def _ask(self, payload: dict) -> dict | None:
        try:
            return _query(self.session, keys.lease(self.prefix), payload,
                          min(self.query_timeout_s, self.lease_timeout_s))
        except zenoh.ZError:
            return None

    def _probe(self, period: float) -> None:
        """After a lost link: ask for the lease status until the gateway answers again (the
        link is back: the end of the `link_lost` fault; the lease stays lost) or release."""
        while not self._stop.wait(period):
            if self._ask({"op": "status"}) is not None and not self._stop.is_set():
                self._fault_end("the gateway answers again (the lease stays lost)")
                return

    def _lose(self, reason: str, kind: str = "lease_lost", since_ns: int | None = None) -> None:
        self.lost_reason = reason
        set_lease_token(self.prefix, None)
        self.lost.set()
        self._fault = (kind, since_ns or time.time_ns())
        if self.on_fault is not None:
            with contextlib.suppress(Exception):  # recording must not break the keep-alive
                self.on_fault(kind, True, self._fault[1], reason)

    def _fault_end(self, reason: str) -> None:
        fault, self._fault = self._fault, None
        if fault is not None and self.on_fault is not None:
            with contextlib.suppress(Exception):
                self.on_fault(fault[0], False, time.time_ns(), reason)

    def release(self) -> None:
        """Give the bench back (the gateway then drives its safe state); idempotent."""
        if self.released:
            return
        self.released = True
        self._stop.set()
        if self._thread is not None:
            self._thread.join(5)
        self._fault_end("lease released")
        set_lease_token(self.prefix, None)
        with contextlib.suppress(zenoh.ZError, ValueError):
            if not self.lost.is_set() and self.session is not None:
                _query(self.session, keys.lease(self.prefix),
                       {"op": "release", "token": self.token.hex()}, self.query_timeout_s)
        if self._alive is not None:
            with contextlib.suppress(zenoh.ZError):
                self._alive.undeclare()
            self._alive = None
        if self._own_session:
            close_session(self.session)

    def __enter__(self) -> Lease:
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()

    # -- using the bench ----------------------------------------------------------------------
    def _query_string(self) -> str:
        how = "connect=" + ",".join(self.connect)
        return f"{how}&mode={self.mode}"

    def can_url(self, bus: str) -> str:
        """`zenoh:<lab>/<bench>/can/<bus>?connect=...` for open_can / can.Bus."""
        return f"zenoh:{keys.can(self.prefix, bus)}?{self._query_string()}"

    def serial_url(self, port: str, baud: int | None = None) -> str:
        """`zenoh:<lab>/<bench>/rs485/<port>?...&role=master` for open_serial."""
        extra = f"&baud={baud}" if baud else ""
        return f"zenoh:{keys.rs485(self.prefix, port)}?{self._query_string()}&role=master{extra}"

    def dio_url(self, drive: str) -> str:
        """`zenoh:<lab>/<bench>/dio/<drive>?...` for open_dio(role="harness")."""
        return f"zenoh:{keys.dio(self.prefix, drive)}?{self._query_string()}"

    def health(self, timeout_s: float = 2.0) -> dict | None:
        return _query(self.session, keys.health(self.prefix), None, timeout_s)

    def info(self, timeout_s: float = 2.0) -> dict | None:
        return _query(self.session, keys.info(self.prefix), None, timeout_s)


def _session(connect: list[str], mode: str, what: str, timeout_s: float,
             allow_remote: bool) -> zenoh.Session:
    cfg = make_config(mode, connect=connect, allow_remote=allow_remote)
    s = open_session(cfg, what=what)
    try:
        wait_connected(s, timeout_s, what=what, endpoints=connect)
    except ConnectionError:
        close_session(s)
        raise
    return s


def acquire(lab: str, bench: str, *, holder: str | None = None,
            connect: str | Iterable[str], mode: str = "peer", timeout_s: float = 5.0,
            allow_remote: bool = False, session: zenoh.Session | None = None) -> Lease:
    """Take the lease of `<lab>/<bench>` from its gateway; raises LeaseRefused (naming the
    holder and since when) if someone else has it, GatewayUnreachable if nobody answers.

    connect: the gateway's (or the router's, with mode="client") endpoints; TLS files
    for tls/ endpoints come from HIL_ZENOH_TLS_* (hil.transport.zenoh_net.tls_from_env)."""
    eps = _endpoints(connect)
    what = f"lease {lab}/{bench}"
    own = session is None
    if session is None:
        session = _session(eps, mode, what, timeout_s, allow_remote)
    lease = Lease(lab, bench, holder or default_holder(), eps, mode, session, own, timeout_s)
    try:
        lease._acquire()
    except BaseException:
        lease._stop.set()
        if lease._alive is not None:
            with contextlib.suppress(zenoh.ZError):
                lease._alive.undeclare()
        if own:
            close_session(session)
        raise
    return lease


def status(lab: str, bench: str, *, connect: str | Iterable[str], mode: str = "peer",
           timeout_s: float = 2.0, allow_remote: bool = False) -> dict:
    """Who holds a bench (no lease taken): {"held", "holder", "since", "safing"}."""
    eps = _endpoints(connect)
    s = _session(eps, mode, f"lease status {lab}/{bench}", timeout_s, allow_remote)
    try:
        ans = _query(s, keys.lease(keys.prefix(lab, bench)), {"op": "status"}, timeout_s)
    finally:
        close_session(s)
    if ans is None:
        raise GatewayUnreachable(f"no gateway answered for bench {lab}/{bench}")
    return ans


__all__ = ["GatewayUnreachable", "Lease", "LeaseRefused", "acquire", "default_holder",
           "status"]
