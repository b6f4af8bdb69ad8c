"""In-process buses on the virtual clock: CAN bit time and arbitration, RS-485 char time.

Frame lengths are written fresh from ISO 11898-1 (classic base frame: SOF 1, identifier 11,
RTR 1, IDE 1, r0 1, DLC 4, data 8n, CRC 15 - stuffed after five equal bits - then CRC
delimiter 1, ACK 2, EOF 7 and intermission 3: 47 + 8n bits unstuffed).
"""

from __future__ import annotations

import itertools
import random

import can
import pytest

from hil import clock
from hil.clock import VirtualClock
from hil.transport.can_bus import open_can
from hil.transport.serial_line import open_serial
from hil.transport.sim import frame_bits, pump
from hil.units import MS


def _stuffed_reference(bits: str) -> int:
    """Stuff bits in a bit string: after five equal bits, one of the other value."""
    out, run, last = 0, 0, ""
    for b in bits:
        if b == last:
            run += 1
        else:
            last, run = b, 1
        if run == 5:
            out += 1
            last, run = ("1" if b == "0" else "0"), 1
    return out


def test_frame_bits_without_and_with_stuffing() -> None:
    for n in range(9):
        msg = can.Message(arbitration_id=0x555, data=bytes([0x55] * n), is_extended_id=False)
        bits = frame_bits(msg)
        worst = (34 + 8 * n - 1) // 4  # the bound of stuff bits over SOF..CRC
        assert 47 + 8 * n <= bits <= 47 + 8 * n + worst
    # identifier 0 and zero data: long runs of dominant bits, so stuffing is certain
    zero = can.Message(arbitration_id=0, data=bytes(8), is_extended_id=False)
    assert frame_bits(zero) >= 47 + 64 + 10
    assert frame_bits(can.Message(is_error_frame=True)) == 17


def _reference_bits(msg: can.Message) -> int:
    """ISO 11898-1 bit by bit: SOF..data, CRC-15 (x^15+x^14+x^10+x^8+x^7+x^4+x^3+1) shifted
    one bit at a time, stuffing over SOF..CRC, then 13 fixed bits (delimiter, ACK, EOF,
    intermission)."""
    def field(v: int, n: int) -> str:
        return "".join(str((v >> (n - 1 - i)) & 1) for i in range(n))

    rtr = "1" if msg.is_remote_frame else "0"
    data = b"" if msg.is_remote_frame else bytes(msg.data)
    dlc = msg.dlc if msg.is_remote_frame else len(data)
    if msg.is_extended_id:
        head = ("0" + field(msg.arbitration_id >> 18, 11) + "11"
                + field(msg.arbitration_id & 0x3FFFF, 18) + rtr + "00")
    else:
        head = "0" + field(msg.arbitration_id, 11) + rtr + "00"
    body = head + field(dlc, 4) + "".join(field(b, 8) for b in data)
    crc = 0
    for b in body:
        top = (crc >> 14) & 1
        crc = (crc << 1) & 0x7FFF
        if top ^ int(b):
            crc ^= 0x4599
    body += field(crc, 15)
    return len(body) + _stuffed_reference(body) + 13


def test_frame_bits_match_a_bit_by_bit_reference_on_random_frames() -> None:
    rng = random.Random(7)
    for _ in range(3000):
        ext, rtr, n = rng.random() < 0.3, rng.random() < 0.1, rng.randint(0, 8)
        data = bytes(rng.choice([0, 0xFF, 0xF0, 0x0F, 0x1F, 0xF8, rng.randrange(256)])
                     for _ in range(n))
        msg = can.Message(arbitration_id=rng.randrange(1 << (29 if ext else 11)),
                          data=None if rtr else data, dlc=n, is_extended_id=ext,
                          is_remote_frame=rtr)
        assert frame_bits(msg) == _reference_bits(msg), msg


