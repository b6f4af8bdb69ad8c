"""hil.clock: the virtual clock's event order, waits, deadlines and cancellation."""

from __future__ import annotations

import threading
import time

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


def test_nested_batches_settle_once_at_the_outer_end() -> None:
    c = VirtualClock(epoch_ns=0)
    settled: list[int] = []
    with clock.use(c):
        pending = {"n": 2}

        def busy() -> bool:
            return pending["n"] > 0

        def drain() -> None:
            pending["n"] -= 1
            settled.append(c.time_ns())

        c.at(MS, drain)
        c.at(2 * MS, drain)
        with clock.batch():
            with clock.batch():
                c.settle(busy)
            assert settled == []  # the inner batch does not settle
            c.settle(busy)
        assert settled == [MS, 2 * MS] and c.held == []


def test_settle_gives_up_on_a_bus_that_never_idles() -> None:
    c = VirtualClock(epoch_ns=0)

    def again() -> None:
        c.after(MS, again)

    c.after(MS, again)
    c.settle(lambda: True)  # always busy: ends at the settle limit, not never
    assert clock.SETTLE_LIMIT_NS <= c.time_ns() <= clock.SETTLE_LIMIT_NS + MS


def test_a_stale_sdo_reply_does_not_put_the_client_back_on_the_wall_clock() -> None:
    import time

    import canopen
    import pytest as _pytest
    from canopen.sdo.exceptions import SdoCommunicationError

    from hil.drivers.canopen_clock import sdo_on_clock
    from hil.transport.can_bus import open_can

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        bus = open_can("virtual:sdo-stale")
        net = canopen.Network(bus)
        from hil.transport.sim import ListenerPump

        net.notifier = ListenerPump(bus, net.listeners)
        node = canopen.RemoteNode(5, canopen.ObjectDictionary())
        net.add_node(node)
        sdo_on_clock(node.sdo)
        node.sdo.MAX_RETRIES = 1  # one attempt (0 would retry for ever)
        node.sdo.responses.put(b"\x43\x00\x10\x00\0\0\0\0")  # a stale reply
        t0, w0 = c.time_ns(), time.monotonic()
        with _pytest.raises(SdoCommunicationError):
            node.sdo.upload(0x1000, 0)  # nobody answers: canopen swaps its reply queue
        assert isinstance(node.sdo.responses, ClockQueue)
        assert c.time_ns() - t0 >= 300 * MS  # the 0.3 s reply timeout passed in bench time
        assert time.monotonic() - w0 < 0.25  # not in wall time
        bus.shutdown()


def test_a_signal_while_events_run_never_cuts_one_and_never_outlives_its_wait():
    """A Ctrl-C handler raising inside `run_until` (after an event was taken, or inside one)
    lost that event: a host tick that reschedules itself never ran again and the model
    stopped (13 of 300 real SIGINTs in an outside probe). `defer_interrupt` defers it to
    the top of the next pass; one deferred while an event then raises is raised in place
    of that error, not left to cut the safe state's later wait. The real signals go to a
    child process of their own (a test worker's main thread may not be the test's)."""
    import subprocess
    import sys

    probe = """
import os, random, signal, threading
from hil.clock import VirtualClock
from hil.plan.runner import Interrupts
lost = 0
for _ in range(120):
    clk = VirtualClock()
    def tick(clk=clk):
        sum(range(150))
        clk.after(1_000_000, tick)
    clk.after(0, tick)
    with Interrupts(clk):
        try:
            threading.Timer(random.uniform(0.0005, 0.003), os.kill,
                            (os.getpid(), signal.SIGINT)).start()
            clk.run_until(clk.time_ns() + 10**15)
        except KeyboardInterrupt:
            pass
    lost += not any(not e.cancelled for e in clk._heap)
print("lost", lost)
"""
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True,
                         timeout=120)
    assert out.stdout.strip() == "lost 0", (out.stdout, out.stderr[-2000:])

    clk = VirtualClock()

    def fails():
        assert clk.defer_interrupt(KeyboardInterrupt("SIGINT (Ctrl-C)"))
        raise ValueError("the event's own error")

    clk.after(0, fails)
    with pytest.raises(KeyboardInterrupt):
        clk.run_until(clk.time_ns() + 10)
    ran = []
    clk.after(5, lambda: ran.append(1))
    assert clk.run_until(clk.time_ns() + 10) and ran  # nothing left over for this wait


