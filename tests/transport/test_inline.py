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


def _close(stops, *buses) -> None:
    for stop in stops:
        stop()
    for bus in buses:
        bus.shutdown()


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
        _close(stops, server, master, listener)


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
        _close(stops, bad, good, tx)


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

    with pytest.raises(TypeError, match="neither a python-can virtual bus nor"):
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


class _Hooked(can.BusABC):
    """A bus that calls back on each frame it queues (as ZenohBus.set_inline)."""

    def __init__(self) -> None:
        super().__init__(channel="hooked")
        self.q: list[can.Message] = []
        self.notify = None

    def set_inline(self, notify) -> None:
        self.notify = notify

    def pending(self) -> int:
        return len(self.q)

    def arrive(self, msg: can.Message) -> None:
        self.q.append(msg)
        if self.notify is not None:
            self.notify()

    def send(self, msg, timeout=None) -> None: ...

    def _recv_internal(self, timeout):
        return (self.q.pop(0) if self.q else None), False


def test_a_bus_with_set_inline_hands_frames_over_as_they_arrive_waiting_ones_first():
    bus = _Hooked()
    bus.arrive(_frame(1))  # before the pump
    got: list[int] = []
    stop = inline_pump(bus, lambda m: got.append(m.arbitration_id))
    assert got == [1]

    def reply_inside(m: can.Message) -> None:  # a frame arriving while one is handed over
        got.append(m.arbitration_id)
        if m.arbitration_id == 2:
            bus.arrive(_frame(3))
            assert got[-1] == 2  # not re-entered: 3 waits until 2 is done
    stop()
    stop = inline_pump(bus, reply_inside)
    bus.arrive(_frame(2))
    assert got == [1, 2, 3]
    stop()
    bus.arrive(_frame(4))
    assert got == [1, 2, 3] and bus.recv(0).arbitration_id == 4


def _pause_second_copy(monkeypatch, thread_name: str):
    """Pause `thread_name` inside its send, between two receivers' puts (a thread switch)."""
    import hil.transport.inline as il

    paused, go, n = threading.Event(), threading.Event(), [0]
    orig = il.copy_frame

    def copy_frame(*a):
        if threading.current_thread().name == thread_name:
            n[0] += 1
            if n[0] == 2:
                paused.set()
                go.wait(5)
        return orig(*a)

    monkeypatch.setattr(il, "copy_frame", copy_frame)
    return paused, go


def test_an_answer_never_overtakes_its_cause_when_another_thread_sends_meanwhile(
        ch, monkeypatch):
    """T2 is between two puts of its frame 0x100 when the main thread sends 0x300: R1's
    answer 0x200 to 0x100 still reaches R2 after 0x100 (found by review: it came first)."""
    s, r1, r2, x = _bus(ch), _bus(ch), _bus(ch), _bus(ch)
    got: list[int] = []
    stops = [inline_pump(r1, lambda m: m.arbitration_id == 0x100 and r1.send(_frame(0x200))),
             inline_pump(r2, lambda m: got.append(m.arbitration_id))]
    paused, go = _pause_second_copy(monkeypatch, "T2")
    t2 = threading.Thread(target=lambda: s.send(_frame(0x100)), name="T2")
    try:
        t2.start()
        assert paused.wait(5)
        threading.Timer(0.05, go.set).start()  # T2 goes on while the main thread sends
        x.send(_frame(0x300))
        t2.join(5)
        assert sorted(got) == [0x100, 0x200, 0x300]
        assert got.index(0x100) < got.index(0x200)
    finally:
        go.set()
        for stop in stops:
            stop()
        for bus in (s, r1, r2, x):
            bus.shutdown()


def test_a_frame_put_while_the_pump_is_installed_is_not_lost(ch, monkeypatch):
    s, r = _bus(ch), _bus(ch)
    paused, go = _pause_second_copy(monkeypatch, "T2")
    s2 = _bus(ch)  # a third queue, so T2's second copy is for r (after s2's)
    got: list[int] = []
    t2 = threading.Thread(target=lambda: s.send(_frame(0x701)), name="T2")
    try:
        t2.start()
        assert paused.wait(5)
        stop = inline_pump(r, lambda m: got.append(m.arbitration_id))
        go.set()
        t2.join(5)
        s.send(_frame(0x702))
        assert got == [0x701, 0x702]
        stop()
    finally:
        go.set()
        for bus in (s, r, s2):
            bus.shutdown()


def test_after_stop_the_receiver_gets_nothing_and_frames_wait_for_recv(ch):
    a, b, tx = _bus(ch), _bus(ch), _bus(ch)
    got: list[tuple[str, int]] = []
    stop_b: list = []

    def on_a(m: can.Message) -> None:  # handed over first: stops b before b's turn
        got.append(("a", m.arbitration_id))
        if stop_b:
            stop_b.pop()()

    stop_a = inline_pump(a, on_a)
    stop_b.append(inline_pump(b, lambda m: got.append(("b", m.arbitration_id))))
    try:
        tx.send(_frame(0x80))
        assert got == [("a", 0x80)]
        assert b.recv(1).arbitration_id == 0x80  # left for recv, not lost
    finally:
        stop_a()
        for bus in (a, b, tx):
            bus.shutdown()


