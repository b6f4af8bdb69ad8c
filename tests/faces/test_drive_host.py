"""The real-time host wakes on the model's grid and at the model's next timer (host.py)."""

from __future__ import annotations

import time

from hil.model.drive import Drive
from hil.model.events import DoChanged
from hil.model.timebase import Scheduler
from hil.units import MS, US
from hil.virtual.host import DriveHost


class _Clocked:
    """A drive stand-in: only the scheduler the host reads."""

    def __init__(self) -> None:
        self.sched = Scheduler()
        self.now = 0


def _host_at(model_ns: int, **kw) -> DriveHost:
    host = DriveHost(_Clocked(), **kw)
    host.model_now = lambda: model_ns  # type: ignore[method-assign]
    return host


def test_the_next_wake_is_the_next_grid_point_without_timers() -> None:
    assert _host_at(2_300 * US)._next_wake(MS) == 3 * MS


def test_a_timer_before_the_next_grid_point_wakes_the_host_then() -> None:
    host = _host_at(2_300 * US)
    host.drive.sched.at(2_650 * US, lambda: None)
    assert host._next_wake(MS) == 2_650 * US


def test_later_and_cancelled_timers_and_the_plain_ticker_keep_the_grid() -> None:
    host = _host_at(2_300 * US)
    host.drive.sched.at(3_400 * US, lambda: None)  # after the grid point
    early = host.drive.sched.at(2_500 * US, lambda: None)
    early.cancel()
    assert host._next_wake(MS) == 3 * MS
    plain = _host_at(2_300 * US, timer_wakeups=False)
    plain.drive.sched.at(2_500 * US, lambda: None)
    assert plain._next_wake(MS) == 3 * MS


def test_a_timer_armed_during_the_tick_and_already_due_means_at_once() -> None:
    """The tick advanced the model to 2.3 ms; the host decides at 2.4 ms; a timer at 2.35 ms
    has not fired: the host ticks again at once instead of sleeping to the grid."""
    host = _host_at(2_400 * US)
    host.drive.now = 2_300 * US
    host.drive.sched.at(2_350 * US, lambda: None)
    assert host._next_wake(MS) == 2_350 * US  # <= model_now: no sleep


def test_a_timer_armed_at_the_model_time_itself_means_at_once() -> None:
    """`Scheduler.at` moves a past deadline up to now: a timer at drive.now is due too."""
    host = _host_at(2_400 * US)
    host.drive.now = 2_300 * US
    host.drive.sched.now = 2_300 * US
    host.drive.sched.at(1_000 * US, lambda: None)  # in the past: due at 2.3 ms
    assert host._next_wake(MS) == 2_300 * US


def test_a_timer_a_face_arms_wakes_the_sleeping_ticker() -> None:
    import threading

    host = _host_at(2_300 * US)
    host._wake = threading.Event()
    assert host._next_wake(MS) == 3 * MS  # planned: the grid
    host.drive.sched.at(2_800 * US, lambda: None)  # armed from a face's thread
    with host.lock:
        host.poke()
    assert host._wake.is_set()
    host._wake.clear()
    host.drive.sched.at(2_900 * US, lambda: None)  # not earlier than the new plan
    with host.lock:
        host.poke()
    assert not host._wake.is_set()


def test_a_filtered_di_edge_reaches_a_subscriber_at_its_model_time() -> None:
    """On a real host: SON through the 3 ms P2.009 filter; DO2 = SON (table 8.2) changes
    at the filter's model time, and the host delivers it well before the next grid point
    would have (the measure of how well is benchmarks/bench_edges.py)."""
    drive = Drive(inputs={8: True}, params={"P2.009": 3, "P2.019": 0x0102})
    host = DriveHost(drive)
    seen: list[tuple[int, int]] = []
    drive.subscribe(lambda ev: isinstance(ev, DoChanged) and seen.append(
        (ev.t, host.model_now())))
    host.start()
    try:
        time.sleep(0.0123)
        t_set = host.call(lambda: (drive.set_di(1, True), drive.now)[1])
        deadline = time.monotonic() + 2.0
        while not seen and time.monotonic() < deadline:
            time.sleep(0.001)
    finally:
        host.stop()
    assert seen, "no DO edge"
    t_edge, t_seen = seen[0]
    assert t_edge >= t_set + 3 * MS  # the filter's time, on the model's clock
    assert t_seen >= t_edge  # never early


def test_hil_rt_priority_is_read_and_checked(monkeypatch) -> None:
    from hil.realtime import env_priority

    for raw, want in (("", None), ("10", 10), ("99", 99), ("0", None), ("100", None),
                      ("fifo", None)):
        monkeypatch.setenv("HIL_RT_PRIORITY", raw)
        assert env_priority() == want, raw
    monkeypatch.setenv("HIL_RT_PRIORITY", "7")
    assert DriveHost(_Clocked()).rt_priority == 7
    assert DriveHost(_Clocked(), rt_priority=3).rt_priority == 3

