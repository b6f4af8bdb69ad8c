"""In-process CAN delivery in the sender's thread (hil.transport.inline)."""

from __future__ import annotations

import itertools
import threading
import time

import can
import pytest

from hil.transport.can_bus import open_can
from hil.transport.inline import inline_pump

_chan = itertools.count()


def _bus(ch: str) -> can.BusABC:
    """What `open_can` gives for `virtual:<ch>` on the wall clock."""
    return open_can(f"virtual:{ch}")


def _frame(cid: int, data: bytes = b"") -> can.Message:
    return can.Message(arbitration_id=cid, data=data, is_extended_id=False)


@pytest.fixture
def ch():
    return f"inline-{next(_chan)}"


def test_a_frame_is_handed_over_before_send_returns_in_the_senders_thread(ch):
    rx, tx = _bus(ch), _bus(ch)
    got: list[tuple[int, int]] = []
    stop = inline_pump(rx, lambda m: got.append((m.arbitration_id, threading.get_ident())))
    try:
        tx.send(_frame(0x80))
        assert got == [(0x80, threading.get_ident())]
        assert rx.recv(0) is None  # handed over, not left waiting
    finally:
        stop()
        rx.shutdown()
        tx.shutdown()


def test_answers_come_in_order_and_no_receiver_is_re_entered(ch):
    """A server answers every request on the bus; a listener sees each request before its
    answer, and the server's handler is never entered while it runs."""
    server, master, listener = _bus(ch), _bus(ch), _bus(ch)
    depth, deepest, seen = [0], [0], []

    def serve(m: can.Message) -> None:
        depth[0] += 1
        deepest[0] = max(deepest[0], depth[0])
        if m.arbitration_id == 0x601:
            server.send(_frame(0x581, m.data))
            server.send(_frame(0x181, m.data))  # a second frame from inside the handler
        depth[0] -= 1

    stops = [inline_pump(server, serve),
             inline_pump(listener, lambda m: seen.append((m.arbitration_id, bytes(m.data))))]
    try:
        for k in range(3):
            master.send(_frame(0x601, bytes([k])))
        assert seen == [x for k in range(3) for x in
                        ((0x601, bytes([k])), (0x581, bytes([k])), (0x181, bytes([k])))]
        assert deepest[0] == 1
    finally:
        for s in stops:
            s()
        for b in (server, master, listener):
            b.shutdown()


def test_threads_sending_at_once_each_frame_handed_over_once_receivers_one_at_a_time(ch):
    rx, a, b = _bus(ch), _bus(ch), _bus(ch)
    active, overlap, got = [0], [0], []
    guard = threading.Lock()

    def slow(m: can.Message) -> None:
        with guard:
            active[0] += 1
            overlap[0] = max(overlap[0], active[0])
        time.sleep(0.0002)
        got.append((m.arbitration_id, m.data[0]))
        with guard:
            active[0] -= 1

    stop = inline_pump(rx, slow)

    def sender(bus: can.BusABC, cid: int) -> None:
        for k in range(200):
            bus.send(_frame(cid, bytes([k])))

    threads = [threading.Thread(target=sender, args=(bus, cid))
               for bus, cid in ((a, 0x100), (b, 0x200))]
    try:
        for t in threads:
            t.start()
        for t in threads:
            t.join(10)
        assert sorted(got) == sorted((cid, k) for cid in (0x100, 0x200) for k in range(200))
        for cid in (0x100, 0x200):  # each sender's frames in its order
            assert [k for c, k in got if c == cid] == list(range(200))
        assert overlap[0] == 1
    finally:
        stop()
        for bus in (rx, a, b):
            bus.shutdown()


def test_a_thread_reading_with_python_cans_queue_sees_the_same_frames(ch):
    rx, tx = _bus(ch), _bus(ch)
    sniffer = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    got: list[int] = []
    stop = inline_pump(rx, lambda m: rx.send(_frame(0x580 + m.arbitration_id - 0x600)))
    inline_pump_b = inline_pump(tx, lambda m: got.append(m.arbitration_id))
    try:
        tx.send(_frame(0x605))
        assert got == [0x585]
        ids = [sniffer.recv(1).arbitration_id for _ in range(2)]
        assert ids == [0x605, 0x585]
    finally:
        stop()
        inline_pump_b()
        for bus in (rx, tx, sniffer):
            bus.shutdown()


