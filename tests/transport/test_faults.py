"""The harness-side fault layer (issue 16): what it does to frames we send, what it leaves
alone (everything received), and the /faults start/end records."""

from __future__ import annotations

import time
import uuid

import can
import pytest

from hil.drivers.delta_modbus import DeltaModbus, ModbusReplyError, ModbusTimeoutError
from hil.protocol import modbus as mb
from hil.transport.faults import CanMatch, FaultyCanBus, FaultyDio, FaultySerial, error_frames

MS = 1_000_000


class Sink:
    def __init__(self) -> None:
        self.records: list[tuple] = []
        self.times = []

    def fault(self, fault, transport, active, fault_id, *, t=None, **detail):
        self.records.append((fault, transport, active, fault_id, detail))
        self.times.append(t)


@pytest.fixture
def pair():
    ch = f"flt-{uuid.uuid4().hex}"
    inner = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    peer = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    sink = Sink()
    bus = FaultyCanBus(inner, "can0", sink=sink, seed=1)
    yield bus, peer, sink
    bus.shutdown()
    peer.shutdown()


def frame(cid: int, data: bytes = b"\x01\x02") -> can.Message:
    return can.Message(arbitration_id=cid, data=data, is_extended_id=False)


def drain(peer: can.BusABC) -> list[can.Message]:
    out = []
    while (m := peer.recv(0.02)) is not None:
        out.append(m)
    return out


def test_passive_layer_passes_everything_both_ways(pair):
    bus, peer, sink = pair
    bus.send(frame(0x601))
    peer.send(frame(0x585))
    assert [m.arbitration_id for m in drain(peer)] == [0x601]
    assert bus.recv(0.1).arbitration_id == 0x585
    assert sink.records == []


def test_drop_by_function_only_matching_frames_and_recorded(pair):
    bus, peer, sink = pair
    f = bus.inject("drop", match=CanMatch(functions=("sync",)))
    bus.send(frame(0x80, b""))
    bus.send(frame(0x77F, b"\x05"))
    assert [m.arbitration_id for m in drain(peer)] == [0x77F]
    bus.faults.stop(f)
    bus.send(frame(0x80, b""))
    assert [m.arbitration_id for m in drain(peer)] == [0x80]
    assert [(r[0], r[1], r[2]) for r in sink.records] == [("drop", "can:can0", True),
                                                          ("drop", "can:can0", False)]
    assert sink.records[0][4]["match"] == {"function": ["sync"]}


def test_received_frames_are_never_touched(pair):
    bus, peer, _ = pair
    bus.inject("drop")  # everything we send
    peer.send(frame(0x185))
    assert bus.recv(0.1).arbitration_id == 0x185


def test_duration_ends_the_fault_and_records_the_end(pair):
    bus, peer, sink = pair
    bus.inject("drop", match=CanMatch(cob_ids=frozenset({0x601})), duration_ns=30 * MS)
    bus.send(frame(0x601))
    time.sleep(0.1)
    bus.send(frame(0x601))
    assert len(drain(peer)) == 1
    assert [r[2] for r in sink.records] == [True, False]


def test_duplicate_corrupt_and_delay(pair):
    bus, peer, _ = pair
    f = bus.inject("duplicate", match=CanMatch(ranges=((0x200, 0x27F),)))
    bus.send(frame(0x205))
    assert [m.arbitration_id for m in drain(peer)] == [0x205, 0x205]
    bus.faults.stop(f)
    f = bus.inject("corrupt")
    bus.send(frame(0x205, b"\x00\x00"))
    bus.send(frame(0x80, b""))  # no data: becomes an error frame
    got = drain(peer)
    assert bin(int.from_bytes(got[0].data, "little")).count("1") == 1  # one bit flipped
    assert got[1].is_error_frame
    bus.faults.stop(f)
    bus.inject("delay", delay_ns=50 * MS)
    t0 = time.monotonic()
    bus.send(frame(0x205))
    m = peer.recv(1.0)
    assert m is not None and time.monotonic() - t0 >= 0.045


