"""A cyclic producer (SYNC, heartbeat, node guarding) that never catches up in a burst.

python-can's `send_periodic` keeps its phase: a thread that wakes 40 ms late sends the
missed frames back to back. For SYNC that burst is a genuinely early SYNC (AL3E2,
L20159-20163) and a cycle off 1006h (AL301, L20123-20127) that the harness made, not the
drive. A real master's producer does not do that, so this one re-phases instead: a frame
more than `rephase` x period late is sent at once and the cycle restarts from it. Every
interval is then at least (1 - rephase) x period; a stall still makes one long interval
(that is what a stalled master does) and is reported through `on_late`. With
`HIL_RT_PRIORITY` the producer's thread asks for `SCHED_FIFO` (hil.realtime).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable, Sequence

import can

from hil import clock
from hil.realtime import env_priority, set_fifo

log = logging.getLogger(__name__)

REPHASE = 0.25  # of the period: later than this, restart the cycle from the late frame


class Cyclic:
    """Calls `fn()` every `period_s` on the current clock until `stop()` or `fn()` returns
    False: clock events in virtual time (exactly on period), else a daemon thread that
    re-phases after a stall instead of catching up in a burst."""

    def __init__(self, fn: Callable[[], bool | None], period_s: float, *,
                 rephase: float = REPHASE, on_late: Callable[[int], None] | None = None,
                 name: str = "cyclic") -> None:
        if period_s <= 0:
            raise ValueError(f"period {period_s} s: must be > 0")
        self.fn = fn
        self.period_ns = round(period_s * 1e9)
        self.rephase_ns = round(self.period_ns * rephase)
        self.on_late = on_late
        self.rephased = 0
        self._stop = threading.Event()
        self._thread: threading.Thread | None = None
        self._event = None
        clk = clock.current()
        if isinstance(clk, clock.VirtualClock):  # events of the clock, exactly on period
            self._clock = clk
            self._event = clk.after(0, self._tick)
            return
        self._thread = threading.Thread(target=self._run, daemon=True, name=name)
        self._thread.start()

    def _tick(self) -> None:
        if self._stop.is_set() or self.fn() is False:
            return
        self._event = self._clock.after(self.period_ns, self._tick)

    def _run(self) -> None:
        set_fifo(env_priority(), self._thread.name if self._thread else "cyclic")
        due = time.perf_counter_ns()
        while not self._stop.is_set():
            now = time.perf_counter_ns()
            if now - due > self.rephase_ns:  # woke late: no burst, a new phase
                self.rephased += 1
                if self.on_late is not None:
                    self.on_late(now - due)
                due = now
            if self.fn() is False:
                return
            due += self.period_ns
            wait = due - time.perf_counter_ns()
            if wait > 0 and self._stop.wait(wait / 1e9):
                return

    def stop(self) -> None:
        self._stop.set()
        if self._event is not None:
            self._event.cancel()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout=1.0)


class CyclicSender(Cyclic):
    """Sends `msg` on `bus` every `period_s` until `stop()` (a closed bus ends it, as a
    stopped master)."""

    def __init__(self, bus: can.BusABC, msg: can.Message, period_s: float, *,
                 rephase: float = REPHASE,
                 on_late: Callable[[int], None] | None = None) -> None:
        self.bus, self.msg = bus, msg
        self.sent = 0
        super().__init__(self._send, period_s, rephase=rephase, on_late=on_late,
                         name=f"cyclic-{msg.arbitration_id:03X}")

    def _send(self) -> bool:
        try:
            self.bus.send(self.msg)
        except Exception:  # a closed bus ends the producer, as a stopped master
            return False
        self.sent += 1
        return True


class ClockCyclicSendTask(can.broadcastmanager.LimitedDurationCyclicSendTaskABC,
                          can.broadcastmanager.ModifiableCyclicTaskABC,
                          can.broadcastmanager.RestartableCyclicTaskABC):
    """python-can's `send_periodic` task on a virtual clock: `ThreadBasedCyclicSendTask`'s
    behaviour (the messages in turn, the first at once, `duration`, `modifier_callback`, a
    send error stops it) as clock events, each frame exactly on period in bench time. A
    thread on the wall clock would send at wall-clock instants the bench's time knows
    nothing of. A send error (or the callback's) is kept in `error` and raised at the run's
    next wait, not inside another send's settle: the test or the plan step fails with it."""

    def __init__(self, bus: can.BusABC, clk: clock.VirtualClock,
                 messages: Sequence[can.Message] | can.Message, period: float,
                 duration: float | None = None, autostart: bool = True,
                 modifier_callback: Callable[[can.Message], None] | None = None) -> None:
        super().__init__(messages, period, duration)
        if self.period_ns <= 0:
            raise ValueError(f"period {period} s: must be > 0")
        self.bus, self.clock = bus, clk
        self.modifier_callback = modifier_callback
        self.stopped = True
        self.error: BaseException | None = None  # what stopped it, if a send failed
        self._event: clock.Event | None = None
        self._index = 0
        self._end_ns: int | None = None
        if autostart:
            self.start()

    def start(self) -> None:
        if not self.stopped:
            return
        self.stopped, self._index = False, 0
        self._end_ns = (None if not self.duration
                        else self.clock.time_ns() + round(self.duration * 1e9))
        self._event = self.clock.after(0, self._tick)

    def stop(self) -> None:
        self.stopped = True
        if self._event is not None:
            self._event.cancel()
            self._event = None

    def _tick(self) -> None:
        if self.stopped:
            return
        if self._end_ns is not None and self.clock.time_ns() >= self._end_ns:
            self.stop()
            return
        msg = self.messages[self._index]
        try:
            if self.modifier_callback is not None:
                self.modifier_callback(msg)
            self.bus.send(msg)
        except Exception as exc:  # as python-can's task without `on_error`: it stops, and
            self.error = exc  # the error is raised at the run's next wait (python-can raises
            log.error("cyclic send of %03Xh stopped: %s", self.arbitration_id, exc)
            self.stop()  # it in its own thread, where pytest only warns)
            self.clock.fail(exc)
            return
        self._index = (self._index + 1) % len(self.messages)
        self._event = self.clock.after(self.period_ns, self._tick)


class ClockPeriodic:
    """A bus mixin: `send_periodic` runs on the virtual clock when one is current (else
    python-can's own thread-based task). First among the bases: `(ClockPeriodic, BusABC)`."""

    def _send_periodic_internal(self, msgs: Sequence[can.Message] | can.Message,
                                period: float, duration: float | None = None,
                                autostart: bool = True,
                                modifier_callback: Callable[[can.Message], None] | None = None,
                                ) -> can.broadcastmanager.CyclicSendTaskABC:
        clk = getattr(self, "clock", None)
        if not isinstance(clk, clock.VirtualClock):
            clk = clock.current()
        if isinstance(clk, clock.VirtualClock):
            return ClockCyclicSendTask(self, clk, msgs, period, duration, autostart,  # type: ignore[arg-type]
                                       modifier_callback)
        return super()._send_periodic_internal(  # type: ignore[misc]
            msgs, period, duration, autostart, modifier_callback)