def test_a_failing_receiver_loses_nothing_for_the_others(ch, caplog):
    bad, good, tx = _bus(ch), _bus(ch), _bus(ch)
    got: list[int] = []

    def boom(m: can.Message) -> None:
        raise RuntimeError("receiver bug")

    stops = [inline_pump(bad, boom), inline_pump(good, lambda m: got.append(m.arbitration_id))]
    try:
        for cid in (1, 2, 3):
            tx.send(_frame(cid))
        assert got == [1, 2, 3]
        assert "receiver bug" in caplog.text
        tx.send(_frame(4))  # the courier is free again after the errors
        assert got == [1, 2, 3, 4]
    finally:
        for s in stops:
            s()
        for bus in (bad, good, tx):
            bus.shutdown()


def test_frames_waiting_before_go_first_and_after_stop_frames_wait_for_recv(ch):
    rx, tx = _bus(ch), _bus(ch)
    tx.send(_frame(1))
    got: list[int] = []
    stop = inline_pump(rx, lambda m: got.append(m.arbitration_id))
    assert got == [1]
    tx.send(_frame(2))
    stop()
    tx.send(_frame(3))
    assert got == [1, 2]
    assert rx.recv(1).arbitration_id == 3
    rx.shutdown()
    tx.shutdown()


def test_no_deadlock_when_a_receiver_takes_a_lock_the_next_sender_holds(ch):
    """Thread A hands a frame to a receiver that takes lock L; thread B holds L while it
    sends: B's frame is left to A, B goes on and lets L go, and both finish."""
    rx, a, b = _bus(ch), _bus(ch), _bus(ch)
    lock = threading.Lock()
    in_handler = threading.Event()
    got: list[int] = []

    def handler(m: can.Message) -> None:
        in_handler.set()
        with lock:
            got.append(m.arbitration_id)

    stop = inline_pump(rx, handler)
    done = threading.Event()

    def thread_b() -> None:
        with lock:
            in_handler.wait(5)
            b.send(_frame(0x2))
        done.set()

    tb = threading.Thread(target=thread_b)
    try:
        tb.start()
        time.sleep(0.01)  # B holds L
        a.send(_frame(0x1))  # A hands 0x1 over: waits for L, then hands over B's 0x2
        assert done.wait(5)
        tb.join(5)
        assert got == [0x1, 0x2]
    finally:
        stop()
        for bus in (rx, a, b):
            bus.shutdown()


class _Rec:
    def __init__(self) -> None:
        self.lines: list[tuple[int, str]] = []

    def can(self, bus, msg, direction, t_ns, source_ns) -> None:
        self.lines.append((msg.arbitration_id, direction))


def test_a_tapped_senders_request_is_recorded_before_the_answer_it_caused(ch):
    rec = _Rec()
    master = open_can(f"virtual:{ch}", tap=rec, name="can0")
    server = _bus(ch)
    stops = [inline_pump(server, lambda m: server.send(_frame(0x581, m.data))),
             inline_pump(master, lambda m: None)]
    try:
        master.send(_frame(0x601, b"\x40"))
        assert rec.lines == [(0x601, "tx"), (0x581, "rx")]
    finally:
        for s in stops:
            s()
        master.shutdown()
        server.shutdown()


def test_inline_pump_refuses_a_bus_that_is_not_python_cans_virtual():
    class Other(can.BusABC):
        def __init__(self) -> None:
            super().__init__(channel="x")

        def send(self, msg, timeout=None): ...

        def _recv_internal(self, timeout):
            return None, False

    with pytest.raises(TypeError, match="not a python-can virtual bus"):
        inline_pump(Other(), lambda m: None)


def test_a_frames_copy_is_what_python_cans_virtual_bus_makes_of_it():
    """`copy_frame` against `VirtualBus.send`'s own deepcopy, on random frames."""
    import copy
    import random

    from hil.transport.inline import copy_frame

    rng = random.Random(7)
    for _ in range(300):
        ext, fd = rng.random() < 0.3, rng.random() < 0.2
        rtr = not fd and rng.random() < 0.1
        n = rng.choice((0, 1, 8, 12, 64)) if fd else (0 if rtr else rng.randint(0, 8))
        msg = can.Message(arbitration_id=rng.randrange(1 << (29 if ext else 11)),
                          is_extended_id=ext, is_remote_frame=rtr, is_fd=fd,
                          bitrate_switch=fd and rng.random() < 0.5,
                          error_state_indicator=fd and rng.random() < 0.5,
                          dlc=rng.randint(0, 8) if rtr else None,
                          data=bytes(rng.randrange(256) for _ in range(n)),
                          timestamp=rng.random(), channel="x")
        msg.is_error_frame = rng.random() < 0.05
        want = copy.deepcopy(msg)
        want.timestamp, want.channel, want.is_rx = 12.5, "chan", True
        got = copy_frame(msg, bytes(msg.data), 12.5, "chan", True)
        for slot in can.Message.__slots__[1:]:
            assert getattr(got, slot) == getattr(want, slot), slot
        assert type(got.data) is bytearray and got.data is not msg.data
