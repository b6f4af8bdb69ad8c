"""Lease.on_fault (issue 16, docs/faults.md "Lost link or gateway"): a lost gateway link is
a fault with a start and an end, like an injected one. The keep-alive runs against a
scripted gateway (`_ask` answers from a list): no processes, no network."""

from __future__ import annotations

import threading
import time

from hil.gateway.client import Lease


def _lease(answers: list[dict | None]) -> tuple[Lease, list[tuple]]:
    lease = Lease("lab", "b1", "me", ["tcp/127.0.0.1:1"], "peer", None, False, 0.1)
    lease.lease_timeout_s = 0.08  # renewals every 20 ms
    seen: list[tuple] = []
    lease.on_fault = lambda kind, active, t, reason: seen.append((kind, active, t, reason))
    script = iter(answers)
    lease._ask = lambda payload: next(script, {"granted": True, "held": True})  # type: ignore[method-assign]
    lease._thread = threading.Thread(target=lease._keepalive, daemon=True)
    lease._thread.start()
    return lease, seen


def _until(pred, timeout_s: float = 3.0) -> bool:
    end = time.monotonic() + timeout_s
    while not pred():
        if time.monotonic() > end:
            return False
        time.sleep(0.005)
    return True


def test_link_lost_then_back_is_one_fault_with_start_and_end():
    t0 = time.time_ns()
    lease, seen = _lease([{"granted": True}, *[None] * 8])  # silent > 80 ms, then answers
    try:
        assert _until(lambda: len(seen) == 2), seen
    finally:
        lease.release()
    (k1, a1, t1, why1), (k2, a2, t2, why2) = seen
    assert (k1, a1, k2, a2) == ("link_lost", True, "link_lost", False)
    assert "no answer from the gateway" in why1 and "answers again" in why2
    assert t0 < t1 < t2
    assert lease.lost.is_set()  # the lease stays lost: the runner stops the plan


def test_link_still_lost_ends_at_release():
    lease, seen = _lease([None] * 1000)
    assert _until(lambda: len(seen) == 1), seen
    lease.release()
    assert [(k, a, r) for k, a, _t, r in seen] == [
        ("link_lost", True, seen[0][3]), ("link_lost", False, "lease released")]


def test_lease_ended_by_the_gateway_is_lease_lost():
    lease, seen = _lease([{"granted": False, "holder": "other"}])
    assert _until(lambda: len(seen) == 1), seen
    lease.release()
    assert [(k, a) for k, a, _t, _r in seen] == [("lease_lost", True), ("lease_lost", False)]
    assert "ended the lease" in seen[0][3]
