"""Issue 12, faces: hostile input never silences a face, never escapes as a traceback.

Each test here failed on the code before the fix (see the commit message of each fix).
"""

from __future__ import annotations

import logging
import struct
import threading
import time

import can
import pytest

from hil.faces.canopen_slave import CanopenSlave
from hil.faces.modbus_slave import ModbusSlave, ModbusSlaveRunner
from hil.model import errors as E
from hil.model.drive import Drive
from hil.protocol import canopen as cop
from hil.protocol import modbus as mb
from hil.virtual.host import DriveHost

MS = 1_000_000
S = 1_000_000_000
NODE = 5
# P2.010, DI1 function (L6974, L9238: Modbus 0214H; OD 220Ah, L18156); 0x0007 is no DI
# function of table 8.1 (L15075-L15255).
P2_010_ADDR = 0x0214
P2_010_INDEX = 0x220A
READ_P0_000 = mb.rtu_encode(1, mb.read_request(0x0000, 2))


def modbus_face(drive: Drive, out: list[bytes]) -> ModbusSlave:
    return ModbusSlave(drive.params, station=1, send=out.append)


# ---------------------------------------------------------------- Modbus: silence


@pytest.mark.parametrize("burst", [257, 514, 515, 771, 258, 300, 1000])
def test_request_after_t35_silence_is_answered_after_any_overlong_burst(burst):
    """A burst of 257 (514, 771 ...) bytes left the face "broken" with an empty buffer, and
    the silence check only ran on a non-empty one: the next valid request got no answer."""
    out: list[bytes] = []
    face = modbus_face(Drive(), out)
    face.feed(bytes(range(256)) * (burst // 256) + bytes(burst % 256), 0)
    face.tick(S)
    assert out == []
    t = 2 * S  # > t3.5 of silence (1.75 ms at 38400 baud, Modbus serial line §2.5.1.1)
    face.feed(READ_P0_000, t)
    face.tick(t + 100 * MS)
    assert len(out) == 1 and mb.rtu_decode(out[0])[1][0] == mb.READ_HOLDING


@pytest.mark.parametrize("burst", [257, 514])
def test_request_right_after_overlong_burst_without_tick(burst):
    """The same without a tick in the silence: the next byte itself sees the gap."""
    out: list[bytes] = []
    face = modbus_face(Drive(), out)
    face.feed(bytes(burst), 0)
    face.feed_timed(READ_P0_000, [10 * MS + i * face.line.char_time_ns for i in range(8)])
    face.tick(S)
    assert len(out) == 1


def test_overlong_burst_without_silence_stays_dropped():
    """Bytes glued to an overlong burst (no t3.5 gap) are still part of the broken burst."""
    out: list[bytes] = []
    face = modbus_face(Drive(), out)
    char = face.line.char_time_ns
    face.feed(bytes(257) + READ_P0_000, 0)  # one burst: the request has no silence before
    face.tick(S)
    assert out == [] and face.stats["dropped"] >= 1
    assert face.next_deadline() is None  # nothing left waiting once the silence passed
    face.feed(READ_P0_000, S + 8 * char)
    face.tick(2 * S)
    assert len(out) == 1


# ---------------------------------------------------------------- Modbus: refusals


@pytest.mark.parametrize(
    "pdu",
    [
        mb.write_single_request(P2_010_ADDR, 0x0007),
        mb.write_multiple_request(P2_010_ADDR, [0x0007, 0x0000]),
    ],
)
def test_modbus_undefined_di_function_is_illegal_data_value(pdu):
    """P2.010 = 0x0007 is refused by the model (UnknownFunction): exception 03h, a refused
    value (docs/manual-choices.md#modbus), and P2.010 keeps its value."""
    drive = Drive()
    before = drive.params.get("P2.010")
    out: list[bytes] = []
    face = modbus_face(drive, out)
    face.feed(mb.rtu_encode(1, pdu), 0)
    face.tick(S)
    assert out == [mb.rtu_encode(1, mb.exception_response(pdu[0], mb.ILLEGAL_DATA_VALUE))]
    assert drive.params.get("P2.010") == before
    assert face.last_resort.count == 0


def test_modbus_model_bug_answers_04_logs_once_and_counts(caplog):
    class Buggy:
        def modbus_read(self, address, count):
            raise KeyError("bug")

        def modbus_write(self, address, words):
            raise KeyError("bug")

    out: list[bytes] = []
    face = ModbusSlave(Buggy(), station=1, send=out.append)
    with caplog.at_level(logging.ERROR, logger="hil.faces.modbus_slave"):
        for i in range(3):
            face.feed(READ_P0_000, i * S)
            face.tick(i * S + 100 * MS)
    fail = mb.rtu_encode(1, mb.exception_response(3, mb.SERVER_DEVICE_FAILURE))
    assert out == [fail] * 3
    assert face.last_resort.count == 3
    assert len([r for r in caplog.records if r.levelno >= logging.ERROR]) == 1


def test_modbus_failing_callbacks_do_not_stop_the_face():
    calls = []

    def send(adu):
        calls.append(adu)
        if len(calls) == 1:
            raise OSError("line gone for a moment")

    def on_comm_error(code, message):
        raise RuntimeError("owner bug")

    face = ModbusSlave(Drive().params, station=1, send=send, on_comm_error=on_comm_error)
    bad = mb.rtu_encode(1, mb.read_request(0xFFF0, 2))  # no parameter there: exception 02h
    face.feed(bad, 0)
    face.tick(S)
    face.feed(READ_P0_000, 2 * S)
    face.tick(3 * S)
    assert len(calls) == 2 and mb.rtu_decode(calls[1])[1][0] == mb.READ_HOLDING
    assert face.last_resort.count == 2  # on_comm_error + send


class _FlakyLine:
    """A line whose first read fails, then delivers one request, then stays idle."""

    def __init__(self) -> None:
        self.reads = 0
        self.pending = READ_P0_000
        self.written: list[bytes] = []

    def read(self, n, timeout):
        self.reads += 1
        if self.reads == 1:
            raise OSError("EIO")
        if self.pending and n == 1:
            data, self.pending = self.pending, b""
            return data
        time.sleep(min(timeout or 0, 0.002))
        return b""

    def write(self, data):
        self.written.append(data)


def test_modbus_runner_survives_an_exception_and_keeps_serving():
    line = _FlakyLine()
    face = ModbusSlave(Drive().params, station=1)
    with ModbusSlaveRunner(face, line, poll_s=0.002) as runner:
        end = time.monotonic() + 5
        while not line.written and time.monotonic() < end:
            time.sleep(0.005)
        assert runner._thread.is_alive()
    assert len(line.written) == 1
    assert isinstance(runner.error, OSError) and face.last_resort.count == 1


# ---------------------------------------------------------------- CANopen


class CanPair:
    """A CanopenSlave (real Drive) on one end of a python-can virtual bus, a raw master on
    another (as `hil drive` runs it: own_timer=False, ticked by the host)."""

    def __init__(self, drive, channel: str) -> None:
        self.slave_bus = can.Bus(interface="virtual", channel=channel)
        self.master = can.Bus(interface="virtual", channel=channel)
        self.slave = CanopenSlave(self.slave_bus, drive, node_id=NODE, own_timer=False,
                                  clock=lambda: 0)
        self.slave.start()

    def sdo(self, data: bytes, timeout: float = 2.0) -> bytes | None:
        self.master.send(can.Message(arbitration_id=0x600 + NODE, data=data,
                                     is_extended_id=False))
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = self.master.recv(timeout=left)
            if msg is not None and msg.arbitration_id == 0x580 + NODE:
                return bytes(msg.data)
        return None

    def close(self) -> None:
        self.slave.close()
        self.slave_bus.shutdown()
        self.master.shutdown()


def abort_code(resp: bytes | None) -> int:
    assert resp is not None, "SDO not answered"
    assert resp[0] == 0x80, f"expected an abort, got {resp.hex()}"
    return struct.unpack_from("<I", resp, 4)[0]


def test_sdo_download_of_undefined_di_function_is_aborted_0609_0030(caplog):
    """605#2B0A220007000000 (P2.010 = 0x0007): the model refuses with UnknownFunction.
    Before: no answer and a traceback. Now abort 0609 0030 (value out of range, L17033)."""
    drive = Drive()
    pair = CanPair(drive, "hostile-p2010")
    try:
        with caplog.at_level(logging.ERROR):
            resp = pair.sdo(bytes.fromhex("2B0A220007000000"))
            assert abort_code(resp) == cop.ABORT_VALUE_RANGE
            assert resp[1:4] == bytes.fromhex("0A2200")
            # the face still serves: a valid DI function (0x0101 SON, L6974) is accepted
            assert pair.sdo(bytes.fromhex("2B0A220001010000"))[0] == 0x60
        assert drive.params.get("P2.010") == 0x0101
        assert pair.slave.last_resort.count == 0
        assert not [r for r in caplog.records if r.levelno >= logging.ERROR]
    finally:
        pair.close()


def test_drive_write_object_turns_every_refusal_into_an_object_error():
    drive = Drive()
    with pytest.raises(E.ObjectError) as info:
        drive.write_object(P2_010_INDEX, 0, 0x0007)
    assert info.value.abort_code == cop.ABORT_VALUE_RANGE
    assert isinstance(info.value.__cause__, E.UnknownFunction)


class _BuggyDrive:
    """A drive whose object writes fail with a non-model exception (a model bug)."""

    def __init__(self) -> None:
        self.inner = Drive()

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def write_object(self, index, sub, value):
        raise ZeroDivisionError("model bug")


def test_sdo_model_bug_answers_general_abort_logs_once_and_keeps_serving(caplog):
    pair = CanPair(_BuggyDrive(), "hostile-bug")
    try:
        with caplog.at_level(logging.ERROR, logger="hil.faces.canopen_slave"):
            for _ in range(3):  # 6040h controlword = 6 (shutdown)
                assert abort_code(pair.sdo(bytes.fromhex("2B40600006000000"))) == cop.ABORT_GENERAL
            upload = pair.sdo(bytes.fromhex("4000100000000000"))  # 1000h still readable
        assert upload is not None and upload[0] == 0x43
        assert pair.slave._thread.is_alive()
        assert pair.slave.last_resort.count == 3
        assert len([r for r in caplog.records if r.levelno >= logging.ERROR]) == 1
    finally:
        pair.close()


def test_sdo_model_refusal_that_is_no_object_error_is_still_an_abort():
    """A ModelError that carries no abort code (e.g. from a drive double) -> 0609 0030."""

    class Refusing(_BuggyDrive):
        def write_object(self, index, sub, value):
            raise E.UnknownFunction("DO", 0x77, "P2.018")

    pair = CanPair(Refusing(), "hostile-refusal")
    try:
        assert abort_code(pair.sdo(bytes.fromhex("2B40600006000000"))) == cop.ABORT_VALUE_RANGE
        assert pair.slave.last_resort.count == 0
    finally:
        pair.close()


# ---------------------------------------------------------------- host lock


def test_synced_lock_is_released_when_advancing_the_model_fails():
    """host.synced advances the model on acquire; a model exception there left the host
    lock held forever (the `with` body never ran, so nothing released it)."""

    class Failing:
        now = 0

        def advance_to(self, t):
            raise RuntimeError("model bug")

    host = DriveHost(Failing())
    time.sleep(0.002)  # model_now > 0: acquiring advances
    with host.synced:
        pass
    got = []
    t = threading.Thread(target=lambda: got.append(host.lock.acquire(timeout=1)))
    t.start()
    t.join()
    assert got == [True]
    assert len(host.errors) == 1
