"""Serial lines: pty with emulated line timing, pyserial parameters, zenoh with timing."""

from __future__ import annotations

import os
import time
from typing import ClassVar

import pytest
import serial

from hil.transport import serial_line
from hil.transport.serial_line import SerialFrame, open_serial, pack_chunk, unpack_chunk
from hil.transport.urls import TransportUrlError

pytestmark = pytest.mark.timeout(30)

# Modbus RTU read request from the A3 manual's RTU example: station 01, FC 03, 0200H, 2 words
READ_REQ = bytes.fromhex("010302000002c5b3")


@pytest.fixture
def pty_line(tmp_path):
    lines = []

    def make(query: str = "baud=9600&stopbits=1", **kw):
        line = open_serial(f"pty:{tmp_path / 'ttyA'}?{query}", **kw)
        lines.append(line)
        return line

    yield make
    for line in lines:
        line.close()


@pytest.fixture
def far_end(tmp_path):
    ports = []

    def open_far(**kw):
        p = serial.Serial(str(tmp_path / "ttyA"), timeout=2, **kw)
        ports.append(p)
        return p

    yield open_far
    for p in ports:
        p.close()


def test_pty_link_created_and_removed(pty_line, tmp_path):
    link = tmp_path / "ttyA"
    line = pty_line()
    assert link.is_symlink() and os.readlink(link).startswith("/dev/pts/")
    assert line.device == os.readlink(link)
    line.close()
    assert not os.path.lexists(link)
    line.close()  # idempotent


def test_pty_refuses_to_replace_a_file(tmp_path):
    (tmp_path / "ttyA").write_text("not a tty")
    with pytest.raises(TransportUrlError, match="exists and is not a symlink"):
        open_serial(f"pty:{tmp_path / 'ttyA'}")


def test_pty_missing_directory(tmp_path):
    with pytest.raises(TransportUrlError, match="does not exist"):
        open_serial(f"pty:{tmp_path / 'nope' / 'ttyA'}")


def test_char_time(pty_line):
    line = pty_line("baud=9600&stopbits=1")
    assert line.baudrate == 9600
    assert line.char_time_s == pytest.approx(10 / 9600)  # start + 8 data + stop
    assert line.t35_s == pytest.approx(3.5 * 10 / 9600)
    line.close()
    line = pty_line("baud=38400&parity=E")  # 8E2: 12 bits; > 19200 baud: t3.5 = 1.75 ms
    assert line.char_time_s == pytest.approx(12 / 38400)
    assert line.t35_s == pytest.approx(0.00175)


def test_pty_tx_takes_at_least_ten_char_times(pty_line, far_end):
    """At 9600 baud, 10 bytes reach the far end no sooner than 10 character times."""
    line = pty_line("baud=9600&stopbits=1")
    far = far_end()
    t0 = time.monotonic()
    frame = line.write(bytes(range(10)))
    got = far.read(10)
    elapsed = time.monotonic() - t0
    assert got == bytes(range(10))
    assert elapsed >= 10 * line.char_time_s
    assert elapsed < 10 * line.char_time_s + 1.0  # generous slack: property, not speed
    assert frame.t_end_ns - frame.t_start_ns == 10 * line.char_time_ns
    assert line.flush(1.0)


def test_pty_rx_is_stamped_and_gated_by_line_time(pty_line, far_end):
    line = pty_line("baud=9600&stopbits=1")
    far = far_end()
    t0 = time.monotonic_ns()
    far.write(READ_REQ)
    frame = line.read_frame(timeout=2)
    t_back = time.monotonic_ns()
    assert frame.data == READ_REQ
    c = line.char_time_ns
    assert frame.t_end_ns - frame.t_start_ns == len(READ_REQ) * c  # back to back
    assert frame.gaps_us == [0] * (len(READ_REQ) - 1)
    assert frame.t_start_ns >= t0
    # returned only after the request ended on the line plus t3.5 of silence
    assert t_back >= t0 + len(READ_REQ) * c + round(line.t35_s * 1e9)


