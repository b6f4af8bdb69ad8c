"""DI/DO lines of a model drive on an injected clock, for the absolute-position reader
(`hil.drivers.abs_reader`) in tests and benchmarks: waits advance the model instead of sleeping."""

from __future__ import annotations

from collections.abc import Callable


class ModelClock:
    """Clock whose sleep advances a model (`advance_to(t_ns)`) instead of waiting."""

    def __init__(self, now: Callable[[], int], advance_to: Callable[[int], None]) -> None:
        self._now = now
        self._advance_to = advance_to

    def now_ns(self) -> int:
        return self._now()

    def sleep(self, seconds: float) -> None:
        self._advance_to(self._now() + round(seconds * 1e9))


class ModelLines:
    """DioLines for a model on an injected clock.

    `write(line, level)` delivers a host output (drive input) level; `read(line)` returns a
    drive output level. `wait_for` advances the model from one timer deadline to the next
    (`next_deadline`, else in `poll_ns` steps) until the level shows or the timeout passes.
    """

    def __init__(
        self,
        *,
        now: Callable[[], int],
        advance_to: Callable[[int], None],
        write: Callable[[str, bool], None],
        read: Callable[[str], bool],
        next_deadline: Callable[[], int | None] | None = None,
        poll_ns: int = 100_000,
    ) -> None:
        self._now = now
        self._advance_to = advance_to
        self._write = write
        self._read = read
        self._next_deadline = next_deadline
        self.poll_ns = poll_ns
        self.inputs: dict[str, bool] = {}
        self.clock = ModelClock(now, advance_to)

    def set(self, line: str, level: bool) -> None:
        self.inputs[line] = bool(level)
        self._write(line, bool(level))

    def get(self, line: str) -> bool:
        if line in self.inputs:
            return self.inputs[line]
        return bool(self._read(line))

    def wait_for(self, line: str, level: bool, timeout_s: float) -> int | None:
        deadline = self._now() + round(timeout_s * 1e9)
        while True:
            if self.get(line) == level:
                return self._now()
            now = self._now()
            if now >= deadline:
                return None
            if self._next_deadline is None:
                target = min(now + self.poll_ns, deadline)
            else:
                nxt = self._next_deadline()
                if nxt is None:
                    target = deadline  # nothing scheduled: nothing will change before it
                elif nxt <= now:
                    self._advance_to(now)  # run what is due now
                    nxt = self._next_deadline()
                    if nxt is None or nxt > now:
                        continue
                    target = min(now + self.poll_ns, deadline)  # still due: step on
                else:
                    target = min(nxt, deadline)
            self._advance_to(target)
