"""Runs a model drive in real time and shares it safely between faces.

`DriveHost` owns the lock every face holds while it touches the drive, and a ticker thread
that advances the model clock to the monotonic clock and then calls each face's
`tick(now_ns)`. It wakes at every grid point of the model (`period_s`, 1 ms by default: the
model's motion grid, so a motion step's outputs leave at their model time) and, between two,
at the model's next timer (a brake delay, a DI filter, a capture latch): an edge a timer
makes reaches the faces as late as the host's wake-up, not up to a period later
(`timer_wakeups=False` is the plain ticker, kept as the benchmark's baseline:
benchmarks/bench_edges.py). With `rt_priority` (or the environment variable
`HIL_RT_PRIORITY`, 1-99) the ticker thread asks for `SCHED_FIFO` at that priority where the
host allows it, and says so in the log either way (hil.realtime). Model time starts at 0
when the host starts; `wall_ns(t)` maps it to epoch ns for records.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

from hil.realtime import env_priority, set_fifo

log = logging.getLogger(__name__)

# the ticker never sleeps less between two late ticks, nor wakes on a finer grid
MIN_WAKE_NS = 100_000


class DriveHost:
    """Real-time owner of one `Drive`: lock, ticker thread, tick callbacks."""

    def __init__(self, drive: Any, *, period_s: float = 0.001,
                 timer_wakeups: bool = True, rt_priority: int | None = None) -> None:
        self.drive = drive
        self.lock = threading.RLock()
        self.period_s = period_s
        self.timer_wakeups = timer_wakeups
        self.rt_priority = rt_priority if rt_priority is not None else env_priority()
        self.realtime = False  # SCHED_FIFO granted to the ticker thread
        self._wake: threading.Event | None = None  # set to wake the ticker early (poke)
        self._planned = 0  # model time of the ticker's planned wake-up
        self._ticks: list[Callable[[int], None]] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._mono0 = time.monotonic_ns() - drive.now
        self._wall0 = time.time_ns() - drive.now
        self.errors: list[BaseException] = []
        # the model itself raised while advancing: what the drive shows since is not the
        # drive's (the bench reports it dead, docs/benches.md); a face's error is only logged
        self.model_failed: BaseException | None = None
        self._synced = _SyncedLock(self)

    # -- time --------------------------------------------------------------------------------
    def model_now(self) -> int:
        """Model time that corresponds to the monotonic clock now."""
        return time.monotonic_ns() - self._mono0

    def wall_ns(self, t_model: int) -> int:
        """Epoch ns of a model timestamp (for `publish_time`)."""
        return self._wall0 + t_model

    # -- faces -------------------------------------------------------------------------------
    def add_tick(self, fn: Callable[[int], None]) -> None:
        """Call `fn(model_now_ns)` after each model advance, under the lock."""
        with self.lock:
            self._ticks.append(fn)

    def remove_tick(self, fn: Callable[[int], None]) -> None:
        with self.lock:
            if fn in self._ticks:
                self._ticks.remove(fn)

    @property
    def synced(self) -> _SyncedLock:
        """A lock for faces: acquiring it also brings the model up to now, so a frame a face
        applies is stamped with its arrival time, not the last 1 ms tick."""
        return self._synced

    def call(self, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
        """Bring the model up to now, then run `fn` under the lock."""
        with self.lock:
            self._advance()
            try:
                return fn(*args, **kwargs)
            finally:
                self.poke()

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> DriveHost:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="drive-host", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
        if self._wake is not None:
            self._wake.set()  # not a period later
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None

    def __enter__(self) -> DriveHost:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _advance(self) -> None:
        now = self.model_now()
        if now > self.drive.now:
            self.drive.advance_to(now)

    def tick_once(self) -> None:
        """One host tick: the model up to now, then every face's tick (under the lock)."""
        with self.lock:
            try:
                self._advance()
            except Exception as exc:
                self._model_error(exc)
                return
            try:
                now = self.drive.now
                for fn in list(self._ticks):
                    fn(now)
            except Exception as exc:  # a face bug must not stop the drive clock
                self._note_error("tick", exc)

    def _model_error(self, exc: Exception) -> None:
        self._note_error("advance", exc)
        if self.model_failed is None:
            self.model_failed = exc

    def _note_error(self, where: str, exc: Exception) -> None:
        """Log the first error of each type with its traceback, count the rest."""
        if not any(type(e) is type(exc) for e in self.errors):
            log.error("drive host: %s failed (further %s are counted only)", where,
                      type(exc).__name__, exc_info=exc)
        self.errors.append(exc)
        if len(self.errors) > 100:
            del self.errors[:50]

    def _next_wake(self, period: int) -> int:
        """Model time of the next wake-up: the next point of the host's period and of the
        model's motion grid, or the model's next timer if that comes first; a timer already
        due (armed during the tick) means at once. Read under the lock: the scheduler drops
        cancelled timers as it is read, and faces arm timers from their threads."""
        now = self.model_now()
        nxt = (now // period + 1) * period
        step = getattr(self.drive, "step_ns", None)
        if isinstance(step, int) and step >= MIN_WAKE_NS:  # a finer grid would be a busy loop
            nxt = min(nxt, (now // step + 1) * step)
        if self.timer_wakeups:
            sched = getattr(self.drive, "sched", None)
            if sched is not None:
                with self.lock:
                    due = sched.next_deadline()
                    if due is not None and due < nxt:  # due already: the next tick fires it
                        nxt = due
                    self._planned = nxt
        return nxt

    def poke(self) -> None:
        """Wake the ticker now if the model's next timer comes before its planned wake-up
        (a face armed one from its own thread). Call with the lock held."""
        if not self.timer_wakeups or self._wake is None:
            return
        try:
            sched = getattr(self.drive, "sched", None)
            due = sched.next_deadline() if sched is not None else None
            if due is not None and due < self._planned:
                self._planned = due
                self._wake.set()
        except Exception as exc:  # never in place of the caller's own result or error
            self._note_error("poke", exc)

    def _set_realtime(self) -> None:
        self.realtime = set_fifo(self.rt_priority, "drive host ticker")

    def _run(self) -> None:
        self._set_realtime()
        period = int(self.period_s * 1e9)
        if not self.timer_wakeups:
            self._run_plain(period)
            return
        wake = self._wake = threading.Event()
        late = False
        while not self._stop.is_set():
            self.tick_once()
            try:
                delay = self._next_wake(period) - self.model_now()
            except Exception as exc:  # a broken drive must not stop the clock
                self._note_error("next wake-up", exc)
                delay = period
            if delay > 0:
                late = False
                if wake.wait(delay / 1e9):
                    wake.clear()
            elif late:  # late twice in a row (a loaded host, a stuck model): never spin,
                time.sleep(MIN_WAKE_NS / 1e9)  # which at SCHED_FIFO would hold a core
            else:  # late once: tick at once, advancing to now, no burst
                late = True

    def _run_plain(self, period: int) -> None:
        """A tick every `period` on absolute deadlines, at any phase of the model's grid."""
        deadline = time.monotonic_ns()
        while not self._stop.is_set():
            deadline += period
            self.tick_once()
            delay = deadline - time.monotonic_ns()
            if delay > 0:
                time.sleep(delay / 1e9)
            elif delay < -50 * period:  # fell far behind (suspended?): resynchronise
                deadline = time.monotonic_ns()


class _SyncedLock:
    """Context manager (and lock-like object) over `DriveHost.lock` that advances the model."""

    def __init__(self, host: DriveHost) -> None:
        self._host = host

    def acquire(self, blocking: bool = True, timeout: float = -1) -> bool:
        ok = self._host.lock.acquire(blocking, timeout)
        if ok:
            try:
                self._host._advance()
            except Exception as exc:  # the lock stays held for the caller's `with` body:
                self._host._model_error(exc)  # raising here would leak it
        return ok

    def release(self) -> None:
        try:
            self._host.poke()  # a timer the face armed may come before the planned wake-up
        finally:
            self._host.lock.release()

    def __enter__(self) -> _SyncedLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class ClockHost(DriveHost):
    """`DriveHost` on a `VirtualClock` (docs/clock.md): no thread; a clock event advances the
    model and runs the faces' ticks at every point of the host's period (a grid from the
    host's start) and, between two, at the model's next timer (a brake delay, a DI filter, a
    capture latch), as the real-time host wakes for one; a face that takes the lock brings
    the model up to the clock's now, as on the real-time host. Model time 0 is the clock's
    time when the host is made."""

    def __init__(self, drive: Any, clock: Any, *, period_s: float = 0.001) -> None:
        self.clock = clock
        super().__init__(drive, period_s=period_s)
        self._base = clock.time_ns() - drive.now
        self._event: Any = None
        self._t0 = 0  # model time of the first tick: the period's grid
        self._ticking = False  # inside `_tick`: it plans the next wake-up itself
        self._armed: int | None = None  # the model's `Scheduler.armed` when it planned
        self._at_once = -1  # model time of the last tick planned "at once" for a due timer

    def model_now(self) -> int:
        return self.clock.time_ns() - self._base

    def next_grid(self, t: int) -> int:
        """The first point of the host's period grid (from its start) at or after model time
        `t`: the ground truth samples on it, where the host wakes anyway. (The real-time host
        has none: its samples keep the phase of its first tick, off the model's motion grid,
        as before; on the motion grid a spec's sample after the step can miss an error that
        passed P2.035 and raised AL009 in the same step: plc_al009.)"""
        period = int(self.period_s * 1e9)
        return self._t0 + -(-(t - self._t0) // period) * period

    def wall_ns(self, t_model: int) -> int:
        return self._base + t_model

    def start(self) -> ClockHost:
        if self._event is None:
            self._t0 = self.model_now()  # the period's grid starts here
            self._event = self.clock.after(0, self._tick)
        return self

    def stop(self) -> None:
        with self.lock:
            if self._event is not None:
                self._event.cancel()
                self._event = None

    def _advance(self) -> None:
        now = self.model_now()
        drive = self.drive
        if now > drive.now:
            drive.advance_to(now)
        elif self._ticking and self.timer_wakeups:  # woken at a timer armed for this instant
            sched = getattr(drive, "sched", None)
            due = sched.next_deadline() if sched is not None else None
            if due is not None and due <= now:
                drive.advance_to(now)

    def _tick(self) -> None:
        with self.lock:  # planned under the lock, as `poke` re-plans under it
            self._ticking = True
            try:
                self.tick_once()
            finally:  # the next tick is planned whatever cut this one short (a signal
                self._ticking = False  # handler's exception): the model never stops
                self._plan()

    def _plan(self) -> None:
        """The next wake-up: the next point of the period's grid (which starts at the host's
        start; the ground truth samples on it), or the model's next timer if that comes first.
        A timer already due means at once, but only once per instant: a model that cannot
        advance (it failed) must not hold time at this instant for ever."""
        period = int(self.period_s * 1e9)
        now = self.model_now()
        nxt = self._t0 + ((now - self._t0) // period + 1) * period
        sched = getattr(self.drive, "sched", None)
        if self.timer_wakeups and sched is not None:
            try:
                due = sched.next_deadline()
                if due is not None and due < nxt and (due > now or self._at_once != now):
                    nxt = max(due, now)
                    if due <= now:
                        self._at_once = now
            except Exception as exc:  # a broken drive must not stop the clock
                self._note_error("next wake-up", exc)
        self._planned = nxt
        self._armed = getattr(sched, "armed", None)
        self._event = self.clock.at(self.wall_ns(nxt), self._tick)

    def poke(self) -> None:
        """Wake at the model's next timer if a face armed one before the planned wake-up. A
        face in another thread (a test's own DI/DO set) hands the re-plan to the run's."""
        if not self.timer_wakeups or self._ticking or self._event is None:
            return
        if not self.clock.may_wait():
            self.clock.at(self.clock.time_ns(), self.poke)  # the run's thread, next pass
            return
        try:
            sched = getattr(self.drive, "sched", None)
            armed = getattr(sched, "armed", None)
            if armed is not None and armed == self._armed:
                return  # no timer armed since the wake-up was planned
            self._armed = armed
            due = sched.next_deadline() if sched is not None else None
            if due is not None and due < self._planned:
                self._event.cancel()
                self._planned = due
                self._event = self.clock.at(self.wall_ns(due), self._tick)
        except Exception as exc:  # never in place of the caller's own result or error
            self._note_error("poke", exc)
