"""zenoh plumbing shared by the CAN, serial and DI/DO transports.

- `make_config`: a `zenoh.Config` built only from explicit values (mode, listen/connect
  endpoints, multicast and gossip scouting off, scouting/delay 0). Endpoints must be
  loopback TCP unless `allow_remote=True`.
- `open_session` / `close_session` / `close_all`: a registry that closes every session
  before interpreter shutdown joins zenoh's callback threads (docs/dev/feasibility.md §2.4 gotcha 1:
  `atexit` is too late, so `threading._register_atexit` is used).
- `wait_connected`: a peer's `zenoh.open` returns before its connect link is up; frames put
  before then are lost. Wait for a transport (and optionally a matching subscriber).
- `start_router(port)`: the project's zenoh router as a subprocess (`python -m
  hil.transport.zenoh_router`) for more than two processes on one key; those processes use
  mode=client (peer mode through a router with gossip off gets no data, gotcha 3).
- TLS: `tls/127.0.0.1:<port>` / `tls/localhost:<port>` endpoints count as loopback. A config
  with a tls/ endpoint gets `transport/link/tls` from `tls=` or, by default, from the
  environment (`HIL_ZENOH_TLS_ROOT_CA`, `HIL_ZENOH_TLS_CERT`, `HIL_ZENOH_TLS_KEY`), so a
  runner's `zenoh:` URLs stay the same behind a TLS gateway (docs/gateway.md).
- Lease tokens (`set_lease_token` / `lease_token`): a gateway lease held in this process
  (hil.gateway.client) is attached to every sample the zenoh transports put under its bench
  prefix; a gateway forwards only samples that carry the current holder's token.
"""

from __future__ import annotations

import contextlib
import json
import logging
import os
import subprocess
import sys
import threading
import time
from collections.abc import Callable, Iterable, Mapping
from dataclasses import dataclass
from typing import Any

import zenoh

from hil.transport.urls import ZenohConfigError, ZenohEndpoints, check_endpoint

log = logging.getLogger(__name__)

MODES = ("peer", "client", "router")
def make_config(
    mode: str,
    *,
    listen: Iterable[str] = (),
    connect: Iterable[str] = (),
    allow_remote: bool = False,
    tls: Mapping[str, object] | None = None,
) -> zenoh.Config:
    """An explicit zenoh config: nothing is left to zenoh's defaults that touches the net.

    An empty `listen` list is written too: a default peer listens on tcp/[::]:0.
    `tls`: the `transport/link/tls` section (root_ca_certificate, listen_/connect_ private
    key and certificate, enable_mtls); default for tls/ endpoints: `tls_from_env()`.
    """
    if mode not in MODES:
        raise ZenohConfigError(f"zenoh mode {mode!r}: must be one of {', '.join(MODES)}")
    listen = [check_endpoint(e, allow_remote=allow_remote) for e in listen]
    connect = [check_endpoint(e, allow_remote=allow_remote) for e in connect]
    if not listen and not connect:
        raise ZenohConfigError("zenoh config needs at least one listen or connect endpoint")
    if mode == "client" and not connect:
        raise ZenohConfigError("zenoh mode 'client' needs a connect endpoint (a router)")
    c = zenoh.Config()
    c.insert_json5("mode", json.dumps(mode))
    c.insert_json5("scouting/multicast/enabled", "false")  # else 224.0.0.224:7446
    c.insert_json5("scouting/gossip/enabled", "false")
    c.insert_json5("scouting/delay", "0")  # else open() blocks ~500 ms (gotcha 2)
    c.insert_json5("listen/endpoints", json.dumps(listen))
    c.insert_json5("connect/endpoints", json.dumps(connect))
    if tls is None and any(e.startswith("tls/") for e in (*listen, *connect)):
        tls = tls_from_env()
        if tls is None:
            raise ZenohConfigError(f"zenoh tls/ endpoint(s) {', '.join(listen + connect)}: "
                                   f"need TLS files; set {TLS_ENV['root_ca_certificate']} "
                                   "(and the certificate/key variables for mutual TLS)")
    if tls:
        c.insert_json5("transport/link/tls", json.dumps(dict(tls)))
    return c