def test_a_frame_arrives_after_its_bit_time_and_arbitration_orders_waiting_frames() -> None:
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a = open_can("virtual:sim-t?bitrate=500000")
        b = open_can("virtual:sim-t")
        d = open_can("virtual:sim-t")
        got: list[tuple[int, int]] = []
        stop = pump(b, lambda m: got.append((m.arbitration_id, c.time_ns())))
        first = can.Message(arbitration_id=0x700, data=b"\x05", is_extended_id=False)
        high = can.Message(arbitration_id=0x601, data=bytes(8), is_extended_id=False)
        low = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)
        other = can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False)
        with clock.batch():  # all queued at one instant on an idle bus
            a.send(first)
            a.send(high)
            a.send(low)  # a's queue is first in, first out: 601h leaves before 080h
            d.send(other)  # another node: its head 181h wins against a's head, 700h
        bit = 1_000_000_000 // 500_000
        t1 = frame_bits(other) * bit
        t2 = t1 + frame_bits(first) * bit
        t3 = t2 + frame_bits(high) * bit
        t4 = t3 + frame_bits(low) * bit
        assert got == [(0x181, t1), (0x700, t2), (0x601, t3), (0x080, t4)]
        assert c.time_ns() == t4  # the send settled: nothing in flight
        stop()
        for bus in (a, b, d):
            bus.shutdown()


def test_only_a_virtual_can_url_opens_under_a_virtual_clock() -> None:
    from hil.transport.urls import TransportUrlError

    with clock.use(VirtualClock()), pytest.raises(TransportUrlError, match="--clock real"):
        open_can("zenoh:lab/x?connect=tcp/127.0.0.1:7447")


def test_rs485_characters_arrive_at_their_end_on_the_line(tmp_path) -> None:
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        drive = open_serial(f"pty:{tmp_path}/l1?baud=38400")
        master = open_serial(f"serial:{tmp_path}/l1?baud=38400")
        char = round(11 * 1e9 / 38400)  # start + 8 data + 2 stop (8N2, the A3 default)
        assert master.char_time_ns == char
        master.write(b"\x01\x03\x00\x00")
        frame = drive.read_timed(4, timeout=0.1)
        assert frame is not None and frame.data == b"\x01\x03\x00\x00"
        assert list(frame.times_ns) == [char * (i + 1) for i in range(4)]
        assert c.time_ns() == 4 * char  # handed over at the end of the last character
        assert drive.read(1, timeout=0.05) == b""
        assert c.time_ns() == 4 * char + 50_000_000
        master.close()
        drive.close()


def test_a_failing_receiver_neither_loses_the_frame_for_others_nor_stalls_the_bus() -> None:
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b, d = (open_can("virtual:sim-f") for _ in range(3))
        got: list[int] = []

        def boom(_m: can.Message) -> None:
            raise RuntimeError("receiver bug")

        pump(b, boom)
        pump(d, lambda m: got.append(m.arbitration_id))
        with clock.batch():
            a.send(can.Message(arbitration_id=0x100, data=b"", is_extended_id=False))
            a.send(can.Message(arbitration_id=0x200, data=b"", is_extended_id=False))
        assert got == [0x100, 0x200]  # the second frame still went on the wire
        assert len(b.errors) == 2 and d.errors == []
        for bus in (a, b, d):
            bus.shutdown()


def test_arbitration_compares_the_bits_in_wire_order() -> None:
    # ISO 11898-1: the base id first; a standard data frame (RTR 0) beats the extended frame
    # of the same base id (SRR 1), and beats its own RTR; an extended base id 1 beats a
    # standard id 2
    from hil.transport.sim import _arbitration_key as key

    def m(i: int, ext: bool = False, rtr: bool = False) -> can.Message:
        return can.Message(arbitration_id=i, is_extended_id=ext, is_remote_frame=rtr)

    assert key(m(0x001 << 18, ext=True)) < key(m(0x002))
    assert key(m(0x005)) < key(m(0x005 << 18, ext=True))
    assert key(m(0x005)) < key(m(0x005, rtr=True)) < key(m(0x005 << 18, ext=True))
    assert key(m(0x005 << 18 | 7, ext=True)) < key(m(0x005 << 18 | 7, ext=True, rtr=True))


