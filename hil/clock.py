"""The harness's clock: the wall clock, or the virtual bench's own (docs/clock.md).

Every wait of the harness goes through here, never through `time.sleep`:

    from hil import clock
    clock.time_ns(); clock.monotonic_ns(); clock.monotonic()
    clock.sleep(0.01)                      # a pause of bench time
    clock.wait(event, 0.5) -> bool         # Event.wait on the bench's clock
    clock.wait_for(pred, 0.5) -> bool      # until pred() or timeout

`current()` is `REAL` (the `time` module) unless a run installed a `VirtualClock` with
`use(clock)`. A `VirtualClock` is one discrete-event scheduler: time moves only when the thread
that runs the plan waits, and then it fires every event due (the model's host ticks, each frame's
delivery after its wire time, each cyclic producer) in time order, one at a time. So a run on it
is deterministic and as fast as the host computes it. Only one thread may wait on it at a time
(the plan's step thread, or the runner's main thread between steps); the events never wait.
"""

from __future__ import annotations

import collections
import contextlib
import ctypes
import heapq
import itertools
import queue
import sys
import threading
import time
from collections.abc import Callable, Iterator
from typing import Any

from hil.units import S

# Virtual recordings start here: 2000-01-01T00:00:00Z, so two runs carry the same log times.
VIRTUAL_EPOCH_NS = 946_684_800 * S
CLOCKS = ("virtual", "real")
# Added to a late event's order: it runs after the other events of its time (`at`)
LATE = 1 << 62
# A send settles its bus at most this long (a bus carrying more than its bit rate never idles)
SETTLE_LIMIT_NS = 100_000_000


# How long (wall s) a thread waits for the virtual clock while another holds it. An event
# ends in microseconds and a cancelled wait at its next event, so only a step hung inside an
# event holds it this long; then the clock is "hung" and every other thread fails at once
# (the safe state records it, the recording is closed) instead of blocking for ever.
HELD_WAIT_S = 10.0


class ClockHung(RuntimeError):
    """The virtual clock is held by a thread that does not let go (a step hung inside a clock
    event): nothing else can run on it."""


class EventHung(BaseException):
    """Raised inside a clock event that held off an interrupt for HELD_WAIT_S of wall time
    (it never ended); the interrupt itself is raised from it."""


def async_raise(ident: int, exc: type[BaseException] | None) -> None:
    """Raise `exc` in thread `ident` at its next Python instruction (None: withdraw one not
    yet raised). A thread in a C-level wait (a lock, an Event) gets it once it runs Python
    again. For the watchdogs that stop a thread hung inside a clock event."""
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(ident),
                                               None if exc is None else ctypes.py_object(exc))
    if exc is None:
        _settle_async_flag()


class _Settle(BaseException):
    """Taken by `_settle_async_flag`'s own thread, and by nothing else."""


def _settle_async_flag() -> None:
    """Clear the interpreter's "an asynchronous exception is pending" flag that a withdrawal
    leaves set. Before Python 3.13, `PyThreadState_SetAsyncExc(id, NULL)` sets it and only a
    thread that takes an exception clears it: until then every thread's eval loop stops at
    each call and loop to look for one (8 % slower here), and a call made under a profiler
    (`cProfile`, `sys.setprofile`) loops for ever at its first instruction. A thread of ours
    takes one, which clears it."""
    if sys.version_info >= (3, 13):  # the flag is per thread there, cleared as it is read
        return
    ready = threading.Event()

    def take() -> None:
        try:
            ready.set()
            end = time.monotonic() + 5.0  # never for ever (its caller cut before the raise)
            while time.monotonic() < end:
                time.sleep(0.001)  # the exception lands as the loop runs Python again
        except _Settle:
            pass

    sink = threading.Thread(target=take, name="hil-async-settle", daemon=True)
    try:
        sink.start()
    except RuntimeError:  # interpreter shutdown (3.12): no thread; nothing runs on anyway
        return
    ready.wait()
    ctypes.pythonapi.PyThreadState_SetAsyncExc(ctypes.c_ulong(sink.ident),
                                               ctypes.py_object(_Settle))
    sink.join(1.0)


class Cancelled(Exception):
    """A wait ended because its step was cancelled (step timeout, Ctrl-C)."""


