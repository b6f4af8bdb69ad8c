"""The model's time base: integer nanoseconds and a deterministic event scheduler.

The model never reads a wall clock. Whoever owns the drive advances time: a test calls
`Drive.advance(10 * MS)`, the real-time runner calls `Drive.advance_to(monotonic_ns())`.
Timers scheduled for the same instant fire in the order they were scheduled.
"""

from __future__ import annotations

import heapq
import itertools
from collections.abc import Callable
from dataclasses import dataclass, field

from hil.units import MS


def ms(value: float) -> int:
    """Milliseconds to integer nanoseconds."""
    return round(value * MS)


@dataclass(order=True)
class Timer:
    """A scheduled callback; `cancel()` it to stop it firing."""

    deadline: int
    seq: int
    callback: Callable[[], None] = field(compare=False)
    cancelled: bool = field(default=False, compare=False)

    def cancel(self) -> None:
        self.cancelled = True


class Scheduler:
    """Timer heap on an injected clock (ns). `now` only moves forward."""

    def __init__(self, t0: int = 0) -> None:
        self.now: int = t0
        self._heap: list[Timer] = []
        self._seq = itertools.count()
        self.armed = 0  # timers scheduled so far (a host re-plans its wake-up only when it grew)

    def at(self, deadline: int, callback: Callable[[], None]) -> Timer:
        """Run `callback` when time reaches `deadline` (ns, absolute)."""
        timer = Timer(max(deadline, self.now), next(self._seq), callback)
        self.armed += 1
        heapq.heappush(self._heap, timer)
        return timer

    def after(self, delay: int, callback: Callable[[], None]) -> Timer:
        """Run `callback` `delay` ns from now."""
        return self.at(self.now + delay, callback)

    def next_deadline(self) -> int | None:
        """Deadline of the earliest live timer, or None."""
        heap = self._heap
        while heap and heap[0].cancelled:
            heapq.heappop(heap)
        return heap[0].deadline if heap else None

    def run_due(self) -> int:
        """Fire every live timer whose deadline is <= now; return how many fired."""
        fired = 0
        heap = self._heap
        while heap and heap[0].deadline <= self.now:
            timer = heapq.heappop(heap)
            if not timer.cancelled:
                timer.cancelled = True
                timer.callback()
                fired += 1
        return fired

    def advance_to(self, t: int) -> None:
        """Fire timers in deadline order, each at its own deadline, then set `now = t`."""
        while True:
            nxt = self.next_deadline()
            if nxt is None or nxt > t:
                break
            self.now = max(self.now, nxt)
            self.run_due()
        self.now = max(self.now, t)


__all__ = ["Scheduler", "Timer", "ms"]