def test_a_delivered_frame_is_what_python_can_makes_of_the_sent_one() -> None:
    """Each receiver gets its own frame with the fields `can.Message` gives them: data a
    bytearray of its own (empty for a remote frame), the DLC as sent, classic CAN flags."""
    rnd = random.Random(7)
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b, d = (open_can("virtual:sim-copy") for _ in range(3))
        got_b: list[can.Message] = []
        got_d: list[can.Message] = []
        pump(b, got_b.append)
        pump(d, got_d.append)
        sent = []
        for _ in range(200):
            ext, rtr = rnd.random() < 0.3, rnd.random() < 0.2
            data = bytes(rnd.randrange(256) for _ in range(rnd.randrange(9)))
            msg = can.Message(arbitration_id=rnd.randrange(1 << (29 if ext else 11)),
                              is_extended_id=ext, is_remote_frame=rtr, data=data,
                              dlc=rnd.randrange(9) if rtr else len(data))
            sent.append(msg)
            a.send(msg)
        assert len(got_b) == len(got_d) == len(sent)
        for msg, rb, rd in zip(sent, got_b, got_d, strict=True):
            ref = can.Message(arbitration_id=msg.arbitration_id, data=bytes(msg.data),
                              is_extended_id=msg.is_extended_id,
                              is_remote_frame=msg.is_remote_frame, dlc=msg.dlc)
            for got in (rb, rd):
                assert got.equals(ref, timestamp_delta=None, check_channel=False)
                assert type(got.data) is bytearray and got.is_rx and not got.is_fd
                assert not got.bitrate_switch and not got.error_state_indicator
                assert got.sender_time_ns is not None and got.timestamp * 1e9 >= got.sender_time_ns
            assert rb.data is not rd.data  # canopen writes into a PDO's buffer: one each
        for bus in (a, b, d):
            bus.shutdown()


def _tapped(tap) -> list[tuple[int, str]]:
    """(identifier, direction) of each frame the recording tap (conftest's) was given."""
    return [(frame.arbitration_id, direction) for _bus, frame, direction, _t, _s
            in tap.can_frames]


@pytest.mark.parametrize("tapped", [False, True])
def test_a_filtered_recv_waits_its_timeout_in_bench_time(tapped, tap) -> None:
    """python-can's `BusABC.recv` counts its timeout in wall seconds: on the virtual clock a
    filtered `recv(0.5)` that saw no match ran on for hours of bench time."""
    from hil.transport.can_bus import TappedBus

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a = open_can("virtual:sim-r")
        raw = open_can("virtual:sim-r")
        b = TappedBus(raw, tap, "can0") if tapped else raw
        b.set_filters([{"can_id": 0x181, "can_mask": 0x7FF}])
        assert b.recv(0.5) is None
        assert c.time_ns() == 500_000_000  # no traffic: the timeout, no more

        heartbeat = can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)
        tpdo = can.Message(arbitration_id=0x181, data=b"\x27\x06", is_extended_id=False)

        def beat() -> None:  # other traffic every 10 ms: read and dropped by the filter
            a.send(heartbeat)
            clock.call_later(0.01, beat)

        clock.call_later(0.01, beat)
        assert b.recv(0.2) is None
        assert c.time_ns() == 700_000_000
        clock.call_later(0.035, a.send, tpdo)  # the match comes 35 ms on, after its wire time
        got = b.recv(0.2)
        assert got is not None and got.arbitration_id == 0x181 and bytes(got.data) == b"\x27\x06"
        assert c.time_ns() == 735_000_000 + frame_bits(tpdo) * 1000  # 1 Mbit/s: 1000 ns a bit
        if tapped:  # the recording has what arrived, the dropped frames too
            frames = _tapped(tap)
            assert frames[-1] == (0x181, "rx") and (0x701, "rx") in frames
        for bus in (a, b):
            bus.shutdown()


def test_recv_0_reads_past_frames_the_filter_drops() -> None:
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b = open_can("virtual:sim-z"), open_can("virtual:sim-z")
        b.set_filters([{"can_id": 0x181, "can_mask": 0x7FF}])
        with clock.batch():
            a.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
            a.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
        now = c.time_ns()
        got = b.recv(0)
        assert got is not None and got.arbitration_id == 0x181  # queued behind a dropped one
        assert b.recv(0) is None and c.time_ns() == now
        for bus in (a, b):
            bus.shutdown()


