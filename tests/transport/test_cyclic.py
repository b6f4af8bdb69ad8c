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


def _virtual_stack(c, tapped_frames):
    """A virtual bus as a session opens it: the sim bus, the fault layer, the recording tap."""
    from hil.transport.can_bus import TappedBus, open_can
    from hil.transport.faults import FaultyCanBus

    class Tap:
        def can(self, _bus, frame, direction, t, _source_t):
            tapped_frames.append((frame.arbitration_id, direction, t))

    raw = open_can("virtual:cyc-v")
    return raw, TappedBus(FaultyCanBus(raw, "can0"), Tap(), "can0")


@pytest.mark.parametrize("layer", ["sim", "session"])
def test_send_periodic_on_the_virtual_clock_sends_on_period_in_bench_time(layer):
    """python-can's `send_periodic` is a wall-clock thread: on the virtual bench its frames
    came at wall instants (none in 0.1 s of bench time, all of them later at once)."""
    from hil import clock
    from hil.clock import VirtualClock
    from hil.transport.can_bus import open_can
    from hil.transport.sim import frame_bits, pump

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        tapped: list = []
        raw, session_bus = _virtual_stack(c, tapped)
        sender = raw if layer == "sim" else session_bus
        peer = open_can("virtual:cyc-v")
        got: list[tuple[int, bytes]] = []
        pump(peer, lambda m: got.append((c.time_ns(), bytes(m.data))))
        counter = [0]

        def bump(msg: can.Message) -> None:  # the callback sets each frame's data
            counter[0] += 1
            msg.data = bytearray([counter[0]])

        msgs = [can.Message(arbitration_id=0x80, data=b"\x00", is_extended_id=False),
                can.Message(arbitration_id=0x80, data=b"\x00", is_extended_id=False)]
        task = sender.send_periodic(msgs, 0.010, duration=0.095, modifier_callback=bump)
        clock.sleep(0.2)
        def wire(k: int) -> int:  # the k-th frame's bit time at 1 Mbit/s (its stuff bits)
            return frame_bits(can.Message(arbitration_id=0x80, data=bytes([k + 1]),
                                          is_extended_id=False)) * 1000

        # the first at once, then every 10 ms of bench time, until 95 ms: 0..90 ms
        assert [t for t, _ in got] == [k * 10_000_000 + wire(k) for k in range(10)]
        assert [d for _, d in got] == [bytes([k + 1]) for k in range(10)]
        assert task.stopped
        if layer == "session":  # through the tap: on the recording, at the send's time
            assert [t for i, d, t in tapped if d == "tx"] == [k * 10_000_000 for k in range(10)]
        task.start()  # restartable, as python-can's
        clock.sleep(0.025)
        assert len(got) == 13
        task.stop()
        clock.sleep(0.1)
        assert len(got) == 13
        for bus in (session_bus, peer):
            bus.shutdown()


def test_send_periodic_on_the_wall_clock_is_python_cans_own():
    from hil.transport.can_bus import TappedBus, open_can

    class Tap:
        def can(self, *_a):
            pass

    bus = TappedBus(open_can("virtual:cyc-real"), Tap(), "can0")
    peer = open_can("virtual:cyc-real")
    try:
        task = bus.send_periodic(can.Message(arbitration_id=0x80, data=b""), 0.01)
        assert isinstance(task, can.broadcastmanager.ThreadBasedCyclicSendTask)
        assert peer.recv(1.0) is not None and peer.recv(1.0) is not None
        task.stop()
    finally:
        bus.shutdown()
        peer.shutdown()


def test_a_failing_periodic_send_stops_and_fails_the_runs_wait():
    """python-can's task raises a send error in its own thread (pytest only warns); on the
    virtual clock the error is raised where the run waits, and the task stops."""
    from hil import clock
    from hil.clock import VirtualClock
    from hil.transport.can_bus import open_can

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        bus = open_can("virtual:cyc-err")
        calls = [0]

        def bug(_msg: can.Message) -> None:
            calls[0] += 1
            if calls[0] == 3:
                raise ValueError("modifier bug")

        task = bus.send_periodic(can.Message(arbitration_id=0x80, data=b""), 0.01,
                                 modifier_callback=bug)
        with pytest.raises(ValueError, match="modifier bug"):
            clock.sleep(0.1)
        assert c.time_ns() == 20_000_000 and task.stopped
        assert isinstance(task.error, ValueError)
        clock.sleep(0.1)
        assert calls[0] == 3  # stopped: no more sends
        bus.shutdown()


def test_a_periodic_failure_is_not_raised_by_another_send():
    """The task's error comes out of the run's next wait, not out of a send whose settle ran
    the failing tick: that send's frame went out, and canopen would take the error for its
    own (an SDO request on the wire, the transfer failed)."""
    from hil import clock
    from hil.clock import VirtualClock
    from hil.transport.can_bus import open_can
    from hil.transport.sim import pump

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b, d = (open_can("virtual:cyc-other") for _ in range(3))
        heard: list[int] = []
        pump(d, lambda m: heard.append(m.arbitration_id))

        def bug(_msg: can.Message) -> None:
            if c.time_ns() >= 10_000_000:
                raise ValueError("modifier bug")

        a.send_periodic(can.Message(arbitration_id=0x80, data=b""), 0.01, modifier_callback=bug)
        clock.sleep(0.0099)
        b.send(can.Message(arbitration_id=0x605, data=bytes(8)))  # its settle runs the tick
        assert heard[-1] == 0x605
        with pytest.raises(ValueError, match="modifier bug"):
            clock.sleep(0.01)
        for bus in (a, b, d):
            bus.shutdown()