def test_only_the_runs_own_threads_move_bench_time() -> None:
    """Bench time is the run's: the thread that installed the clock, a step thread inside
    `watch`. Another thread's wait says so; its queue and condition waits wait in wall time
    for what the run's events put there (docs/clock.md "Other threads")."""
    c = VirtualClock(epoch_ns=0)
    results: dict[str, object] = {}

    def elsewhere(key, fn) -> threading.Thread:
        def run() -> None:
            try:
                results[key] = fn()
            except BaseException as exc:
                results[key] = exc
        th = threading.Thread(target=run)
        th.start()
        return th

    th = elsewhere("free", lambda: c.sleep(0.001) or c.time_ns())
    th.join(5)
    assert results["free"] == 1 * MS  # before `use`, any thread may
    with clock.use(c):
        elsewhere("sleep", lambda: clock.sleep(0.5)).join(5)
        assert isinstance(results["sleep"], RuntimeError) and "not the run's" in str(
            results["sleep"])
        assert c.time_ns() == 1 * MS
        q, cond = ClockQueue(), clock.ClockCondition()
        t_q = elsewhere("queue", lambda: q.get(timeout=5))
        def cond_wait() -> bool:
            with cond:
                return cond.wait(5)
        t_c = elsewhere("cond", cond_wait)
        c.after(30 * MS, lambda: q.put("reply"))

        def notify() -> None:
            with cond:
                cond.notify_all()
        c.after(40 * MS, notify)
        time.sleep(0.05)
        assert c.time_ns() == 1 * MS and "queue" not in results  # the other thread waits
        c.sleep(0.05)  # the run's thread moves time: the reply and the notify come
        t_q.join(5)
        t_c.join(5)
        assert results["queue"] == "reply" and results["cond"] is True
        def step() -> int:  # a step thread: inside `watch` it is the run's
            with c.watch(None, None):
                c.sleep(0.01)
                return c.time_ns()
        elsewhere("step", step).join(5)
        assert results["step"] == 61 * MS


def test_a_late_event_runs_after_every_other_event_of_its_time() -> None:
    c = VirtualClock(epoch_ns=0)
    seen: list[str] = []
    c.at(5 * MS, lambda: seen.append("late"), late=True)
    c.at(5 * MS, lambda: (seen.append("a"), c.at(5 * MS, lambda: seen.append("b"))))
    c.at(4 * MS, lambda: seen.append("earlier"))
    c.at(6 * MS, lambda: seen.append("after"))
    c.sleep(0.01)
    assert seen == ["earlier", "a", "b", "late", "after"]


@pytest.mark.parametrize("virtual", [True, False])
def test_odd_timeouts_mean_the_same_on_both_clocks(virtual) -> None:
    """inf waits as None does (forever: an hour of bench time on a virtual clock, where it
    raised OverflowError); NaN is refused on both (it never returned on the wall clock);
    a negative ClockQueue timeout is refused as queue.Queue refuses it; a sleep of NaN or inf
    is refused on both (the wall clock raised OverflowError or slept not at all)."""
    import queue as _queue

    c = VirtualClock(epoch_ns=0) if virtual else clock.REAL
    with clock.use(c):
        if virtual:
            assert clock.wait_for(lambda: False, float("inf")) is False
            assert c.time_ns() == 3600 * S
            c.after(5 * MS, lambda: None)
            cond = clock.ClockCondition()
            c.after(10 * MS, lambda: (cond.acquire(), cond.notify_all(), cond.release()))
            with cond:
                assert cond.wait(float("inf")) is True
        with pytest.raises(ValueError, match="nan"):
            clock.wait_for(lambda: False, float("nan"))
        with pytest.raises(ValueError, match="nan"):
            clock.wait(threading.Event(), float("nan"))
        set_event = threading.Event()
        set_event.set()
        assert clock.wait(set_event, float("inf")) is True  # wall clock: OverflowError before
        for odd in (float("nan"), float("inf")):  # a sleep must end, on either clock
            with pytest.raises(ValueError, match="not a finite number"):
                clock.sleep(odd)
        t0 = c.time_ns() if virtual else None
        clock.sleep(-1.0)  # no sleep
        assert t0 is None or c.time_ns() == t0
        with pytest.raises(ValueError, match="non-negative"):
            ClockQueue().get(timeout=-1)
        with pytest.raises(_queue.Empty):
            ClockQueue().get(timeout=0)


