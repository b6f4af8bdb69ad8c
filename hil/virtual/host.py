"""Runs a model drive in real time and shares it safely between faces.

`DriveHost` owns the lock every face holds while it touches the drive, and a ticker thread
that advances the model clock to the monotonic clock every `period_s` (1 ms by default,
absolute deadlines: docs/dev/feasibility.md §7) and then calls each face's `tick(now_ns)`.
Model time starts at 0 when the host starts; `wall_ns(t)` maps it to epoch ns for records.
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

log = logging.getLogger(__name__)


class DriveHost:
    """Real-time owner of one `Drive`: lock, ticker thread, tick callbacks."""

    def __init__(self, drive: Any, *, period_s: float = 0.001) -> None:
        self.drive = drive
        self.lock = threading.RLock()
        self.period_s = period_s
        self._ticks: list[Callable[[int], None]] = []
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._mono0 = time.monotonic_ns() - drive.now
        self._wall0 = time.time_ns() - drive.now
        self.errors: list[BaseException] = []
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
            return fn(*args, **kwargs)

    # -- lifecycle ---------------------------------------------------------------------------
    def start(self) -> DriveHost:
        if self._thread is None:
            self._stop.clear()
            self._thread = threading.Thread(target=self._run, name="drive-host", daemon=True)
            self._thread.start()
        return self

    def stop(self) -> None:
        self._stop.set()
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
                now = self.drive.now
                for fn in list(self._ticks):
                    fn(now)
            except Exception as exc:  # a face bug must not stop the drive clock
                self._note_error("tick", exc)

    def _note_error(self, where: str, exc: Exception) -> None:
        """Log the first error of each type with its traceback, count the rest."""
        if not any(type(e) is type(exc) for e in self.errors):
            log.error("drive host: %s failed (further %s are counted only)", where,
                      type(exc).__name__, exc_info=exc)
        self.errors.append(exc)
        if len(self.errors) > 100:
            del self.errors[:50]

    def _run(self) -> None:
        period = int(self.period_s * 1e9)
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
                self._host._note_error("advance", exc)  # raising here would leak it
        return ok

    def release(self) -> None:
        self._host.lock.release()

    def __enter__(self) -> _SyncedLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


class ClockHost(DriveHost):
    """`DriveHost` on a `VirtualClock` (docs/clock.md): no thread; a clock event every
    `period_s` advances the model and runs the faces' ticks, and a face that takes the lock
    brings the model up to the clock's now, as on the real-time host. Model time 0 is the
    clock's time when the host is made."""

    def __init__(self, drive: Any, clock: Any, *, period_s: float = 0.001) -> None:
        self.clock = clock
        super().__init__(drive, period_s=period_s)
        self._base = clock.time_ns() - drive.now
        self._event: Any = None

    def model_now(self) -> int:
        return self.clock.time_ns() - self._base

    def wall_ns(self, t_model: int) -> int:
        return self._base + t_model

    def start(self) -> ClockHost:
        if self._event is None:
            self._event = self.clock.after(0, self._tick)
        return self

    def stop(self) -> None:
        if self._event is not None:
            self._event.cancel()
            self._event = None

    def _tick(self) -> None:
        self.tick_once()
        self._event = self.clock.after(int(self.period_s * 1e9), self._tick)