def test_rate_affects_a_fraction(pair):
    bus, peer, _ = pair
    bus.inject("drop", rate=0.5)
    for _ in range(200):
        bus.send(frame(0x205))
    n = len(drain(peer))
    assert 60 < n < 140


def test_burst_is_one_recorded_fault(pair):
    bus, peer, sink = pair
    assert bus.burst("bus_error", error_frames(17)) == 17
    got = drain(peer)
    assert len(got) == 17 and all(m.is_error_frame for m in got)
    assert [(r[0], r[2]) for r in sink.records] == [("bus_error", True), ("bus_error", False)]


class SlowBus(can.BusABC):
    """A bus whose sends take `delays` seconds each, in turn (a loaded host)."""

    def __init__(self, delays):
        self.delays = list(delays)
        self.sent = []
        super().__init__(channel="slow")

    def send(self, msg, timeout=None):
        time.sleep(self.delays.pop(0) if self.delays else 0)
        self.sent.append(msg)

    def _recv_internal(self, timeout):
        return None, False


def test_burst_records_its_spread_and_whether_it_was_tight():
    """A burst is recorded start (before the first frame) and end (after the last) with its
    measured spread; `tight` says whether it stayed within the window the fault needs."""
    sink = Sink()
    bus = FaultyCanBus(SlowBus([0, 0.003]), "can0", sink=sink)
    frames = [frame(0x201, b"\0\0\0")] * 2
    bus.burst("duplicate_pdo", frames, within_ns=MS)
    (_, _, a0, id0, d0), (_, _, a1, id1, d1) = sink.records
    assert (a0, a1) == (True, False) and id0 == id1
    assert d0 == d1 and d0["tight"] is False and d0["spread_us"] >= 3000 and d0["frames"] == 2
    assert sink.times[1] - sink.times[0] == bus.last_spread_ns >= 3 * MS
    bus.burst("duplicate_pdo", frames, within_ns=10_000 * MS)  # no delay: well within
    assert sink.records[-1][4]["tight"] is True and bus.last_spread_ns < 10_000 * MS
    bus.burst("bus_error", error_frames(3))  # no window: no verdict on it
    assert "tight" not in sink.records[-1][4]
    bus.shutdown()


def test_bad_fault_is_refused(pair):
    bus, _, _ = pair
    with pytest.raises(ValueError, match="drop, delay"):
        bus.inject("explode")
    with pytest.raises(ValueError, match="unknown CANopen function"):
        CanMatch(functions=("foo",))


class Line:
    def __init__(self) -> None:
        self.writes: list[bytes] = []

    def write(self, data: bytes, **kw) -> None:
        self.writes.append(bytes(data))


def test_serial_faults():
    line = Line()
    s = FaultySerial(line, "rs0", sink=Sink(), seed=1)
    req = bytes.fromhex("7F0300000002CED5")
    s.write(req)
    f = s.inject("crc")
    s.write(req)
    s.faults.stop(f)
    f = s.inject("silence")
    s.write(req)
    s.faults.stop(f)
    f = s.inject("split", gap_ms=1)
    s.write(req)
    s.faults.stop(f)
    f = s.inject("partial")
    s.write(req)
    assert line.writes == [req, req[:-1] + bytes([req[-1] ^ 0xFF]), req[:4], req[4:], req[:4]]


class AnsweringLine:
    """A line whose far end answers every request at once with register value 1 (station
    1); reads as `SerialLine.read(n, timeout)`."""

    def __init__(self) -> None:
        self.buf = bytearray()
        self.writes: list[bytes] = []

    def write(self, data: bytes, **kw) -> None:
        self.writes.append(bytes(data))
        self.buf += mb.rtu_encode(1, bytes([0x03, 0x02, 0x00, 0x01]))

    def read(self, n: int = 1, timeout: float | None = None) -> bytes:
        if not self.buf:
            time.sleep(min(timeout or 0.0, 0.01))
            return b""
        out = bytes(self.buf[:n])
        del self.buf[:n]
        return out

    def reset_input_buffer(self) -> None:
        self.buf.clear()


