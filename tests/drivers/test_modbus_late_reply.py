"""The harness's Modbus master after a failed transaction (an outside review found a late
reply taken as the next request's answer, for another parameter): what the line still
carries is dropped until it has been quiet for the RTU silence (L15703), and a frame followed
by another within that silence was the late one (docs/manual-choices.md)."""

from __future__ import annotations

import time

import pytest

from hil.drivers.delta_modbus import DeltaModbus, ModbusReplyError, ModbusTimeoutError
from hil.protocol import modbus as mb


class TimedSerial:
    """pyserial-like: each written request gets replies at delays after the write."""

    def __init__(self, responder) -> None:
        self.responder = responder
        self.timeout: float | None = 1.0
        self.pending: list[tuple[float, bytes]] = []
        self.buf = bytearray()
        self.writes: list[float] = []

    def _pull(self) -> None:
        now = time.monotonic()
        for item in [p for p in self.pending if p[0] <= now]:
            self.buf += item[1]
            self.pending.remove(item)

    def write(self, data: bytes) -> int:
        t = time.monotonic()
        self.writes.append(t)
        for delay, b in self.responder(bytes(data)):
            self.pending.append((t + delay, b))
        self.pending.sort(key=lambda p: p[0])
        return len(data)

    def flush(self) -> None:
        pass

    def reset_input_buffer(self) -> None:
        self._pull()
        self.buf.clear()

    def read(self, n: int = 1) -> bytes:
        end = time.monotonic() + (self.timeout if self.timeout is not None else 1e9)
        while True:
            self._pull()
            if len(self.buf) >= n or time.monotonic() >= end:
                out = bytes(self.buf[:n])
                del self.buf[:n]
                return out
            time.sleep(0.0005)


VALUES = {0x0112: [3000, 0], 0x0158: [1, 0]}  # P1.009 = 3000, P1.044 = 1


def test_a_reply_that_comes_after_the_timeout_is_not_the_next_answer():
    """The drive stalls once and answers just after the master's timeout and silence, while
    the master has already sent its next request (for another register): that reply is
    dropped, and the next request gets its own answer."""
    first = [True]

    def respond(req: bytes):
        addr = int.from_bytes(req[2:4], "big")
        delay = 0.078 if first[0] else 0.010  # past the timeout and the 10 ms silence
        first[0] = False
        return [(delay, mb.rtu_encode(1, mb.read_response(VALUES[addr])))]

    m = DeltaModbus(TimedSerial(respond), station=1, timeout_s=0.06, silence_s=None)
    with pytest.raises(ModbusTimeoutError):
        m.read_registers(0x0112, 2)
    assert m.read_registers(0x0158, 2) == [1, 0]


def test_the_rest_of_a_garbled_reply_does_not_spoil_the_next_transaction():
    """A reply trickling in at 9600 baud with a byte count hit by noise: the master stops
    early with a reply error; the rest of those bytes must not fail the next request."""
    n = [0]

    def respond(req: bytes):
        n[0] += 1
        good = mb.rtu_encode(1, mb.read_response(list(range(1, 11))))
        frame = good if n[0] > 1 else good[:2] + bytes([4]) + good[3:]  # 14h -> 04h
        return [(0.002 + i * 0.00115, bytes([b])) for i, b in enumerate(frame)]

    m = DeltaModbus(TimedSerial(respond), station=1, timeout_s=0.06, silence_s=None)
    with pytest.raises(ModbusReplyError):
        m.read_registers(0x0200, 10)
    assert m.read_registers(0x0200, 10) == list(range(1, 11))


def test_after_a_timeout_on_a_quiet_line_the_master_is_not_silent_long():
    """The drive counts the master's silence (P3.004, L10571-10578): after a timeout the next
    request goes out once the line has been quiet for the 10 ms silence, not a timeout later."""
    calls = [0]

    def respond(req: bytes):
        calls[0] += 1
        if calls[0] == 1:
            return []  # lost
        return [(0.002, mb.rtu_encode(1, mb.read_response([7])))]

    line = TimedSerial(respond)
    m = DeltaModbus(line, station=1, timeout_s=0.2, silence_s=None)
    with pytest.raises(ModbusTimeoutError):
        m.read_registers(0x0112, 1)
    t_fail = time.monotonic()
    assert m.read_registers(0x0112, 1) == [7]
    assert line.writes[1] - t_fail < 0.1  # 10 ms quiet + host slack, well under timeout_s


def test_a_reply_later_than_the_next_answer_is_dropped_before_the_request_after():
    """The late reply comes after the next request's own answer: that answer is taken, and the
    late reply, by then on the line, is dropped before the request after it."""
    n = [0]

    def respond(req: bytes):
        n[0] += 1
        addr = int.from_bytes(req[2:4], "big")
        delay = 0.15 if n[0] == 1 else 0.003
        return [(delay, mb.rtu_encode(1, mb.read_response(VALUES[addr])))]

    m = DeltaModbus(TimedSerial(respond), station=1, timeout_s=0.06, silence_s=None)
    with pytest.raises(ModbusTimeoutError):
        m.read_registers(0x0112, 2)
    assert m.read_registers(0x0158, 2) == [1, 0]
    time.sleep(0.12)  # the late P1.009 reply lands
    assert m.read_registers(0x0158, 2) == [1, 0]


def test_a_stray_byte_after_a_good_answer_does_not_make_it_a_late_one():
    """An outside review: within the late-reply window, one glitch byte (0x00, a transceiver
    turning off) after a correct answer made the master drop it and time out. Only a frame's
    start (the station's address) behind an answer marks it as late."""
    n = [0]

    def respond(req: bytes):
        n[0] += 1
        if n[0] == 1:
            return []  # lost: the window opens
        good = mb.rtu_encode(1, mb.read_response(VALUES[0x0158]))
        return [(0.003, good), (0.004, b"\x00")]

    m = DeltaModbus(TimedSerial(respond), station=1, timeout_s=0.06, silence_s=None)
    with pytest.raises(ModbusTimeoutError):
        m.read_registers(0x0112, 2)
    assert m.read_registers(0x0158, 2) == [1, 0]