class VirtualTimeout(BaseException):
    """A wait would pass the step's deadline in virtual time. A BaseException, so that no
    step code's `except Exception` takes the runner's step timeout for its own failure."""


def _timeout_s(timeout_s: float | None) -> float | None:
    """A wait's timeout: None or +inf is "forever" (None); NaN is refused (a wait that
    never ends on the wall clock, an error on a virtual one: neither is meant)."""
    if timeout_s is None:
        return None
    if timeout_s != timeout_s:
        raise ValueError("timeout nan: not a number of seconds")
    return None if timeout_s == float("inf") else timeout_s


def _sleep_s(seconds: float) -> float:
    """A sleep's length: NaN and +inf are refused on both clocks (a sleep must end); a
    negative one is no sleep."""
    if seconds != seconds or seconds == float("inf"):
        raise ValueError(f"sleep {seconds}: not a finite number of seconds")
    return max(0.0, seconds)


class RealClock:
    """The wall clock (`time`): what real benches, zenoh and `hil drive` run on."""

    name = "real"
    virtual = False

    def time_ns(self) -> int:
        return time.time_ns()

    def monotonic_ns(self) -> int:
        return time.monotonic_ns()

    def sleep(self, seconds: float) -> None:
        if (seconds := _sleep_s(seconds)) > 0:
            time.sleep(seconds)

    def wait_for(self, pred: Callable[[], Any], timeout_s: float | None,
                 poll_s: float = 0.002) -> bool:
        timeout_s = _timeout_s(timeout_s)
        end = None if timeout_s is None else time.monotonic() + timeout_s
        while True:
            if pred():
                return True
            if end is not None and time.monotonic() >= end:
                return bool(pred())
            time.sleep(poll_s if end is None else max(0.0, min(poll_s, end - time.monotonic())))


class Event:
    """A scheduled call on a `VirtualClock` (`cancel()` it to drop it)."""

    __slots__ = ("cancelled", "fn", "seq", "t")

    def __init__(self, t: int, seq: int, fn: Callable[[], Any]) -> None:
        self.t, self.seq, self.fn, self.cancelled = t, seq, fn, False

    def __lt__(self, other: Event) -> bool:
        t, u = self.t, other.t
        return t < u or (t == u and self.seq < other.seq)

    def cancel(self) -> None:
        self.cancelled = True


