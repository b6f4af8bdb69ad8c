"""The harness's masters fuzzed on the model's clock, as a stranger's drive would answer: the
Modbus master against replies late, garbled, split, for other registers or missing; the CiA 402
driver's SDO transfers against random answers. Each call ends within its timeout with a value
or one of the driver's errors, and a value is never another request's answer beyond what
docs/manual-choices.md leaves ("Master reading a reply", "the CiA 402 driver on a bad SDO
answer")."""

from __future__ import annotations

import queue
import random

import pytest
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from hil import clock
from hil.drivers import sdo_transfer
from hil.drivers.delta_modbus import (
    LATE_REPLIES,
    DeltaModbus,
    ModbusExceptionError,
    ModbusReplyError,
    ModbusTimeoutError,
)
from hil.protocol import modbus as mb

MS = 1_000_000


def value_of(address: int) -> int:
    return (address * 7919) & 0xFFFF


class VirtualLine:
    """A line with `read(n, timeout)` on a virtual clock: the responder schedules bytes."""

    def __init__(self, clk: clock.VirtualClock, responder) -> None:
        self.clk = clk
        self.responder = responder
        self.buf = bytearray()

    def write(self, data: bytes) -> int:
        for delay_ns, chunk in self.responder(bytes(data), self.clk.time_ns()):
            self.clk.after(delay_ns, lambda c=chunk: self.buf.extend(c))
        return len(data)

    def read(self, n: int, timeout: float | None) -> bytes:
        end = self.clk.time_ns() + round((timeout or 0) * 1e9)
        self.clk.run_until(end, lambda: len(self.buf) > 0)
        out = bytes(self.buf[:n])
        del self.buf[:n]
        return out

    def reset_input_buffer(self) -> None:
        self.buf.clear()