# Environment variables naming the TLS files of this process (runner side).
TLS_ENV = {"root_ca_certificate": "HIL_ZENOH_TLS_ROOT_CA",
           "certificate": "HIL_ZENOH_TLS_CERT", "private_key": "HIL_ZENOH_TLS_KEY"}


def tls_from_env() -> dict[str, object] | None:
    """`transport/link/tls` from HIL_ZENOH_TLS_ROOT_CA / _CERT / _KEY, or None if unset.

    With a certificate and key, they serve both to connect (client auth, mutual TLS) and to
    listen."""
    ca = os.environ.get(TLS_ENV["root_ca_certificate"])
    if not ca:
        return None
    out: dict[str, object] = {"root_ca_certificate": ca}
    cert = os.environ.get(TLS_ENV["certificate"])
    key = os.environ.get(TLS_ENV["private_key"])
    if bool(cert) != bool(key):
        raise ZenohConfigError(f"{TLS_ENV['certificate']} and {TLS_ENV['private_key']} "
                               "must be set together")
    if cert and key:
        out.update(connect_certificate=cert, connect_private_key=key,
                   listen_certificate=cert, listen_private_key=key, enable_mtls=True)
    return out


# -- lease tokens (hil.gateway) ------------------------------------------------------

_lease_tokens: dict[str, bytes] = {}


def set_lease_token(prefix: str, token: bytes | None) -> None:
    """Attach `token` to every sample put under `<prefix>/` (None: stop)."""
    with _lock:
        if token is None:
            _lease_tokens.pop(prefix, None)
        else:
            _lease_tokens[prefix] = bytes(token)


def lease_token(key: str) -> bytes | None:
    """The lease token for a key, if a lease on one of its prefixes is held here."""
    if not _lease_tokens:
        return None
    for prefix, token in list(_lease_tokens.items()):
        if key.startswith(prefix) and key[len(prefix):len(prefix) + 1] == "/":
            return token
    return None


def config_from(ep: ZenohEndpoints, *, allow_remote: bool = False,
                tls: Mapping[str, object] | None = None) -> zenoh.Config:
    return make_config(ep.mode, listen=ep.listen, connect=ep.connect, allow_remote=allow_remote,
                       tls=tls)


# -- session registry ----------------------------------------------------------------

_sessions: set[zenoh.Session] = set()
_lock = threading.Lock()
_hook_installed = False


def _install_hook() -> None:
    global _hook_installed
    if _hook_installed:
        return
    try:
        # Runs in threading._shutdown, *before* non-daemon threads are joined.
        threading._register_atexit(close_all)  # type: ignore[attr-defined]
    except RuntimeError:  # interpreter already shutting down
        return
    _hook_installed = True


def open_session(config: zenoh.Config, *, what: str = "zenoh session") -> zenoh.Session:
    """`zenoh.open(config)`, registered so it is closed before interpreter shutdown."""
    try:
        session = zenoh.open(config)
    except zenoh.ZError as e:
        raise ConnectionError(f"{what}: cannot open zenoh session: {e}") from None
    with _lock:
        _install_hook()
        _sessions.add(session)
    return session


def undeclare(*entities: Any) -> None:
    """Undeclare subscribers, publishers and queryables (None skipped; a session already
    gone is no error): the first half of closing a zenoh transport."""
    for entity in entities:
        if entity is not None:
            with contextlib.suppress(zenoh.ZError):
                entity.undeclare()


def close_session(session: zenoh.Session) -> None:
    """Close a session (idempotent) and forget it."""
    with _lock:
        _sessions.discard(session)
    try:
        if not session.is_closed():
            session.close()
    except zenoh.ZError as e:  # e.g. "close operation timed out" after a flood
        log.warning("closing zenoh session: %s", e)


def close_all() -> None:
    """Close every session still open (called at interpreter shutdown)."""
    with _lock:
        sessions = list(_sessions)
    for s in sessions:
        close_session(s)


def open_sessions() -> int:
    """How many registered sessions are open (tests check for leaks)."""
    with _lock:
        return len(_sessions)


