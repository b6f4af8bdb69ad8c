"""The cyclic producer (SYNC, heartbeat, guarding): a late wake-up restarts the cycle, it
never sends the missed frames in a burst (python-can's send_periodic does, which a drive
reads as an early SYNC, AL3E2 L20159-20163)."""

from __future__ import annotations

import threading
import time

import can
import pytest

from hil.transport.cyclic import CyclicSender

PERIOD = 0.020


class StallingBus(can.BusABC):
    """Records send times; the `stall_at`-th send blocks the producer for `stall` s."""

    def __init__(self, stall_at: int, stall: float) -> None:
        self.times: list[int] = []
        self.stall_at, self.stall = stall_at, stall
        self.done = threading.Event()
        super().__init__(channel="stall")

    def send(self, msg, timeout=None):
        self.times.append(time.perf_counter_ns())
        if len(self.times) == self.stall_at:
            time.sleep(self.stall)  # the host descheduled the producer
        if len(self.times) >= 12:
            self.done.set()

    def _recv_internal(self, timeout):
        return None, False


def test_a_stalled_producer_restarts_its_cycle_without_a_burst():
    bus = StallingBus(stall_at=4, stall=0.065)  # 3 periods + 5 ms late
    lates: list[int] = []
    sync = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
    task = CyclicSender(bus, sync, PERIOD, on_late=lates.append)
    try:
        assert bus.done.wait(2.0)
    finally:
        task.stop()
    gaps = [(b - a) / 1e6 for a, b in zip(bus.times, bus.times[1:], strict=False)]
    assert max(gaps) >= 60  # the stall itself: one long interval, as a stalled master
    # never a short one: at least (1 - 0.25) x period, less a little for the send itself
    assert min(gaps) >= 0.75 * PERIOD * 1e3 - 3, gaps
    assert task.rephased >= 1 and lates and max(lates) >= 40e6


def test_stop_ends_the_thread_and_a_closed_bus_ends_the_producer():
    bus = StallingBus(stall_at=0, stall=0)
    task = CyclicSender(bus, can.Message(arbitration_id=0x80), PERIOD)
    time.sleep(0.05)
    task.stop()
    n = len(bus.times)
    time.sleep(0.05)
    assert len(bus.times) == n and not task._thread.is_alive()

    class Closed(StallingBus):
        def send(self, msg, timeout=None):
            raise can.CanOperationError("bus is shut down")

    gone = CyclicSender(Closed(0, 0), can.Message(arbitration_id=0x80), PERIOD)
    gone._thread.join(1.0)
    assert not gone._thread.is_alive() and gone.sent == 0
    with pytest.raises(ValueError, match="must be > 0"):
        CyclicSender(bus, can.Message(arbitration_id=0x80), 0)
