"""hil.clock: the virtual clock's event order, waits, deadlines and cancellation."""

from __future__ import annotations

import threading

import pytest

from hil import clock
from hil.clock import Cancelled, ClockQueue, VirtualClock, VirtualTimeout
from hil.units import MS, S


def test_events_fire_in_time_then_submission_order() -> None:
    c = VirtualClock(epoch_ns=0)
    seen: list[tuple[str, int]] = []
    c.at(5 * MS, lambda: seen.append(("b", c.time_ns())))
    c.at(2 * MS, lambda: seen.append(("a", c.time_ns())))
    c.at(5 * MS, lambda: seen.append(("c", c.time_ns())))
    c.sleep(0.004)
    assert seen == [("a", 2 * MS)]
    assert c.time_ns() == 4 * MS
    c.sleep(0.010)
    assert seen == [("a", 2 * MS), ("b", 5 * MS), ("c", 5 * MS)]
    assert c.time_ns() == 14 * MS


def test_wait_for_stops_at_the_event_that_makes_it_true() -> None:
    c = VirtualClock(epoch_ns=0)
    box = {"v": 0}
    c.at(30 * MS, lambda: box.update(v=1))
    c.at(40 * MS, lambda: box.update(v=2))
    assert c.wait_for(lambda: box["v"] == 1, 1.0)
    assert c.time_ns() == 30 * MS  # not a poll period later
    assert not c.wait_for(lambda: box["v"] == 3, 0.5)
    assert c.time_ns() == 530 * MS
    assert box["v"] == 2


def test_cancelled_events_do_not_run() -> None:
    c = VirtualClock(epoch_ns=0)
    seen = []
    ev = c.after(MS, lambda: seen.append(1))
    ev.cancel()
    c.sleep(0.01)
    assert seen == []


def test_an_event_never_waits() -> None:
    c = VirtualClock(epoch_ns=0)
    errors = []

    def bad() -> None:
        try:
            c.sleep(0.001)
        except RuntimeError as e:
            errors.append(str(e))

    c.after(MS, bad)
    c.sleep(0.002)
    assert errors and "inside a clock event" in errors[0]


def test_watch_deadline_raises_a_base_exception_at_the_deadline() -> None:
    c = VirtualClock(epoch_ns=0)
    with c.watch(None, 100 * MS), pytest.raises(VirtualTimeout):
        try:
            c.sleep(1.0)
        except Exception:  # step code's own handlers must not swallow it
            pytest.fail("VirtualTimeout caught as an Exception")
    assert c.time_ns() == 100 * MS


def test_watch_cancel_raises_cancelled() -> None:
    c = VirtualClock(epoch_ns=0)
    cancel = threading.Event()
    c.at(10 * MS, cancel.set)
    with c.watch(cancel, None), pytest.raises(Cancelled):
        c.sleep(1.0)
    assert c.time_ns() == 10 * MS
    c.sleep(0.01)  # outside the block: no longer watched


def test_clock_queue_waits_in_clock_time() -> None:
    import queue

    c = VirtualClock(epoch_ns=0)
    q = ClockQueue()
    with clock.use(c):
        c.at(7 * MS, lambda: q.put("reply"))
        assert q.get(timeout=0.3) == "reply"
        assert c.time_ns() == 7 * MS
        with pytest.raises(queue.Empty):
            q.get(timeout=0.3)
        assert c.time_ns() == 307 * MS


def test_module_functions_follow_the_installed_clock() -> None:
    c = VirtualClock()
    assert not clock.is_virtual()
    with clock.use(c):
        assert clock.is_virtual()
        t0 = clock.time_ns()
        assert t0 == clock.VIRTUAL_EPOCH_NS
        clock.sleep(2.5)
        assert clock.monotonic_ns() - t0 == int(2.5 * S)
        ev = threading.Event()
        handle = clock.call_later(0.1, ev.set)
        assert clock.wait(ev, 1.0)
        assert clock.time_ns() - t0 == int(2.6 * S)
        handle.cancel()
    assert clock.current() is clock.REAL