def _master(kind: str | None, **params):
    line = AnsweringLine()
    sink = Sink()
    s = FaultySerial(line, "rs0", sink=sink, seed=1)
    if kind:
        s.inject(kind, **params)
    return DeltaModbus(s, station=1, timeout_s=0.2, silence_s=0.0), s, sink


def test_reply_faults_give_the_master_line_errors_never_a_value():
    """The harness's receiver (docs/faults.md): a reply later than the master's timeout or
    cut short is a timeout; noise ahead of it a bad reply or a timeout."""
    for kind, params, errors in (("reply_late", {"delay_ms": 300}, ModbusTimeoutError),
                                 ("reply_partial", {"bytes": 3}, ModbusTimeoutError),
                                 ("reply_noise", {"bytes": 2},
                                  (ModbusTimeoutError, ModbusReplyError))):
        m, s, sink = _master(kind, **params)
        with pytest.raises(errors):
            m.read_registers(0x0308, 1)
        s.stop_all()
        assert m.read_registers(0x0308, 1) == [1], kind  # the next transaction is clean
        assert [(r[0], r[2]) for r in sink.records] == [(kind, True), (kind, False)]


def test_split_and_short_late_replies_are_read_whole():
    m, s, _ = _master("reply_split", bytes=3, gap_ms=50)
    t0 = time.monotonic()
    assert m.read_registers(0x0308, 1) == [1]
    assert time.monotonic() - t0 >= 0.045
    s.stop_all()
    m, s, _ = _master("reply_late", delay_ms=50)
    assert m.read_registers(0x0308, 1) == [1]


def test_request_gaps_use_the_given_sleep():
    slept: list[float] = []
    line = Line()
    s = FaultySerial(line, "rs0", seed=1, sleep=slept.append)
    req = bytes.fromhex("7F0300000002CED5")
    s.inject("noise", bytes=4, gap_ms=15)
    s.write(req)
    assert slept == [0.015] and len(line.writes[0]) == 4 and line.writes[1] == req


def test_every_nth_frame_is_hit_exactly(pair):
    bus, peer, sink = pair
    bus.inject("drop", match=CanMatch(functions=("sync",)), every=2)
    for _ in range(6):
        bus.send(frame(0x80, b""))
    assert len(drain(peer)) == 3  # the 2nd, 4th, 6th dropped
    assert sink.records[0][4]["every"] == 2
    with pytest.raises(ValueError, match="every"):
        bus.inject("drop", every=2, rate=0.5)


class Port:
    def __init__(self) -> None:
        self.levels: dict[str, bool] = {}
        self.sets: list[tuple[str, bool]] = []

    def set(self, line: str, level: bool) -> None:
        self.levels[line] = level
        self.sets.append((line, level))

    def get(self, line: str) -> bool:
        return self.levels.get(line, False)


def test_stuck_line_holds_then_goes_to_the_harness_level():
    port, sink = Port(), Sink()
    dio = FaultyDio(port, "drive1", sink=sink)
    f = dio.inject("stuck", "DI1", level=False)
    dio.set("DI1", True)  # swallowed
    dio.set("DI2", True)  # another line: passes
    assert port.levels == {"DI1": False, "DI2": True}
    dio.faults.stop(f)
    assert port.levels["DI1"] is True  # freed: the level the harness set last
    assert [(r[0], r[2]) for r in sink.records] == [("stuck", True), ("stuck", False)]
    f = dio.inject("stuck", "DI3", level=True, duration_ns=20 * MS)  # never set: back to open
    deadline = time.monotonic() + 5.0  # the fault's end runs on a timer thread
    while port.sets[-2:] != [("DI3", True), ("DI3", False)] and time.monotonic() < deadline:
        time.sleep(0.01)
    assert port.sets[-2:] == [("DI3", True), ("DI3", False)]


def test_stuck_line_is_not_replayed_on_the_safe_state_path():
    """The safe state ends faults with restore=False: a SON stuck open is not closed again
    just before the safe state (which then sets every line itself)."""
    port = Port()
    dio = FaultyDio(port, "drive1", sink=Sink())
    dio.inject("stuck", "DI1", level=False)
    dio.set("DI1", True)
    dio.stop_all(restore=False)
    assert port.sets == [("DI1", False)] and not dio.faults.active
