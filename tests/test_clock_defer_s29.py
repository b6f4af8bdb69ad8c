"""A Ctrl-C deferred inside a clock event is not replaced by another handler's exception
that comes in the same event (helper-125: SIGINT then pytest-timeout's SIGALRM in one event
lost the Ctrl-C, and pytest ran the next test)."""

from __future__ import annotations

import pytest

from hil import clock
from hil.clock import VirtualClock


def test_a_deferred_ctrl_c_wins_over_a_later_exception() -> None:
    clk = VirtualClock()

    def event() -> None:  # as two signal handlers would, inside one event
        assert clk.defer_interrupt(KeyboardInterrupt("SIGINT (Ctrl-C)"))
        assert clk.defer_interrupt(RuntimeError("Timeout"))

    with clock.use(clk):
        clk.after(1_000, event)
        with pytest.raises(KeyboardInterrupt, match="SIGINT"):
            clk.sleep(0.01)


def test_a_later_ctrl_c_replaces_another_deferred_exception() -> None:
    clk = VirtualClock()

    def event() -> None:
        assert clk.defer_interrupt(RuntimeError("Timeout"))
        assert clk.defer_interrupt(KeyboardInterrupt("SIGINT (Ctrl-C)"))

    with clock.use(clk):
        clk.after(1_000, event)
        with pytest.raises(KeyboardInterrupt):
            clk.sleep(0.01)


def test_a_virtual_run_switches_threads_seldom_and_gives_the_interval_back() -> None:
    """The recorder's writer took the GIL from the run every 5 ms; in virtual time nothing
    waits on a thread's latency (docs/performance.md, session 29)."""
    import dataclasses
    import sys

    from hil.bench.bench import load_bench
    from hil.plan.runner import VIRTUAL_SWITCH_INTERVAL_S, bench_clock

    before = sys.getswitchinterval()
    bench = load_bench(None)
    with bench_clock(dataclasses.replace(bench, clock="virtual")):
        assert abs(sys.getswitchinterval() - VIRTUAL_SWITCH_INTERVAL_S) < 1e-6
    assert sys.getswitchinterval() == before
    with bench_clock(dataclasses.replace(bench, clock="real")):
        assert sys.getswitchinterval() == before  # a real-time run keeps Python's