def test_another_thread_reading_or_sending_never_moves_bench_time() -> None:
    """A test's own thread (a python-can Notifier) on a virtual bus: it waits in wall time for
    what the run's thread delivers, and its sends go on the wire when the run next waits.
    Before, its `recv(1.0)` fired the run's events from that thread: bench time moved by
    some 60 s while the test slept half a second."""
    import threading
    import time

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b = open_can("virtual:sim-o"), open_can("virtual:sim-o")
        ticks: list[int] = []

        def tick() -> None:  # the run's own events: a heartbeat every 10 ms
            ticks.append(c.time_ns())
            a.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
            clock.call_later(0.01, tick)

        clock.call_later(0.0, tick)
        got: list[tuple[int, int]] = []
        sent = threading.Event()

        def notifier() -> None:
            for _ in range(3):
                m = b.recv(2.0)  # wall seconds: the run's thread delivers
                if m is not None:
                    got.append((m.arbitration_id, c.time_ns()))
            b.send(can.Message(arbitration_id=0x181, data=b"\x01", is_extended_id=False))
            sent.set()
            with pytest.raises(RuntimeError, match="not the run's"):
                clock.sleep(0.1)  # bench time is the run's to move

        th = threading.Thread(target=notifier, name="notifier")
        th.start()
        time.sleep(0.2)
        assert c.time_ns() == 0 and ticks == []  # nothing moved while the run only slept
        while len(got) < 3:
            clock.sleep(0.01)
            time.sleep(0.001)
        assert sent.wait(5)
        th.join(5)
        mark = c.time_ns()
        heard: list[int] = []
        pump(a, lambda m: heard.append(m.arbitration_id))
        clock.sleep(0.001)
        assert 0x181 in heard  # the other thread's frame, delivered once the run waited
        assert [cid for cid, _ in got] == [0x701] * 3
        assert all(t <= mark for _, t in got)
        for bus in (a, b):
            bus.shutdown()


def test_a_listener_added_to_the_pump_hears_the_bus() -> None:
    """python-can's `Notifier.add_listener` on a session network's pump (`net.notifier`):
    the way for a test to hear the frames the harness's bus receives."""
    from hil.transport.sim import ListenerPump

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b = open_can("virtual:sim-l"), open_can("virtual:sim-l")
        pump_b = ListenerPump(b, [])
        reader = can.BufferedReader()
        pump_b.add_listener(reader)
        a.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))
        got = reader.get_message(0)
        assert got is not None and got.arbitration_id == 0x701
        pump_b.remove_listener(reader)
        a.send(can.Message(arbitration_id=0x702, data=b"\x05", is_extended_id=False))
        assert reader.get_message(0) is None
        for bus in (a, b):
            bus.shutdown()


def test_frames_queued_at_one_instant_on_an_idle_bus_go_by_arbitration() -> None:
    """Every node with a frame pending at the start of frame arbitrates (ISO 11898-1),
    whichever of them queued it first in the clock's order: 080h, then 300h, then 701h.
    Before, the first one queued took the idle bus at once (300h first)."""
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b, d, s = (open_can("virtual:sim-i?bitrate=500000") for _ in range(4))
        got: list[tuple[int, int]] = []
        pump(s, lambda m: got.append((m.arbitration_id, c.time_ns())))
        f300 = can.Message(arbitration_id=0x300, data=bytes(8), is_extended_id=False)
        f701 = can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False)
        f080 = can.Message(arbitration_id=0x080, data=b"", is_extended_id=False)
        c.at(1_000_000, lambda: d.send(f300))
        c.at(1_000_000, lambda: a.send(f701))
        c.at(1_000_000, lambda: b.send(f080))
        clock.sleep(0.01)
        bit = 2000  # ns at 500 kbit/s
        t1 = 1_000_000 + frame_bits(f080) * bit
        t2 = t1 + frame_bits(f300) * bit
        assert got == [(0x080, t1), (0x300, t2), (0x701, t2 + frame_bits(f701) * bit)]
        for bus in (a, b, d, s):
            bus.shutdown()


