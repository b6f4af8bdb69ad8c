"""LeaseTable: one holder, refusals name holder and since, keep-alive expiry, liveliness."""

from __future__ import annotations

import pytest

from hil.gateway.lease import LeaseTable
from hil.units import S

A, B = b"A" * 16, b"B" * 16


class Clock:
    def __init__(self) -> None:
        self.mono = 0
        self.wall = 1_700_000_000 * S

    def m(self) -> int:
        return self.mono

    def w(self) -> int:
        return self.wall


@pytest.fixture
def table():
    c = Clock()
    return LeaseTable(2.0, mono=c.m, wall=c.w), c


def test_second_holder_refused_with_holder_and_since(table):
    t, c = table
    ok, info = t.acquire("alice", A, "a1")
    assert ok and info["holder"] == "alice" and info["since_ns"] == c.wall
    c.wall += 5 * S
    ok, info = t.acquire("bob", B, "b1")
    assert not ok
    assert info["holder"] == "alice" and info["since_ns"] == 1_700_000_000 * S
    assert info["reason"] == "held" and info["since"].startswith("2023-11-14T22:13:20")
    assert "token" not in info  # the secret never leaves the table
    assert t.allows(A) and not t.allows(B) and not t.allows(None)


def test_reacquire_by_holder_keeps_since(table):
    t, c = table
    t.acquire("alice", A, "a1")
    c.wall += S
    ok, info = t.acquire("alice", A, "a1")
    assert ok and info["since_ns"] == 1_700_000_000 * S


def test_keepalive_expiry_then_safing_blocks_until_done(table):
    t, c = table
    t.acquire("alice", A, "a1")
    c.mono += 1 * S
    assert t.renew(A) and not t.renew(B)
    c.mono += 2 * S  # exactly the timeout: still held
    assert t.expired() is None
    c.mono += 1
    ended = t.expired()
    assert ended is not None and ended.holder == "alice"
    assert not t.allows(A)
    ok, info = t.acquire("bob", B, "b1")
    assert not ok and info["reason"] == "safing" and "alice" in info["holder"]
    t.safe_done()
    assert t.acquire("bob", B, "b1")[0]


def test_liveliness_gone_ends_only_the_holders_lease(table):
    t, _ = table
    t.acquire("alice", A, "a1")
    assert t.gone("zz") is None
    assert t.gone("a1").holder == "alice"
    assert t.status() == {"held": False, "safing": "alice"}


def test_release_needs_the_token_and_bad_requests_are_refused(table):
    t, _ = table
    t.acquire("alice", A, "a1")
    assert t.release(B) is None
    assert t.release(A).holder == "alice"
    ok, info = t.acquire("", B, "b1")
    assert not ok and "holder" in info["reason"]
    with pytest.raises(ValueError, match="lease timeout"):
        LeaseTable(0)