def test_ctrl_c_inside_a_hand_over_reaches_the_sender_and_the_channel_goes_on(ch):
    """A KeyboardInterrupt raised while the main thread hands a frame over propagates to its
    send; the next frames are handed over, none lost, none a frame behind."""
    tx, rx = _bus(ch), _bus(ch)
    got: list[int] = []
    fire = [True]

    def handler(m: can.Message) -> None:
        if fire[0] and m.arbitration_id == 1:
            fire[0] = False
            raise KeyboardInterrupt
        got.append(m.arbitration_id)

    stop = inline_pump(rx, handler)
    try:
        tx.send(_frame(0))
        with pytest.raises(KeyboardInterrupt):
            tx.send(_frame(1))
        tx.send(_frame(2))
        assert got == [0, 2]  # 1 was being handled when Ctrl-C came: not handed again
        tx.send(_frame(3))
        assert got == [0, 2, 3]
    finally:
        stop()
        tx.shutdown()
        rx.shutdown()


def test_a_held_burst_reaches_the_receiver_only_after_its_last_frame_is_put(ch):
    """`hold`: a master's burst goes on the channel back to back; the receiver is handed
    the frames at the end, in order (the drive sees them all before it answers any)."""
    from hil.transport.inline import hold

    tx, rx = _bus(ch), _bus(ch)
    got: list[int] = []
    stop = inline_pump(rx, lambda m: got.append(m.data[0]))
    try:
        with hold(tx):
            for k in range(3):
                tx.send(_frame(0x601, bytes([k])))
            assert got == []
        assert got == [0, 1, 2]
        tx.send(_frame(0x601, b"\x03"))  # after the hold: at once again
        assert got == [0, 1, 2, 3]
    finally:
        stop()
        tx.shutdown()
        rx.shutdown()


@pytest.mark.parametrize("seed", range(6))
def test_fuzz_threads_receivers_answers_and_a_sniffer(seed):
    """Random senders in threads, inline receivers that answer some frames (an answer names
    its cause in its data), one receiver installed while frames fly, a plain sniffer: every
    receiver gets every frame not its own exactly once; each sender's frames in its order;
    at every receiver an answer comes after its cause; handlers never overlap."""
    import random
    import sys

    rng = random.Random(seed)
    ch = f"inline-fuzz-{seed}-{next(_chan)}"
    n_rx, n_tx, per = rng.randint(2, 4), rng.randint(2, 3), rng.randint(100, 200)
    interval = sys.getswitchinterval()
    sys.setswitchinterval(1e-6)  # threads switch between almost any two bytecodes
    rxs = [_bus(ch) for _ in range(n_rx)]
    txs = [_bus(ch) for _ in range(n_tx)]
    sniffer = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    seen: list[list[tuple[int, int, int]]] = [[] for _ in rxs]  # (cob, origin, seq)
    active, overlap = [0], [0]
    answers = {i: rng.random() < 0.5 for i in range(n_rx)}

    def handler(i: int):
        def fn(m: can.Message) -> None:
            active[0] += 1
            overlap[0] = max(overlap[0], active[0])
            cob, origin, seq = m.arbitration_id, m.data[0], int.from_bytes(m.data[1:3], "big")
            seen[i].append((cob, origin, seq))
            if answers[i] and cob < 0x500 and rng.random() < 0.3:
                rxs[i].send(_frame(0x580 + i, bytes([origin]) + seq.to_bytes(2, "big")
                                   + bytes([cob & 0xFF])))
            active[0] -= 1
        return fn

    late = rng.randrange(n_rx)
    stops = [inline_pump(rx, handler(i)) for i, rx in enumerate(rxs) if i != late]

    def sender(k: int) -> None:
        for seq in range(per):
            txs[k].send(_frame(0x100 + k, bytes([k]) + seq.to_bytes(2, "big")))
            if rng.random() < 0.2:
                time.sleep(0.0002)

    threads = [threading.Thread(target=sender, args=(k,)) for k in range(n_tx)]
    try:
        for t in threads:
            t.start()
        time.sleep(0.001)
        stops.append(inline_pump(rxs[late], handler(late)))  # installed while frames fly
        for t in threads:
            t.join(10)
        sent = {(0x100 + k, k, s) for k in range(n_tx) for s in range(per)}
        for i, got in enumerate(seen):
            requests = [g for g in got if g[0] < 0x500]
            # exactly once each (the late receiver too: what waited in python-can's queue
            # before its pump is handed over first, what came after through the pump)
            assert sorted(requests) == sorted(sent), (i, late, sorted(set(sent) - set(requests)))
            for k in range(n_tx):
                mine = [s for c, o, s in requests if o == k]
                assert mine == sorted(mine), (i, k)  # each sender's order
            for pos, (cob, origin, seq) in enumerate(got):
                if cob >= 0x580:  # an answer: its cause came before it at this receiver
                    cause = (0x100 + origin, origin, seq)
                    assert cause in got[:pos], (i, cob, cause)
        assert overlap[0] == 1
        sniffed = []
        while (m := sniffer.recv(0)) is not None:
            sniffed.append(m.arbitration_id)
        assert sniffed.count(0x100) == per
    finally:
        sys.setswitchinterval(interval)
        _close(stops, *rxs, *txs, sniffer)