class Script:
    """Random answers from one station on a half-duplex line: replies come in the order of
    the requests (a late reply is ahead of any later one). Logs when each valid reply frame
    has reached the line and whose it is."""

    def __init__(self, rng: random.Random) -> None:
        self.rng = rng
        self.writes: list[tuple[int, int]] = []  # (time, address) per request
        self.arrivals: list[tuple[int, int]] = []  # (time, address answered) per valid reply
        self.line_free = 0  # when the last reply scheduled has been sent

    def __call__(self, req: bytes, now: int) -> list[tuple[int, bytes]]:
        n = len(self.arrivals)
        chunks = self._answer(req, now)
        if not chunks:
            return []
        shift = max(0, self.line_free + MS - (now + chunks[0][0]))
        chunks = [(d + shift, c) for d, c in chunks]
        self.arrivals[n:] = [(t + shift, a) for t, a in self.arrivals[n:]]
        self.line_free = now + chunks[-1][0]
        return chunks

    def _answer(self, req: bytes, now: int) -> list[tuple[int, bytes]]:
        rng = self.rng
        address = int.from_bytes(req[2:4], "big")
        count = int.from_bytes(req[4:6], "big")
        self.writes.append((now, address))
        good = mb.rtu_encode(1, mb.read_response([value_of(address + i) for i in range(count)]))
        kind = rng.choice(["ok", "ok", "late", "lost", "garbled", "split", "noise", "exc"])
        delay = rng.randrange(1, 40) * MS
        if kind == "ok" or kind == "late":
            if kind == "late":
                delay = rng.randrange(45, 150) * MS  # past the master's 40 ms
            self.arrivals.append((now + delay, address))
            return [(delay, good)]
        if kind == "lost":
            return []
        if kind == "garbled":
            bad = bytearray(good)
            bad[rng.randrange(len(bad))] ^= 1 << rng.randrange(8)
            return [(delay + i * MS // 10, bytes([b])) for i, b in enumerate(bad)]
        if kind == "split":
            cut = rng.randrange(1, len(good))
            gap = rng.randrange(1, 30) * MS
            self.arrivals.append((now + delay + gap, address))
            return [(delay, good[:cut]), (delay + gap, good[cut:])]
        if kind == "noise":
            return [(delay, bytes(rng.randrange(256) for _ in range(rng.randrange(1, 12))))]
        return [(delay, mb.rtu_encode(1, bytes([0x83, 0x02])))]


@pytest.mark.parametrize("seed", range(6))
def test_the_modbus_master_never_takes_another_requests_answer(seed):
    rng = random.Random(seed)
    clk = clock.VirtualClock()
    script = Script(rng)
    with clock.use(clk):
        m = DeltaModbus(VirtualLine(clk, script), station=1, timeout_s=0.04)
        outcomes = {"value": 0, "error": 0, "wrong": 0, "late one dropped": 0}
        last_failure = -10**18
        for _ in range(400):
            address = rng.randrange(0x0100, 0x0200, 2)
            t0 = clk.time_ns()
            try:
                got = m.read_registers(address, 1)
            except (ModbusTimeoutError, ModbusReplyError, ModbusExceptionError):
                outcomes["error"] += 1
                last_failure = clk.time_ns()
            else:
                sent = script.writes[-1][0]
                if got == [value_of(address)]:
                    outcomes["value"] += 1
                    stale = [t for t, a in script.arrivals if a != address and t >= sent]
                    own = [t for t, a in script.arrivals if a == address and t >= sent]
                    if stale and own and stale[0] < own[0]:
                        outcomes["late one dropped"] += 1
                else:
                    # the case left: a late reply alone on the line after this request, its
                    # own answer not within the 10 ms silence behind it
                    stale = [t for t, a in script.arrivals if a != address and t >= sent]
                    own = [t for t, a in script.arrivals if a == address and t >= sent]
                    assert stale, f"a wrong value {got} with no late reply on the line"
                    late_window = last_failure + LATE_REPLIES * 40 * MS
                    assert stale[0] >= late_window or not own or own[0] - stale[0] > 10 * MS, (
                        got, stale, own)
                    outcomes["wrong"] += 1
            # every transaction ends within its silence, drain, timeout and a split's rest
            assert clk.time_ns() - t0 <= 200 * MS
    assert outcomes["value"] > 60 and outcomes["error"] > 50
    assert outcomes["late one dropped"] > 0  # the case the heuristic is for did occur


class FakeSdo:
    """canopen's SdoClient surface the transfers use, answered at once by a script."""

    RESPONSE_TIMEOUT = 0.01

    def __init__(self, answer) -> None:
        self.answer = answer
        self._q: queue.Queue = clock.ClockQueue()
        self.sent: list[bytes] = []
        self.aborts: list[int] = []

    @property
    def responses(self) -> queue.Queue:
        return self._q

    @responses.setter
    def responses(self, _fresh: queue.Queue) -> None:
        self._q = clock.ClockQueue()

    def send_request(self, request: bytearray) -> None:
        self.sent.append(bytes(request))
        if request[0] == 0x80:
            self.aborts.append(int.from_bytes(request[4:8], "little"))
            return
        for a in self.answer(bytes(request)):
            self._q.put(a)

    def abort(self, code: int) -> None:
        self.send_request(bytearray([0x80, 0, 0, 0]) + code.to_bytes(4, "little"))

    def download(self, index: int, sub: int, data: bytes) -> None:
        raise AssertionError("not an expedited download")


def _random_answers(rng: random.Random):
    def answer(req: bytes) -> list[bytes]:
        out = []
        for _ in range(rng.choice([0, 1, 1, 1, 2, 3])):
            if rng.random() < 0.6:  # a plausible frame: a real command, often our mux
                cmd = rng.choice([0x60, 0x4B, 0x4F, 0x43, 0x47, 0x41, 0x40, 0x80, 0x00, 0x10,
                                  0x01, 0x11, 0x0D, 0x1F, rng.randrange(256)])
                mux = req[1:4] if rng.random() < 0.7 else bytes(rng.randrange(256)
                                                                for _ in range(3))
                data = bytes(rng.randrange(256) for _ in range(4))
                if req[0] & 0xE0 == 0x60 and rng.random() < 0.7:  # an upload segment
                    frame = bytes([(req[0] & 0x10) | rng.randrange(16)]) + data + data[:3]
                else:
                    frame = bytes([cmd]) + mux + data
                out.append(frame[:rng.choice([8, 8, 8, 8, rng.randrange(0, 9)])])
            else:
                out.append(bytes(rng.randrange(256) for _ in range(rng.randrange(0, 9))))
        return out
    return answer


@pytest.mark.parametrize("seed", range(4))
def test_sdo_transfers_end_with_a_value_or_an_sdo_error(seed):
    rng = random.Random(seed)
    clk = clock.VirtualClock()
    with clock.use(clk):
        for _ in range(1500):
            sdo = FakeSdo(_random_answers(rng))
            index, sub = rng.choice([(0x6041, 0), (0x607A, 0), (0x1008, 0), (0x6098, 0)])
            t0 = clk.time_ns()
            try:
                if rng.random() < 0.5:
                    sdo_transfer.download(sdo, index, sub, bytes(rng.randrange(1, 5)))
                    ok = [s for s in sdo.sent if s[0] != 0x80]
                    assert len(ok) == 1  # one initiate, no segment
                else:
                    data = sdo_transfer.upload(sdo, index, sub)
                    assert len(data) <= sdo_transfer.MAX_UPLOAD + 7
            except (SdoAbortedError, SdoCommunicationError):
                pass
            assert len(sdo.sent) <= sdo_transfer.MAX_UPLOAD // 7 + 4
            # each exchange waits at most its timeout: the whole transfer is bounded
            assert clk.time_ns() - t0 <= (len(sdo.sent) + 1) * 10 * MS


def test_a_download_is_success_only_with_its_own_acknowledgement():
    """Answers that are not `60h` with this index and sub-index never make a download succeed."""
    rng = random.Random(99)
    clk = clock.VirtualClock()
    successes = 0
    with clock.use(clk):
        for _ in range(3000):
            seen: list[bytes] = []
            base = _random_answers(rng)

            def answer(req: bytes, base=base, seen=seen) -> list[bytes]:
                out = base(req)
                seen.extend(out)
                return out

            sdo = FakeSdo(answer)
            try:
                sdo_transfer.download(sdo, 0x607A, 0, b"\x01\x02\x03\x04")
            except (SdoAbortedError, SdoCommunicationError):
                continue
            successes += 1
            assert any(a[0] & 0xE0 == 0x60 and a[1:4] == b"\x7a\x60\x00" for a in seen)
    assert successes > 40
