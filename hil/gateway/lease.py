"""Gateway-side lease table: who may send on a bench, since when, until when.

Pure bookkeeping with injected clocks (`mono` for expiry, `wall` for `since`); the gateway
feeds it queries, keep-alives and liveliness events. One holder at a time; a holder is
identified by a secret `token` (16 random bytes) that rides on every sample it sends, and
by a public `alive_id` naming its liveliness token.
"""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime

from hil.units import S


@dataclass(frozen=True)
class LeaseInfo:
    holder: str
    token: bytes
    alive_id: str
    since_ns: int  # wall clock ns when granted
    renewed_mono_ns: int
    timeout_ns: int

    def public(self) -> dict:
        """What anyone may see: holder and since (never the token)."""
        return {"holder": self.holder, "since_ns": self.since_ns, "since": iso(self.since_ns),
                "timeout_s": self.timeout_ns / S}


def iso(t_ns: int) -> str:
    return datetime.fromtimestamp(t_ns / S, UTC).isoformat(timespec="milliseconds")


class LeaseTable:
    """At most one lease; `safing` blocks new leases while the safe state is being driven."""

    def __init__(self, timeout_s: float, *, mono: Callable[[], int] = time.monotonic_ns,
                 wall: Callable[[], int] = time.time_ns) -> None:
        if not 0.05 <= timeout_s <= 3600:
            raise ValueError(f"lease timeout {timeout_s:g} s: must be 0.05..3600 s")
        self.timeout_ns = round(timeout_s * S)
        self._mono, self._wall = mono, wall
        self._lock = threading.Lock()
        self.current: LeaseInfo | None = None
        self.safing: str | None = None  # previous holder, while the gateway makes it safe
        self.token: bytes | None = None  # fast path for the per-sample check

    def acquire(self, holder: str, token: bytes, alive_id: str) -> tuple[bool, dict]:
        """Grant if free (or already ours: renews); else refuse naming holder and since."""
        if not holder or len(token) != 16 or not alive_id:
            return False, {"reason": "bad request: holder, a 16-byte token and alive id "
                                     "are required"}
        with self._lock:
            cur = self.current
            if cur is not None and cur.token != token:
                return False, {"reason": "held", **cur.public()}
            if cur is None and self.safing is not None:
                return False, {"reason": "safing", "holder": f"gateway (safe state after "
                               f"{self.safing})", "since_ns": self._wall(),
                               "since": iso(self._wall())}
            if cur is not None and (holder, alive_id) != (cur.holder, cur.alive_id):
                # the holder's own token with another name or liveliness id: a new acquire
                # must not move the lease off the token whose loss ends it at once
                return False, {"reason": "bad request: the lease is held under another "
                                         "holder name or alive id", **cur.public()}
            since = cur.since_ns if cur is not None else self._wall()
            self.current = LeaseInfo(holder, bytes(token), alive_id, since, self._mono(),
                                     self.timeout_ns)
            self.token = self.current.token
            return True, self.current.public()

    def renew(self, token: bytes) -> bool:
        with self._lock:
            cur = self.current
            if cur is None or cur.token != token:
                return False
            self.current = LeaseInfo(cur.holder, cur.token, cur.alive_id, cur.since_ns,
                                     self._mono(), cur.timeout_ns)
            return True

    def release(self, token: bytes) -> LeaseInfo | None:
        """End the lease if `token` holds it; returns the ended lease."""
        with self._lock:
            cur = self.current
            if cur is None or cur.token != token:
                return None
            return self._end(cur)

    def expired(self) -> LeaseInfo | None:
        """End and return the lease if its keep-alive is overdue."""
        with self._lock:
            cur = self.current
            if cur is not None and self._mono() - cur.renewed_mono_ns > cur.timeout_ns:
                return self._end(cur)
            return None

    def gone(self, alive_id: str) -> LeaseInfo | None:
        """The holder's liveliness token disappeared: end and return its lease."""
        with self._lock:
            cur = self.current
            if cur is not None and cur.alive_id == alive_id:
                return self._end(cur)
            return None

    def _end(self, cur: LeaseInfo) -> LeaseInfo:
        self.current = None
        self.token = None
        self.safing = cur.holder
        return cur

    def safe_done(self) -> None:
        with self._lock:
            self.safing = None

    def allows(self, token: bytes | None) -> bool:
        """Whether a sample carrying `token` comes from the current holder."""
        t = self.token
        return t is not None and token == t

    def status(self) -> dict:
        with self._lock:
            cur = self.current
            return {"held": cur is not None, **(cur.public() if cur else {}),
                    "safing": self.safing}