def wait_connected(
    session: zenoh.Session, timeout_s: float, *, what: str, endpoints: Iterable[str] = ()
) -> None:
    """Block until the session has a peer or router, else raise ConnectionError."""
    deadline = time.monotonic() + timeout_s
    while True:
        info = session.info
        if info.peers_zid() or info.routers_zid():
            return
        if time.monotonic() >= deadline:
            raise ConnectionError(
                f"{what}: no zenoh peer or router reachable at {', '.join(endpoints) or '?'} "
                f"within {timeout_s:g} s")
        time.sleep(0.001)


def wait_matching(publisher: zenoh.Publisher, timeout_s: float) -> bool:
    """Wait until the publisher has a matching subscriber; False on timeout."""
    deadline = time.monotonic() + timeout_s
    while not publisher.matching_status.matching:
        if time.monotonic() >= deadline:
            return False
        time.sleep(0.0005)
    return True


ASK_EVERY_S = 0.1  # a level never heard of is asked for again at most this often ...
ASK_TIMEOUT_S = 0.25  # ... and waited for this long


class AskAgain:
    """Runs `learn()` (a query of a key's current levels) on a thread of its own, at most
    every `every_s`: for a DI/DO or pulse level never heard of, set before this side's
    subscriber was routed and not published again while it does not change. Never blocks
    the caller; an error (the session closed meanwhile) means nothing is learned."""

    def __init__(self, learn: Callable[[], Any], name: str, every_s: float = ASK_EVERY_S
                 ) -> None:
        self.learn, self.name, self.every_s = learn, name, every_s
        self._at = float("-inf")  # time.monotonic() of the last ask

    def __call__(self) -> None:
        now = time.monotonic()
        if now - self._at < self.every_s:
            return
        self._at = now
        threading.Thread(target=self._run, daemon=True, name=self.name).start()

    def _run(self) -> None:
        with contextlib.suppress(Exception):
            self.learn()


# -- router --------------------------------------------------------------------------


@dataclass
class RouterHandle:
    """A project zenoh router subprocess. `stop()` (or `with`) ends it."""

    process: subprocess.Popen
    endpoint: str

    def stop(self, timeout_s: float = 5.0) -> None:
        p = self.process
        if p.poll() is None:
            with contextlib.suppress(OSError):
                p.stdin.close()  # type: ignore[union-attr]
            p.terminate()
            try:
                p.wait(timeout_s)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait(timeout_s)
        for stream in (p.stdout, p.stdin):
            if stream:
                with contextlib.suppress(OSError):
                    stream.close()

    @property
    def alive(self) -> bool:
        return self.process.poll() is None

    def __enter__(self) -> RouterHandle:
        return self

    def __exit__(self, *exc) -> None:
        self.stop()


def start_router(
    port: int,
    *,
    host: str = "127.0.0.1",
    tie_to_parent: bool = True,
    allow_remote: bool = False,
    timeout_s: float = 10.0,
) -> RouterHandle:
    """Start `python -m hil.transport.zenoh_router --listen tcp/<host>:<port>`.

    A subprocess rather than a thread: the router outlives any client that dies and never
    shares a GIL with a bus. With `tie_to_parent` (default) it also exits when our end of its
    stdin closes, i.e. when this process dies, so no router is left behind.
    Returns once the router prints `ready`; raises ConnectionError otherwise.
    """
    endpoint = check_endpoint(f"tcp/{host}:{port}", allow_remote=allow_remote)
    cmd = [sys.executable, "-m", "hil.transport.zenoh_router", "--listen", endpoint]
    if tie_to_parent:
        cmd.append("--exit-on-stdin-eof")
    if allow_remote:
        cmd.append("--allow-remote")
    env = dict(os.environ, PYTHONUNBUFFERED="1")
    p = subprocess.Popen(cmd, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                         stderr=subprocess.STDOUT, text=True, env=env)
    handle = RouterHandle(p, endpoint)
    lines: list[str] = []
    ready = threading.Event()

    def _read() -> None:
        for line in p.stdout:  # type: ignore[union-attr]
            lines.append(line.rstrip())
            if "ready" in line:
                ready.set()
                break

    reader = threading.Thread(target=_read, daemon=True, name="zenoh-router-start")
    reader.start()
    if not ready.wait(timeout_s):
        handle.stop()
        reader.join(1)
        raise ConnectionError(f"zenoh router on {endpoint} did not start within "
                              f"{timeout_s:g} s: {' | '.join(lines[-5:]) or 'no output'}")
    return handle
