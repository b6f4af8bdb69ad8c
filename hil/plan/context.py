"""What a running step sees (`StepContext`) and what it returns (`Outcome`) or raises.

Shared by the runner (hil/plan/runner.py) and the step kinds (hil/plan/kinds/), so that
neither imports the other's internals.
"""

from __future__ import annotations

import contextlib
import threading
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.units import S

if TYPE_CHECKING:
    from hil.plan.plan import Plan
    from hil.plan.session import DriveIO, Session
    from hil.plan.steps import Step


# A virtual-time step that has not ended after its timeout plus this much wall time hangs
# the host (docs/clock.md): the runner gives up on it as on a real-time step timeout.
WATCHDOG_GRACE_NS = 60 * S
WATCH_S = 0.25  # how often a running step's bench is looked at (a drive process died?)
# ... or this many times the step timeout, whichever is longer: a heavy bench (many axes at a
# short SYNC) may run slower than real time, and a legitimate long step must not trip it
WATCHDOG_FACTOR = 10


class SafeStateHung(BaseException):
    """The safe state (or the 200 ms after it) ran past its wall-clock watchdog on a virtual
    clock: the host hung inside a clock event that this thread itself was running. A
    BaseException, so that no `except Exception` in the hung event or on the way out (the
    safe state's own per-action handling, the tail's) takes it for something to carry on
    after; `hil.plan.safety.go_safe_watched` records it."""

    def __init__(self, *args: object) -> None:  # raised as a class, from another thread
        super().__init__(*args or ("a clock event hung the host during the safe state or the "
                                   "200 ms after it: stopped by its wall-clock watchdog "
                                   "(docs/clock.md)",))


@contextlib.contextmanager
def safe_state_watchdog(timeout_ns: int) -> Iterator[None]:
    """On a virtual clock, stop the block once it has run `max(WATCHDOG_GRACE_NS,
    WATCHDOG_FACTOR x timeout_ns)` of wall time: the clock is marked hung and SafeStateHung
    is raised in this thread, again every second until the block has ended (an event that
    caught it once is stopped the next time). A step's own hang is `StepThread.run`'s
    watchdog; this one covers a model event that never returns while the safe state runs it
    (helper-131: the process hung for good, Ctrl-C and SIGTERM held off). An event blocked
    in a C-level wait (a lock, an Event) gets it only when it runs Python again. On the wall
    clock the safe state's own timeouts end it."""
    clk = clock.current()
    if not isinstance(clk, clock.VirtualClock):
        yield
        return
    wall_s = max(WATCHDOG_GRACE_NS, WATCHDOG_FACTOR * timeout_ns) / S
    ident, lock, done = threading.get_ident(), threading.RLock(), threading.Event()
    sent = False  # a SafeStateHung was raised: one that has not landed is withdrawn at the end

    def bark() -> None:
        nonlocal sent
        wait_s = wall_s
        while not done.wait(wait_s):
            with lock:
                if done.is_set():
                    return
                clk.hung = True  # every other use of the clock fails at once from now on
                clock.async_raise(ident, SafeStateHung)
                sent = True
            wait_s = 1.0

    threading.Thread(target=bark, name="hil-safe-watchdog", daemon=True).start()
    try:
        yield
    finally:
        landed: SafeStateHung | None = None
        while True:  # one raised just as the block ended lands here: done is set anyway
            try:
                with lock:
                    done.set()
                    if sent:  # one not raised yet never will be (a withdrawal costs a thread)
                        clock.async_raise(ident, None)
                break
            except SafeStateHung as e:
                landed = e
        if landed is not None:
            raise landed


class StepFailed(Exception):
    """A step's expectation was not met (not a harness error); may carry timing verdicts."""

    def __init__(self, message: str, verdicts: list[dict] | None = None) -> None:
        super().__init__(message)
        self.verdicts = verdicts or []


class Inconclusive(StepFailed):
    """The observation cannot decide pass or fail (e.g. a gap in the recording)."""


Cancelled = clock.Cancelled  # the step was cancelled (step timeout, Ctrl-C) while it waited


@dataclass
class Outcome:
    """What a step kind's `run` returns: a one-line result and any timing verdicts."""

    text: str = ""
    verdicts: list[dict] = field(default_factory=list)


