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



# -- the virtual-time host (ClockHost): the same wake-ups as clock events ---------------------


def _clock_host(period_ms: float = 1.0):
    from hil.clock import VirtualClock
    from hil.virtual.host import ClockHost

    clk = VirtualClock(epoch_ns=0)
    host = ClockHost(_Clocked(), clk, period_s=period_ms / 1000)
    host.drive.advance_to = lambda t: _run_to(host.drive, t)  # type: ignore[attr-defined]
    ticks: list[int] = []
    host.add_tick(ticks.append)
    return clk, host, ticks


def _run_to(drive: _Clocked, t: int) -> None:
    drive.sched.advance_to(t)
    drive.now = drive.sched.now


def test_the_virtual_host_wakes_at_a_model_timer_between_its_ticks() -> None:
    """A brake delay, a DI filter: the faces saw its edge at the next 1 ms tick in virtual
    time, while the real-time host wakes at the timer (an outside review)."""
    clk, host, ticks = _clock_host()
    fired: list[int] = []
    host.drive.sched.at(2_300 * US, lambda: fired.append(host.drive.sched.now))
    host.start()
    clk.run_until(3_500 * US)
    assert fired == [2_300 * US]
    assert ticks == [0, MS, 2 * MS, 2_300 * US, 3 * MS]  # the grid keeps its phase


def test_a_timer_a_face_arms_replans_the_virtual_host() -> None:
    """A face that arms a timer under the host's lock (a frame that starts a delay) wakes the
    host at it; one armed for the very instant fires at once."""
    clk, host, ticks = _clock_host()
    host.start()
    clk.run_until(1_100 * US)
    fired: list[int] = []
    with host.synced:
        host.drive.sched.at(1_700 * US, lambda: fired.append(host.drive.sched.now))
    clk.run_until(1_200 * US)
    with host.synced:
        host.drive.sched.at(1_200 * US, lambda: fired.append(host.drive.sched.now))
    clk.run_until(2_100 * US)
    assert fired == [1_200 * US, 1_700 * US]
    assert ticks == [0, MS, 1_200 * US, 1_700 * US, 2 * MS]


