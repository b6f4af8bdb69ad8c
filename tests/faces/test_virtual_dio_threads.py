"""DI/DO lines on the virtual clock from a thread of the test's own (an outside probe,
docs/clock.md "Other threads"): another thread reads levels while the run waits, and waits
for a level in wall time, as a python-can reader does on the virtual bus."""

from __future__ import annotations

import threading
import time

import pytest

from hil import clock
from hil.clock import VirtualClock
from hil.transport.dio import open_dio

pytestmark = pytest.mark.virtual_time


@pytest.fixture
def lines():
    clk = VirtualClock()
    with clock.use(clk):
        harness = open_dio("virtual:thr", role="harness", name="io")
        drive = open_dio("virtual:thr", role="drive", name="drv")
        clk.after(0, lambda: None)
        yield clk, harness, drive
        harness.close()
        drive.close()


def _ticker(clk: VirtualClock, period_ns: int = 1_000_000):
    """Something on the clock every ms, as a drive host (bench time moves in steps)."""
    def tick() -> None:
        clk.after(period_ns, tick)
    clk.after(period_ns, tick)


def test_another_thread_reads_levels_while_the_run_waits(lines) -> None:
    """`get` from another thread waited for the lock the run's `wait_for` held while the
    clock ran: for the whole wait (735 ms of wall time for a 120 s wait)."""
    clk, harness, drive = lines
    _ticker(clk)
    drive.set("DO1", True)
    seen: dict[str, object] = {}
    run_waited = threading.Event()

    def other() -> None:
        time.sleep(0.02)
        seen["DO1"] = harness.get("DO1")
        seen["during the run's wait"] = not run_waited.is_set()

    th = threading.Thread(target=other)
    th.start()
    with pytest.raises(TimeoutError):
        harness.wait_for("DO6", True, 600.0)  # never comes: 600 000 events of bench time
    run_waited.set()
    th.join(5)
    assert seen == {"DO1": True, "during the run's wait": True}


def test_another_threads_wait_for_is_in_wall_time_and_sees_the_runs_level(lines) -> None:
    """Another thread's `wait_for` raised "not the run's"; it now waits in wall time for
    what the run's thread sets, and times out in wall seconds."""
    clk, harness, drive = lines
    _ticker(clk)
    got: dict[str, object] = {}

    def other() -> None:
        try:
            got["t"] = harness.wait_for("DO3", True, 5.0)
        except BaseException as exc:  # which one is the point
            got["error"] = exc
        w0 = time.monotonic()
        try:
            harness.wait_for("DO4", True, 0.2)  # never set: times out in wall time
        except TimeoutError:
            got["timeout_wall"] = time.monotonic() - w0

    th = threading.Thread(target=other)
    th.start()
    time.sleep(0.05)
    clk.sleep(0.01)
    drive.set("DO3", True)
    clk.sleep(0.01)
    th.join(5)
    assert "error" not in got, got
    assert isinstance(got["t"], int)
    assert 0.2 <= got["timeout_wall"] < 2, got


def test_a_wait_inside_a_clock_event_is_refused(lines) -> None:
    """Inside one of the run's events no level can change while it waits: it held the clock
    for its whole timeout in wall time, then said the level never came (an outside review).
    It is refused at once, as any wait inside an event."""
    clk, harness, _drive = lines
    seen: dict[str, BaseException] = {}

    def event() -> None:
        try:
            harness.wait_for("DO1", True, 0.3)
        except BaseException as exc:  # which one is the point
            seen["error"] = exc

    clk.after(1000, event)
    clk.sleep(0.001)
    assert type(seen.get("error")) is RuntimeError and "inside a clock event" in str(
        seen["error"]), seen