class StepThread:
    """Runs one step in a thread the runner can give up on, and join later.

    It waits on the step's own `done` event, never `Thread.join`: a Ctrl-C that lands inside
    Python 3.11's `join` marks a thread that is still running as stopped (its tstate-lock
    recovery, bpo-45274), so the safe state would have run beside a live step."""

    def __init__(self) -> None:
        self.thread: threading.Thread | None = None
        self.done = threading.Event()  # set as the last step's thread ends

    def run(self, fn: Callable[[], Any], timeout_ns: int, cancel: threading.Event,
            watch: Callable[[], None] | None = None) -> Any:
        """`fn()` or, at `timeout_ns`, TimeoutError at once (the step is cancelled and left
        to `join`). A KeyboardInterrupt cancels the step and joins it before propagating.
        `watch()` is called every WATCH_S of wall time while the step runs; what it raises
        (a drive process that died) cancels the step and is raised at once."""
        box: dict[str, Any] = {}
        clk = clock.current()
        virtual = isinstance(clk, clock.VirtualClock)
        done = self.done = threading.Event()

        def target() -> None:
            try:
                if virtual:  # the step timeout passes in virtual time
                    with clk.watch(cancel, clk.time_ns() + timeout_ns):
                        box["value"] = fn()
                else:
                    box["value"] = fn()
            except clock.VirtualTimeout:
                box["error"] = TimeoutError(
                    f"step timeout {timeout_ns / 1e9:g} s of virtual time (bench "
                    "timeouts.step or the step's timeout)")
            except BaseException as e:
                box["error"] = e
            finally:
                done.set()

        t = self.thread = threading.Thread(target=target, name="hil-step", daemon=True)
        t0 = time.monotonic_ns()
        t.start()
        # on a virtual clock, a wall-clock watchdog stops a step that hangs the host
        wall_ns = (max(timeout_ns + WATCHDOG_GRACE_NS, timeout_ns * WATCHDOG_FACTOR)
                   if virtual else timeout_ns)
        end = t0 + wall_ns
        seen: Exception | None = None  # what `watch` raised
        try:
            while not done.is_set() and seen is None:
                left = end - time.monotonic_ns()
                if left <= 0:
                    break
                done.wait(min(left / 1e9, WATCH_S) if watch is not None else left / 1e9)
                if watch is not None and not done.is_set():
                    try:
                        watch()
                    except Exception as e:
                        seen = e
        except BaseException:  # Ctrl-C: the step is cancelled and joined first
            cancel.set()
            self.join()
            raise
        if seen is not None:  # the bench is gone: the step is cancelled and left to `join`
            cancel.set()
            done.wait(0.05)
            raise seen
        if not done.is_set():
            cancel.set()
            done.wait(0.05)  # a step that honours `cancel` ends now; the others are joined later
            what = (f"wall-clock watchdog {wall_ns / 1e9:g} s (the step timeout "
                    f"{timeout_ns / 1e9:g} s of virtual time + {WATCHDOG_GRACE_NS // S} s, "
                    f"or x {WATCHDOG_FACTOR:g})"
                    if virtual else f"step timeout {timeout_ns / 1e9:g} s (bench "
                    "timeouts.step or the step's timeout)")
            raise TimeoutError(f"{what}, ended after "
                               f"{(time.monotonic_ns() - t0) / 1e9:.3f} s")
        if "error" in box:
            raise box["error"]
        return box.get("value", "")

    def join(self, timeout_s: float = 5.0) -> bool:
        """Wait for the last step to end (bounded); True if no step thread is left running."""
        if self.thread is None:
            return True
        end = time.monotonic() + timeout_s
        while not self.done.is_set() and time.monotonic() < end:
            self.done.wait(0.05)  # short waits: a signal handler still runs in between
        return self.done.is_set()


class StepContext:
    """What a step kind needs: session, recorder, plan, bench, specs, cancel flag."""

    def __init__(self, session: Session, recorder: Any, plan: Plan, specs: dict[str, Any],
                 cancel: threading.Event, steps: StepThread | None = None) -> None:
        self.session, self.rec, self.plan, self.specs = session, recorder, plan, specs
        self.bench = session.bench
        self.cancel = cancel
        self.steps = steps or StepThread()
        for d in session.drives.values():  # driver waits end when the step is cancelled
            if getattr(d, "_cia", None) is not None:
                d._cia.cancel = cancel
        self.store: dict[str, Any] = {}  # readings kept by `abs_read: {store: name}`
        self.checked: dict[str, int] = {}  # spec id -> wall ns its last check_timing ended
        self.started: dict[str, int] = {}  # step name -> wall ns it (last) started
        # (drive, parameter) -> value check_timing read from the drive (None: unreadable)
        self.param_reads: dict[tuple[str, str], int | None] = {}
        self._live: Any = None  # LiveSource of the check_timing steps

    def live_source(self) -> Any:
        """The recording so far as a timing source (call after `rec.flush()`): decoded once
        per message over the plan (`LiveSource`), or read whole where the recorder keeps no
        mirror (a test double)."""
        from hil.timing.source import LiveSource, RecordingSource

        if not hasattr(self.rec, "keep_messages"):
            return RecordingSource(self.rec.path)
        if self._live is None:
            self._live = LiveSource()
        return self._live.refresh(self.rec)

    @property
    def live(self) -> Any:
        """The `LiveSource` the plan's checks kept, if any (None before a check ran)."""
        return self._live

    def written(self, drive: str, values: dict[str, int]) -> None:
        """Record parameter values the plan wrote; only on a bench that is not virtual (a
        virtual drive records its own changes, a real one has no ground truth)."""
        if not self.bench.virtual:
            self.rec.drive_params(drive, values)

    def drive(self, step: Step | None) -> DriveIO:
        name = (step.drive if step else None) or self.plan.drive or self.bench.default_drive
        return self.session.drive(name)

    def sleep(self, ns: int) -> None:
        if clock.wait(self.cancel, ns / 1e9):
            raise Cancelled()