class VirtualClock:
    """Discrete-event time for the virtual bench (see the module docstring).

    Times are ns on one axis: `time_ns()` == `monotonic_ns()` == `epoch_ns` + elapsed.
    `at(t, fn)` / `after(dt, fn)` schedule events; waits fire them in (time, order) order.
    `media` holds the in-process buses and lines of this run by name (hil.transport.sim).
    """

    name = "virtual"
    virtual = True

    def __init__(self, epoch_ns: int = VIRTUAL_EPOCH_NS) -> None:
        self.epoch_ns = epoch_ns
        self._now = epoch_ns
        self._heap: list[Event] = []
        self._seq = itertools.count()
        self._lock = threading.RLock()
        self.hung = False  # a thread held the clock past HELD_WAIT_S: see ClockHung
        self._guard = _Held(self)  # `with self._guard:` the lock, waited for at most that
        self._running = 0  # > 0 while an event runs (events must not wait)
        # a Ctrl-C / SIGTERM that came while an event ran, raised once it has ended (see
        # `defer_interrupt`)
        self._interrupt: BaseException | None = None
        self._loops = 0  # > 0 while `run_until` fires events (signals are deferred then)
        self._watch: dict[int, tuple[threading.Event | None, int | None]] = {}
        self.media: dict[str, Any] = {}
        self.hold = 0  # > 0 inside `batch()`: settling waits for its end
        self.held: list[Callable[[], bool]] = []
        # threads that ever installed it (`use`): see `may_wait`. Kept after their `use`
        # ends, so that a thread of a test's own left running never runs a finished run on
        self._owners: set[threading.Thread] = set()  # (threads, not idents: those are reused)
        self._runner = 0  # the thread running the events (`in_event` is that thread's)
        self._failure: BaseException | None = None  # an event's error for the run (`fail`)
        # events other threads schedule (`at`): they never take the lock, which the run's
        # thread holds while it waits; moved to the heap at the top of each pass
        self._inbox: collections.deque[Event] = collections.deque()

    # -- reading -------------------------------------------------------------------------
    def time_ns(self) -> int:
        return self._now

    monotonic_ns = time_ns

    @property
    def elapsed_ns(self) -> int:
        return self._now - self.epoch_ns

    @property
    def in_event(self) -> bool:
        """True in the thread running the events while one runs (a wait there would
        reorder time); False in every other thread."""
        return self._running > 0 and self._runner == threading.get_ident()

    def may_wait(self) -> bool:
        """Whether this thread may move bench time: the run's own threads, that is one that
        installed the clock (`use`, also after its block ended) and a step thread inside
        `watch`; any thread while none ever installed it. Another thread (a python-can
        `Notifier` a test started, a timer) waiting on it would fire the run's events from
        there, at wall-clock moments."""
        owners = self._owners
        if not owners:
            return True
        # a step thread (in `watch`) first: the cheap test, and the one most waits pass
        return threading.get_ident() in self._watch or threading.current_thread() in owners

    # -- scheduling ----------------------------------------------------------------------
    def at(self, t: int, fn: Callable[[], Any], *, late: bool = False) -> Event:
        """Run `fn()` at clock time `t` (never before now). `late`: after every event that
        is not late at the same time, also those scheduled later (a CAN bus starts its next
        frame once every node that has one at that instant has queued it: arbitration)."""
        ev = Event(max(int(t), self._now), next(self._seq) + (LATE if late else 0), fn)
        if self._running and self._runner == threading.get_ident():
            heapq.heappush(self._heap, ev)  # from an event: this thread holds the lock
            return ev
        if not self.may_wait():  # another thread: handed over, never waiting for the lock
            self._inbox.append(ev)
            return ev
        with self._guard:
            heapq.heappush(self._heap, ev)
            return ev

    def _take_inbox(self) -> None:
        """Other threads' events onto the heap (under the lock), none before now."""
        inbox, heap, now = self._inbox, self._heap, self._now
        while inbox:
            ev = inbox.popleft()
            ev.t = max(ev.t, now)
            heapq.heappush(heap, ev)

    def after(self, dt: int, fn: Callable[[], Any]) -> Event:
        return self.at(self._now + int(dt), fn)

    def next_time(self) -> int | None:
        with self._guard:
            if self._inbox:
                self._take_inbox()
            heap = self._heap
            while heap and heap[0].cancelled:
                heapq.heappop(heap)
            return heap[0].t if heap else None

    # -- waiting -------------------------------------------------------------------------
    @contextlib.contextmanager
    def watch(self, cancel: threading.Event | None, deadline_ns: int | None) -> Iterator[None]:
        """While in this block, this thread's waits raise `Cancelled` once `cancel` is set and
        `VirtualTimeout` rather than pass `deadline_ns` (the step timeout, in clock time)."""
        key = threading.get_ident()
        old = self._watch.get(key)
        self._watch[key] = (cancel, deadline_ns)
        try:
            yield
        finally:
            if old is None:
                self._watch.pop(key, None)
            else:
                self._watch[key] = old

    def run_until(self, t: int, pred: Callable[[], Any] | None = None, *,
                  watched: bool = True) -> bool:
        """Fire the events due up to `t` in order, stopping early once `pred()` holds;
        returns whether it holds (True without `pred`). Time ends at `t` unless stopped.
        `watched=False`: no cancel or deadline (frames already on the wire still arrive)."""
        if self.hung:
            raise ClockHung("the virtual clock is held by a step hung inside a clock event")
        if not self.may_wait():  # first: the run's own events running now hang nothing
            raise RuntimeError(
                f"virtual clock: thread {threading.current_thread().name!r} is not the run's: "
                "bench time moves only when the plan step or the hil_session test waits "
                "(docs/clock.md, \"Other threads\")")
        if self._running:
            if self._runner != threading.get_ident():  # a step hung inside an event
                raise ClockHung("the virtual clock is held by another thread stuck inside a "
                                "clock event (a step hung there)")
            raise RuntimeError("virtual clock: a wait inside a clock event (it would reorder "
                               "time); events must only schedule")
        cancel, deadline = (self._watch.get(threading.get_ident(), (None, None)) if watched
                            else (None, None))
        with self._guard:
            return self._pass(t, pred, cancel, deadline, watched)

    def _pass(self, t: int, pred: Callable[[], Any] | None, cancel: Any,
              deadline: int | None, watched: bool) -> bool:
        """`_run_events` with signals deferred to the top of a pass (under the lock)."""
        self._loops += 1  # a signal now is deferred to the top of a pass (defer_interrupt)
        try:
            return self._run_events(t, pred, cancel, deadline, watched)
        except BaseException as exc:
            pending, self._interrupt = self._interrupt, None
            if pending is not None and pending is not exc:
                raise pending from exc  # the stop the user asked for, not a later error
            raise
        finally:
            self._loops -= 1

    def _run_events(self, t: int, pred: Callable[[], Any] | None, cancel: Any,
                    deadline: int | None, watched: bool = True) -> bool:
        heap = self._heap
        self._runner = threading.get_ident()
        while True:
            if self._interrupt is not None:  # taken between two events, never inside
                exc, self._interrupt = self._interrupt, None
                raise exc
            if watched and self._failure is not None:  # the run's wait, not a send's settle
                exc, self._failure = self._failure, None
                raise exc
            if self._inbox:
                self._take_inbox()
            if pred is not None and pred():
                return True
            if cancel is not None and cancel.is_set():
                raise Cancelled()
            while heap and heap[0].cancelled:
                heapq.heappop(heap)
            nxt = heap[0].t if heap else None
            if deadline is not None and min(t, nxt if nxt is not None else t) > deadline:
                self._now = max(self._now, deadline)  # the wait would pass the deadline
                raise VirtualTimeout(f"step deadline at {self.elapsed_ns / S:.3f} s of "
                                     "virtual time")
            if nxt is None or nxt > t:
                self._now = max(self._now, t)
                return True if pred is None else bool(pred())
            ev = heapq.heappop(heap)
            self._now = max(self._now, ev.t)
            self._running += 1
            try:
                ev.fn()
            finally:
                self._running -= 1

    def fail(self, exc: BaseException) -> None:
        """An event's error, raised at the run's next wait (not inside the settle of a send,
        whose own frame went out: the sender would take it for its own failure)."""
        if self._failure is None:
            self._failure = exc

    def defer_interrupt(self, exc: BaseException) -> bool:
        """A signal handler's exception while an event runs: raised in the thread running
        the events once that event has ended, not inside it (an event cut in the middle,
        say a host tick before it scheduled the next, would stop the model, and the safe
        state after the interrupt could not run). False outside an event: raise it now."""
        if not (self._running or self._loops):
            return False
        if not isinstance(self._interrupt, KeyboardInterrupt):  # a Ctrl-C already waiting
            self._interrupt = exc  # stays: it stops the run, whatever came after it
            threading.Thread(target=self._cut_hung_event, args=(self._interrupt,),
                             name="hil-interrupt-watchdog", daemon=True).start()
        return True

    def _cut_hung_event(self, exc: BaseException) -> None:
        """An interrupt deferred for HELD_WAIT_S of wall time to the end of an event that
        never ends (a model event that loops; helper-134: pytest-timeout and Ctrl-C waited for
        ever in a `hil_session` test): the event is cut after all. The clock is marked hung
        and EventHung raised in the thread running it; `_pass` raises the deferred interrupt
        from it. An event blocked in a C-level wait gets it when it runs Python again."""
        end = time.monotonic() + HELD_WAIT_S
        while time.monotonic() < end:
            if self._interrupt is not exc:  # raised (or dropped) in time
                return
            time.sleep(0.05)
        if self._interrupt is exc and self._running:
            runner = self._runner
            async_raise(runner, EventHung)
            if self._interrupt is exc and self._running:
                self.hung = True  # what the event left half done is not to be run on
            else:  # it ended just now and took the interrupt: withdraw it (helper-136)
                async_raise(runner, None)

    def drop_interrupt(self) -> BaseException | None:
        """Forget a deferred interrupt not yet raised (the safe state after it must run);
        returns it (None when there was none)."""
        exc, self._interrupt = self._interrupt, None
        return exc

    def sleep(self, seconds: float) -> None:
        self.run_until(self._now + round(_sleep_s(seconds) * S))

    def wait_for(self, pred: Callable[[], Any], timeout_s: float | None,
                 poll_s: float = 0.0) -> bool:
        timeout_s = _timeout_s(timeout_s)
        if timeout_s is None:
            end = self._now + 3600 * S  # "forever" is an hour of bench time
        else:
            end = self._now + max(0, round(timeout_s * S))
        return self.run_until(end, pred)

    def settle(self, busy: Callable[[], bool]) -> None:
        """Fire events while `busy()` (e.g. frames in flight); no-op inside an event."""
        if self._running or not self.may_wait():  # another thread's send: the run's
            return  # thread delivers it when it next waits
        if self.hold:
            self.held.append(busy)
            return
        end = self._now + SETTLE_LIMIT_NS  # an overloaded bus is never idle: give up then
        heap = self._heap
        with self._guard:  # not cancellable: what is on the wire arrives (one SDO at a time)
            while busy():  # between instants, never between two events of one instant
                if self._inbox:
                    self._take_inbox()
                while heap and heap[0].cancelled:
                    heapq.heappop(heap)
                if not heap or heap[0].t > end:
                    return
                if self.hung:
                    raise ClockHung("the virtual clock is held by a step hung inside a clock "
                                    "event")
                self._pass(heap[0].t, None, None, None, False)  # that instant's events