@pytest.mark.parametrize("lock", [None, threading.Lock()], ids=["rlock", "plain lock"])
def test_a_clock_condition_waits_and_waits_for_in_bench_time(lock) -> None:
    """`wait_for` is bench time too (threading's own loops on wall seconds: 0.5 s of it ran
    20 h of bench time), and a plain `Lock` works (the notifying event takes it in the
    waiting thread: it deadlocked)."""
    c = VirtualClock(epoch_ns=0)
    cond = clock.ClockCondition(lock)
    box = {"v": 0}

    def bump() -> None:
        with cond:
            box["v"] += 1
            cond.notify_all()

    with clock.use(c):
        with cond:
            assert cond.wait_for(lambda: False, 0.5) is False
        assert c.time_ns() == 500 * MS
        c.after(20 * MS, bump)
        c.after(40 * MS, bump)
        with cond:
            assert cond.wait_for(lambda: box["v"] >= 2, 1.0) is True
        assert c.time_ns() == 540 * MS
        c.after(10 * MS, bump)
        with cond:
            assert cond.wait(1.0) is True
        assert c.time_ns() == 550 * MS
        with pytest.raises(RuntimeError, match="un-acquired"):
            cond.wait(0.1)


def test_an_event_stuck_in_another_thread_is_clock_hung_for_the_next_wait() -> None:
    """The safe state after a step hung inside an event: the main thread's wait says the
    clock is hung (not "a wait inside a clock event", which blamed the waiting code)."""
    c = VirtualClock(epoch_ns=0)
    release, inside = threading.Event(), threading.Event()

    def stuck() -> None:
        inside.set()
        release.wait(5)

    with clock.use(c):
        c.at(5 * MS, stuck)

        def step() -> None:
            with c.watch(None, None):
                c.sleep(0.01)
        th = threading.Thread(target=step)
        th.start()
        assert inside.wait(5)
        with pytest.raises(clock.ClockHung, match="stuck inside a clock event"):
            c.sleep(0.01)
        release.set()
        th.join(5)


def test_a_thread_that_ran_a_clock_and_ended_leaves_no_owner_behind() -> None:
    """Owners are threads, not idents: a later thread that gets the ended one's ident (Linux
    reuses them) is not the run's."""
    c = VirtualClock(epoch_ns=0)

    def run() -> None:
        with clock.use(c):
            c.sleep(0.1)

    first = threading.Thread(target=run)
    first.start()
    first.join(5)
    seen: dict[str, object] = {}

    def later() -> None:
        seen["ident"] = threading.get_ident()
        try:
            c.sleep(0.1)
        except RuntimeError as exc:
            seen["error"] = exc

    th = threading.Thread(target=later)
    th.start()
    th.join(5)
    assert "not the run's" in str(seen.get("error")) and c.time_ns() == 100 * MS


def test_another_threads_batch_never_holds_the_runs_settling() -> None:
    """`batch()` in a thread of a test's own is no batch: it held every send of the run's
    until its end, then dropped their settling (that thread may not run the clock)."""
    c = VirtualClock(epoch_ns=0)
    settled: list[int] = []
    inside, leave = threading.Event(), threading.Event()

    def other() -> None:
        with clock.batch():
            inside.set()
            leave.wait(5)

    with clock.use(c):
        th = threading.Thread(target=other)
        th.start()
        assert inside.wait(5)
        c.after(3 * MS, lambda: settled.append(c.time_ns()))
        c.settle(lambda: not settled)  # the run's send settling: not held for the batch
        assert settled == [3 * MS]
        leave.set()
        th.join(5)


def test_another_threads_wait_while_the_run_is_inside_an_event_is_not_the_runs() -> None:
    """An outside probe: a test's own thread that waited while the run's thread was inside
    one of its events got `ClockHung` ("stuck inside a clock event"), though nothing hung."""
    c = VirtualClock(epoch_ns=0)
    inside, proceed = threading.Event(), threading.Event()
    seen: dict[str, BaseException] = {}

    def event() -> None:
        inside.set()
        proceed.wait(5)

    def other() -> None:
        inside.wait(5)
        try:
            c.sleep(0.1)
        except BaseException as exc:  # which one is the point
            seen["error"] = exc
        finally:
            proceed.set()

    th = threading.Thread(target=other)
    with clock.use(c):
        c.at(10 * MS, event)
        th.start()
        c.sleep(0.05)
    th.join(5)
    err = seen.get("error")
    assert type(err) is RuntimeError and "not the run's" in str(err), repr(err)
    assert c.time_ns() == 50 * MS