def test_read_frame_splits_on_silence(pty_line, far_end):
    line = pty_line("baud=115200&stopbits=1")
    far = far_end()
    far.write(READ_REQ)
    far.flush()
    # the first frame ends at t3.5 (1.75 ms) of silence, not at the timeout; the next bytes
    # are written only once it has (a host that stalls the reader for longer than a fixed
    # pause between the writes would otherwise see them back to back, as one frame)
    t0 = time.monotonic()
    assert line.read_frame(timeout=2).data == READ_REQ
    assert time.monotonic() - t0 < 1.5
    far.write(b"\x02\x03")
    assert line.read_frame(timeout=2).data == b"\x02\x03"
    assert line.read_frame(timeout=0.05) is None


def test_round_trip_with_pyserial_slave_answer_not_before_t35(pty_line, far_end, tap):
    """We are the slave on the near end; pyserial (the master) opens the link path."""
    line = pty_line("baud=19200&parity=E&stopbits=1", tap=tap, name="rs485")
    far = far_end(baudrate=19200, parity="E")
    far.write(READ_REQ)
    req = line.read_frame(timeout=2)
    answer = bytes.fromhex("010304000100020a32")  # a 4-byte register reply
    sched = line.write(answer, not_before_ns=req.t_end_ns + round(line.t35_s * 1e9))
    assert far.read(len(answer)) == answer
    assert sched.t_start_ns - req.t_end_ns >= round(line.t35_s * 1e9)
    rx, tx = tap.serial_chunks
    assert (rx[0], rx[1], rx[2], tx[1], tx[2]) == ("rs485", READ_REQ, "rx", answer, "tx")
    assert rx[5] == [0] * (len(READ_REQ) - 1) and rx[4] is None
    assert tx[3] - rx[3] >= (len(READ_REQ) * line.char_time_ns + line.t35_s * 1e9) * 0.999


def test_read_returns_partial_on_timeout(pty_line, far_end):
    line = pty_line("baud=115200")
    far = far_end()
    far.write(b"\x55")
    assert line.read(4, timeout=0.2) == b"\x55"
    assert line.read(1, timeout=0.01) == b""
    timed = None
    far.write(b"\x01\x02")
    timed = line.read_timed(2, timeout=1)
    assert isinstance(timed, SerialFrame) and timed.data == b"\x01\x02"


def test_write_after_close_fails(pty_line):
    line = pty_line()
    line.close()
    with pytest.raises(OSError, match="closed"):
        line.write(b"\0")


class FakeSerial:
    instances: ClassVar[list[FakeSerial]] = []

    def __init__(self, **kwargs):
        self.kwargs = kwargs
        self.written = b""
        self.in_waiting = 0
        FakeSerial.instances.append(self)

    def read(self, n):
        time.sleep(0.01)
        return b""

    def write(self, data):
        self.written += data
        return len(data)

    def flush(self):
        pass

    def close(self):
        pass


def test_serial_url_parameters_reach_pyserial(monkeypatch):
    monkeypatch.setattr(serial_line.serial, "Serial", FakeSerial)
    line = open_serial("serial:/dev/ttyUSB0?baud=115200&parity=E&bytesize=8&stopbits=1")
    try:
        fake = FakeSerial.instances[-1]
        assert fake.kwargs | {"timeout": None} == {
            "port": "/dev/ttyUSB0", "baudrate": 115200, "parity": "E", "bytesize": 8,
            "stopbits": 1.0, "timeout": None}
        line.write(READ_REQ)
        assert fake.written == READ_REQ
        assert line.char_time_s == pytest.approx(11 / 115200)
    finally:
        line.close()


def test_serial_open_failure_names_url():
    with pytest.raises(TransportUrlError, match=r"'serial:/dev/hil-no-such-tty'.*cannot open"):
        open_serial("serial:/dev/hil-no-such-tty")


def test_chunk_packing():
    payload = pack_chunk(b"\x01\x03", 123, [1000, 2500], 100)
    assert unpack_chunk(payload) == (b"\x01\x03", 123, 100, [1000, 2500])
    with pytest.raises(ValueError):
        unpack_chunk(payload[:-1])