def test_a_brake_edge_reaches_the_virtual_bench_lines_at_its_model_time(tmp_path) -> None:
    """servo_on_off_brake in virtual time: each BRKR edge is on the DI/DO line (the log time
    of /dio/drive1/DO6) at the model's own time of the change, not at the next 1 ms tick."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import find_plans, load_plan
    from hil.plan.runner import run_plan
    from hil.record.reader import Recording

    res = run_plan(load_plan(find_plans(["servo_on_off_brake"])[0]), load_bench(None), tmp_path,
                   reports=False)
    assert res.passed
    rec = Recording.open(res.recording)
    edges = [(lt, pt) for _t, lt, pt, _m in rec.messages("/dio/drive1/DO6")]
    assert len(edges) >= 3  # the level at start, BRKR on, BRKR off
    off_grid = [pt for _lt, pt in edges if (pt - edges[0][1]) % MS]
    assert off_grid  # edges between two host ticks: the case this is about
    assert all(lt == pt for lt, pt in edges), edges  # was up to 1 ms later than the model


def test_the_ground_truth_samples_on_the_hosts_grid_even_when_it_starts_between_ticks() -> None:
    """A ground truth that starts at a tick the host made for a timer (between two grid
    points) still samples on the grid, where the host wakes anyway (off it, each sample would
    cost a wake-up of its own), and each sample is on the record at its model time."""
    from hil.clock import VirtualClock
    from hil.virtual.host import ClockHost
    from hil.virtual.world import GroundTruth

    class Rec:
        def __init__(self) -> None:
            self.samples: list[tuple[int, int]] = []  # (model t, clock time when recorded)

        def drive_state(self, _name, state, source_t=None) -> None:
            if state.get("periodic"):
                self.samples.append((state["t"], clk.time_ns()))

        def drive_params(self, *a, **k) -> None: ...

        def drive_event(self, *a, **k) -> None: ...

    clk = VirtualClock(epoch_ns=0)
    drive = Drive()
    host = ClockHost(drive, clk)
    host.start()
    drive.sched.at(1_300 * US, lambda: None)  # a timer: the host ticks at 1.3 ms for it
    with host.lock:
        host.poke()
    clk.run_until(1_300 * US)
    rec = Rec()
    truth = GroundTruth("d", drive, host, rec, period_ms=1)  # its first tick: 1.3 ms
    clk.run_until(4_500 * US)
    truth.close()
    assert [t for t, _ in rec.samples] == [2 * MS, 3 * MS, 4 * MS]
    assert all(t == logged for t, logged in rec.samples), rec.samples  # at its model time


class _Failing(_Clocked):
    """A drive whose model raises from 2.5 ms on (a model bug: the bench reports it dead)."""

    def advance_to(self, t: int) -> None:
        if t > 2_500 * US:
            raise ValueError("model bug")
        self.sched.advance_to(t)
        self.now = self.sched.now


def test_a_failed_model_does_not_hold_virtual_time_at_one_instant(caplog) -> None:
    """A timer the failed model can no longer fire is due "at once" at every tick: the host
    re-planned at the same instant for ever and bench time stood still (an outside review).
    It tries once per instant, then keeps its grid."""
    from hil.clock import VirtualClock
    from hil.virtual.host import ClockHost

    clk = VirtualClock(epoch_ns=0)
    host = ClockHost(_Failing(), clk)
    host.drive.sched.at(3 * MS, lambda: None)  # a brake delay, say
    ticks: list[int] = []
    host.add_tick(ticks.append)
    host.start()
    clk.run_until(10 * MS)
    assert clk.time_ns() == 10 * MS
    assert host.model_failed is not None
    assert len(ticks) <= 3  # the faces' ticks stop with the model; time went on


def test_another_threads_timer_replans_the_virtual_host_once() -> None:
    """A face in a test's own thread (a DI/DO set) arms a timer and pokes the host while the
    run's thread is planning its next tick: the poke started a second chain of ticks beside
    the planned one, so ticks came twice per period (an outside review). The host plans
    under its lock, and another thread's poke is handed to the run's thread."""
    import threading

    from hil import clock
    from hil.clock import VirtualClock
    from hil.virtual.host import ClockHost

    clk = VirtualClock(epoch_ns=0)
    host = ClockHost(_Clocked(), clk)
    host.drive.advance_to = lambda t: _run_to(host.drive, t)  # type: ignore[attr-defined]
    ticks: list[int] = []
    host.add_tick(ticks.append)
    fired: list[int] = []
    other: list[threading.Thread] = []
    real_at = clk.at

    def at(t, fn, **kw):  # the other thread runs while the tick at 3 ms plans the next one
        ev = real_at(t, fn, **kw)
        if not other and clk.time_ns() == 3 * MS and getattr(fn, "__name__", "") == "_tick":
            th = threading.Thread(target=lambda: host.call(lambda: host.drive.sched.at(
                3_400 * US, lambda: fired.append(host.drive.sched.now))))
            other.append(th)
            th.start()
            th.join(0.3)  # it finishes here unless the host's lock holds it back;
            real_at(3_200 * US, lambda: th.join(5))  # then it does, outside the host's lock
        return ev

    with clock.use(clk):
        host.start()
        clk.at = at  # type: ignore[method-assign]
        clk.run_until(7_500 * US)
    other[0].join(5)
    assert fired == [3_400 * US]
    assert len(ticks) == len(set(ticks)), ticks  # one tick per instant
    assert [t for t in ticks if t >= 3 * MS] == [3 * MS, 3_400 * US, 4 * MS, 5 * MS, 6 * MS,
                                                  7 * MS]