class _Held:
    """The clock's lock as a context, waited for at most HELD_WAIT_S (then ClockHung); it
    keeps no state of its own, so one serves every (nested) use."""

    __slots__ = ("clk",)

    def __init__(self, clk: VirtualClock) -> None:
        self.clk = clk

    def __enter__(self) -> None:
        clk = self.clk
        if clk._lock.acquire(timeout=0 if clk.hung else HELD_WAIT_S):
            return
        clk.hung = True
        raise ClockHung(f"the virtual clock has been held for more than {HELD_WAIT_S:g} s of "
                        "wall time by another thread (a step hung inside a clock event)")

    def __exit__(self, *exc: object) -> None:
        self.clk._lock.release()


REAL = RealClock()
_current: RealClock | VirtualClock = REAL
# how often each clock was installed in this process (`use`): the test suite's rerun policy
# reads it (a test that ran only in virtual time is deterministic: never rerun)
installs: collections.Counter[str] = collections.Counter()


def current() -> RealClock | VirtualClock:
    """The clock of the run in progress (REAL outside a virtual-time run)."""
    return _current


@contextlib.contextmanager
def use(clk: RealClock | VirtualClock) -> Iterator[RealClock | VirtualClock]:
    """Install `clk` as the current clock for the block (one run at a time per process)."""
    global _current
    old, _current = _current, clk
    installs[clk.name] += 1
    if isinstance(clk, VirtualClock):
        clk._owners.add(threading.current_thread())  # for good: see `may_wait`
    try:
        yield clk
    finally:
        _current = old