def test_a_classic_bus_refuses_can_fd_and_long_frames(tap) -> None:
    """... and the recording tap does not record a refused frame as sent."""
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b = open_can("virtual:sim-fd", tap=tap, name="can0"), open_can("virtual:sim-fd")
        for bad in (can.Message(arbitration_id=0x100, data=bytes(64), is_fd=True,
                                is_extended_id=False),
                    can.Message(arbitration_id=0x100, data=bytes(2), is_fd=True,
                                is_extended_id=False),
                    can.Message(arbitration_id=0x100, data=bytes(12), is_extended_id=False,
                                check=False)):
            with pytest.raises(can.CanOperationError, match="classic CAN"):
                a.send(bad)
        assert b.recv(0.01) is None and c.time_ns() == 10_000_000  # nothing went on the wire
        assert _tapped(tap) == []  # nor on the record
        a.send(can.Message(arbitration_id=0x100, data=bytes(8), is_extended_id=False))
        assert b.recv(0.01) is not None  # the bus is still fine
        assert _tapped(tap) == [(0x100, "tx")]
        for bus in (a, b):
            bus.shutdown()


def test_a_frame_is_never_early_at_a_rate_that_does_not_divide_a_second() -> None:
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b = open_can("virtual:sim-333?bitrate=333333"), open_can("virtual:sim-333")
        msg = can.Message(arbitration_id=0x181, data=b"\x01\x02", is_extended_id=False)
        a.send(msg)
        got = b.recv(0)
        assert got is not None
        exact = frame_bits(msg) * 1e9 / 333333  # a fraction of a ns over a whole one
        assert exact <= c.time_ns() < exact + 1
        for bus in (a, b):
            bus.shutdown()


def test_another_threads_send_while_the_run_waits_neither_stalls_the_bus_nor_hangs() -> None:
    """Another thread's send while the run's thread waits: it is handed over (never waiting
    for the clock's lock, which the run holds while it waits) and goes on the wire at the
    run's next pass. Before, it set the bus's "starting" flag and then blocked on the lock:
    the bus started no frame for the rest of the wait, and after 10 s of it the clock was
    hung for good. After the run, another thread still moves no bench time."""
    import threading
    import time

    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        a, b, d = (open_can("virtual:sim-h") for _ in range(3))
        got: list[tuple[int, int]] = []
        pump(d, lambda m: got.append((m.arbitration_id, c.time_ns())))
        task = a.send_periodic(can.Message(arbitration_id=0x181, data=b"\x01",
                                           is_extended_id=False), 0.001)
        started = threading.Event()

        def other() -> None:
            started.wait(5)
            b.send(can.Message(arbitration_id=0x701, data=b"\x05", is_extended_id=False))

        th = threading.Thread(target=other)
        th.start()
        c.at(1 * MS, started.set)  # the other thread sends while the run's wait goes on:
        c.at(2 * MS, lambda: time.sleep(0.2))  # an event that gives it the wall time to
        clock.sleep(2.0)
        deadline = time.monotonic() + 5
        while th.is_alive() and time.monotonic() < deadline:
            clock.sleep(0.05)
        th.join(5)
        clock.sleep(0.05)
        assert not th.is_alive() and not c.hung
        pdos = [t for cid, t in got if cid == 0x181]
        assert len(pdos) == round(c.time_ns() / MS)  # one every ms, none held back
        assert {b_ - a_ for a_, b_ in itertools.pairwise(pdos)} == {MS}
        assert [cid for cid, _ in got].count(0x701) == 1
        task.stop()
    ran = c.time_ns()

    def late_reader() -> None:  # a thread of a test's own, left running after the run
        d.recv(0.2)

    th = threading.Thread(target=late_reader)
    th.start()
    th.join(5)
    assert c.time_ns() == ran  # the finished run's time does not move
    for bus in (a, b, d):
        bus.shutdown()