def test_zenoh_chunk_held_up_in_transit_continues_its_frame(port):
    """A Modbus answer sent as two chunks back to back (the sender's own times say so) stays
    one frame when the second chunk reaches this host 5 ms late, well past t3.5: the
    line's timeline is the sender's, not the arrival's."""
    from types import SimpleNamespace

    line = open_serial(f"zenoh:tzc/rs485?listen=tcp/127.0.0.1:{port}&baud=115200")
    try:
        c = line.char_time_ns
        answer = bytes.fromhex("0103040064000000") + b"\xbb"  # 9 bytes as 8 + 1
        wall = time.time_ns()

        def sample(data: bytes, t0: int):
            payload = pack_chunk(data, t0, [(i + 1) * c for i in range(len(data))], t0)
            return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))

        line._on_sample(sample(answer[:8], wall))
        time.sleep(0.005)  # held up in transit (t3.5 at 115200 baud is 1.75 ms)
        line._on_sample(sample(answer[8:], wall + 8 * c))  # right after the 8th character
        frame = line.read_frame(timeout=2)
        assert frame.data == answer
        assert frame.t_end_ns - frame.t_start_ns == len(answer) * c  # back to back, as sent
        assert line.read_frame(timeout=0.05) is None
    finally:
        line.close()


def test_zenoh_chunk_after_a_frame_was_read_is_not_stamped_in_the_past(port):
    """The reader took the previous frame; the next chunk follows it by the sender's clock
    (within 1 s) but arrives later than that says: it starts at its arrival, never in the
    reader's past (a waiting reader would take it at once and end the frame early)."""
    from types import SimpleNamespace

    line = open_serial(f"zenoh:tzp/rs485?listen=tcp/127.0.0.1:{port}&baud=115200")
    try:
        c = line.char_time_ns
        wall = time.time_ns()

        def sample(data: bytes, t0: int):
            payload = pack_chunk(data, t0, [(i + 1) * c for i in range(len(data))], t0)
            return SimpleNamespace(payload=SimpleNamespace(to_bytes=lambda: payload))

        line._on_sample(sample(b"\x01\x03", wall))
        assert line.read_frame(timeout=1).data == b"\x01\x03"
        time.sleep(0.03)  # the sender says 10 ms later; it arrives 30 ms later
        arrived = time.monotonic_ns()
        line._on_sample(sample(b"\x01\x83\x02", wall + 2 * c + 10_000_000))
        frame = line.read_frame(timeout=1)
        assert frame.data == b"\x01\x83\x02"
        assert frame.t_start_ns >= arrived - 1_000_000  # not 20 ms before it arrived
    finally:
        line.close()


def test_zenoh_serial_between_two_sessions_keeps_timing(port, tap):
    ep = f"tcp/127.0.0.1:{port}"
    slave = open_serial(f"zenoh:tz/rs485?listen={ep}&role=slave&baud=1200&stopbits=1")
    master = open_serial(f"zenoh:tz/rs485?connect={ep}&baud=1200&stopbits=1", tap=tap)
    try:
        c = master.char_time_ns
        t0 = time.monotonic_ns()
        first = master.write(READ_REQ[:4])
        master.write(READ_REQ[4:], not_before_ns=first.t_end_ns + 2 * c)  # 2-char gap
        frame = slave.read_frame(silence_s=0.02, timeout=2)
        assert frame.data == READ_REQ
        assert frame.gaps_us[3] == pytest.approx(2 * c / 1000, abs=2)  # gap survived
        assert sum(frame.gaps_us) == frame.gaps_us[3]
        assert frame.t_end_ns - frame.t_start_ns == (len(READ_REQ) + 2) * c
        assert frame.t_start_ns >= t0
        assert frame.source_t is not None  # master's wall time of the first character
        slave.write(b"\x01\x83\x02\xc0\xf1")  # exception reply
        back = master.read_frame(timeout=2)
        assert back.data == b"\x01\x83\x02\xc0\xf1"
        assert back.source_t is not None
    finally:
        master.close()
        slave.close()
    directions = [(ch[2], ch[1]) for ch in tap.serial_chunks]
    assert directions == [("tx", READ_REQ[:4]), ("tx", READ_REQ[4:]),
                          ("rx", b"\x01\x83\x02\xc0\xf1")]