def time_ns() -> int:
    return _current.time_ns()


def monotonic_ns() -> int:
    return _current.monotonic_ns()


def monotonic() -> float:
    return _current.monotonic_ns() / S


def sleep(seconds: float) -> None:
    _current.sleep(seconds)


def wait(event: threading.Event, timeout_s: float | None) -> bool:
    """`event.wait(timeout_s)` on the current clock."""
    if not _current.virtual:
        return event.wait(_timeout_s(timeout_s))  # inf: forever, NaN refused (as virtual)
    return _current.wait_for(event.is_set, timeout_s)


def wait_for(pred: Callable[[], Any], timeout_s: float | None, poll_s: float = 0.002) -> bool:
    """Until `pred()` is truthy (True) or `timeout_s` of the current clock passed (False)."""
    return _current.wait_for(pred, timeout_s, poll_s)


def is_virtual() -> bool:
    return _current.virtual


def call_later(seconds: float, fn: Callable[..., Any], *args: Any) -> Any:
    """Call `fn(*args)` after `seconds` of the current clock; returns a handle with
    `cancel()` (a daemon `threading.Timer` on the wall clock, an event on a virtual one)."""
    if isinstance(_current, VirtualClock):
        return _current.after(max(0, round(seconds * S)), lambda: fn(*args))
    timer = threading.Timer(seconds, fn, args)
    timer.daemon = True
    timer.start()
    return timer


def refuse_in_event(what: str) -> None:
    """Raise where a wait would run inside one of the run's clock events (no level or frame
    can change while it waits, and it would hold the clock): as `VirtualClock.run_until`."""
    clk = _current
    if isinstance(clk, VirtualClock) and clk.in_event:
        raise RuntimeError(f"virtual clock: {what} inside a clock event (it would reorder "
                           "time); events must only schedule")


