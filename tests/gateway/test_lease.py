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


def test_the_holder_cannot_move_its_lease_to_another_alive_id(table):
    """An outside fuzz: `acquire` again with the holder's own token and another alive id was
    granted, so the lease no longer ended when the holder's liveliness token went away."""
    t, _c = table
    assert t.acquire("alice", A, "a1")[0]
    ok, info = t.acquire("alice2", A, "other")
    assert not ok and info["holder"] == "alice" and "another" in info["reason"]
    assert t.gone("a1") is not None  # the original token's loss still ends it


@pytest.mark.parametrize("holder", ["x" * 5_000_000, 1e999, "evil\n\x1b[31m", ["a"]])
def test_a_holder_name_is_a_short_printable_text(holder):
    """An outside fuzz: a 5 MB holder was granted (and /health carried it every period, the
    gateway's RSS +100 MB), `1e999` became "inf", and a newline and escapes went raw into the
    log. The gateway refuses them as a bad request, before the lease table."""
    from types import SimpleNamespace

    from hil.gateway.gateway import Gateway, GatewayConfig

    gw = Gateway(SimpleNamespace(name="b", drives={}, can={}, rs485={}, dio={}),
                 GatewayConfig(listen=["tcp/127.0.0.1:1"]))
    with pytest.raises(ValueError, match="holder"):
        gw._lease_op({"op": "acquire", "holder": holder, "token": "ab" * 16, "alive": "a"})
    assert gw.lease.current is None