def waits_on_clock() -> bool:
    """Whether a wait in this thread runs the virtual clock (the run's thread, outside an
    event); otherwise a wait here is in wall time (another thread, or the wall clock)."""
    return _waits_here() is not None


def _waits_here() -> VirtualClock | None:
    """The current clock if a wait in this thread runs it: virtual, this thread the run's
    (`may_wait`) and not inside an event. Else None: the library's own wall-time wait."""
    clk = _current
    if isinstance(clk, VirtualClock) and not clk.in_event and clk.may_wait():
        return clk
    return None


class ClockQueue(queue.Queue):
    """A `queue.Queue` whose blocking `get` waits on the current clock (for a library's reply
    queue, e.g. canopen's SDO client: its timeout then passes in bench time)."""

    def get(self, block: bool = True, timeout: float | None = None) -> Any:
        clk = _waits_here()
        if block and clk is not None:
            if timeout is not None and timeout < 0:
                raise ValueError("'timeout' must be a non-negative number")  # as queue.Queue
            clk.wait_for(lambda: self.qsize() > 0, timeout)
            return super().get(False)
        return super().get(block, timeout)  # another thread: the run's thread fills it


class ClockCondition(threading.Condition):
    """A `threading.Condition` whose `wait` and `wait_for` run on the current clock (for a
    library's condition, e.g. canopen's heartbeat and PDO waits). On a virtual clock the
    waiting thread, one of the run's, releases the lock and runs the events itself, so a
    notify comes from inside one of them, in this thread; `wait` returns True once a notify
    came, else False after `timeout` of bench time. Another thread, and the wall clock, get
    `threading.Condition`'s own waits."""

    def __init__(self, lock: Any = None) -> None:
        super().__init__(lock)
        self._notified = 0

    def notify(self, n: int = 1) -> None:
        self._notified += 1
        super().notify(n)

    def notify_all(self) -> None:
        self._notified += 1
        super().notify_all()

    def wait(self, timeout: float | None = None) -> bool:
        clk = _waits_here()
        if clk is not None:
            seen = self._notified
            return self._on_clock(clk, lambda: self._notified != seen, timeout)
        return super().wait(timeout)

    def wait_for(self, predicate: Callable[[], Any], timeout: float | None = None) -> Any:
        """`threading.Condition.wait_for` on the current clock (threading's own loops on
        wall seconds): `predicate`'s last value."""
        clk = _waits_here()
        if clk is not None:
            result = predicate()
            if not result:  # as threading's: no wait (nor lock check) when it holds already
                self._on_clock(clk, predicate, timeout)
                result = predicate()
            return result
        return super().wait_for(predicate, timeout)

    def _on_clock(self, clk: VirtualClock, pred: Callable[[], Any],
                  timeout: float | None) -> bool:
        """Run the clock with the lock released, as `threading.Condition.wait` releases it:
        the event that notifies takes it in this same thread (so a plain `Lock` works too)."""
        if not self._is_owned():
            raise RuntimeError("cannot wait on un-acquired lock")
        saved = self._release_save()  # type: ignore[attr-defined]
        try:
            return clk.wait_for(pred, timeout)
        finally:
            self._acquire_restore(saved)  # type: ignore[attr-defined]


@contextlib.contextmanager
def batch() -> Iterator[None]:
    """Frames sent in the block are queued back to back, as a master's burst: a virtual
    bus settles once at the end, not after each frame."""
    if not isinstance(_current, VirtualClock) or not _current.may_wait():
        yield  # (another thread's sends never settle: its batch would hold the run's)
        return
    clk = _current
    clk.hold += 1
    try:
        yield
    finally:
        clk.hold -= 1
        if clk.hold == 0:  # the outermost batch settles what its sends left in flight
            held, clk.held = clk.held, []
            for busy in held:
                clk.settle(busy)


__all__ = ["CLOCKS", "REAL", "VIRTUAL_EPOCH_NS", "Cancelled", "ClockCondition", "ClockQueue",
           "RealClock", "VirtualClock", "VirtualTimeout", "batch", "call_later", "current",
           "is_virtual", "monotonic", "monotonic_ns", "sleep", "time_ns", "use", "wait",
           "wait_for"]
