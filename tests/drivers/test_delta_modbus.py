"""DeltaModbus (harness master) against the virtual drive's Modbus face.

Unit tests use an in-memory line; end-to-end tests run the face in a thread on a real pty
pair (os.openpty), the driver on the pty's device path through pyserial, and mbpoll when
it is installed.
"""

from __future__ import annotations

import os
import shutil
import subprocess
import time
import tty
from pathlib import Path

import pytest

from hil.drivers.delta_modbus import (
    DeltaModbus,
    ModbusExceptionError,
    ModbusReplyError,
    ModbusTimeoutError,
    ParamInfo,
    UnknownParameterError,
    param_address,
)
from hil.faces.modbus_slave import FdLine, ModbusSlave, ModbusSlaveRunner
from hil.model import errors
from hil.model.params import ParameterStore
from hil.protocol import modbus as mb
from hil.transport import serial_line

H = bytes.fromhex



class WordStore:
    """Minimal word store: unknown address -> 02, > limit -> 03 (like ParameterStore)."""

    def __init__(self, words: dict[int, int], limit: int = 0xFFFF) -> None:
        self.words = dict(words)
        self.limit = limit

    def modbus_read(self, address, count):
        try:
            return [self.words[a] for a in range(address, address + count)]
        except KeyError as exc:
            raise errors.UnknownParameter(f"address {exc}", "no parameter word") from None

    def modbus_write(self, address, words):
        for i, w in enumerate(words):
            if address + i not in self.words:
                raise errors.UnknownParameter(f"address {address + i}", "no parameter word")
            if w > self.limit:
                raise errors.OutOfRange(f"address {address + i}", f"{w} > {self.limit}")
        for i, w in enumerate(words):
            self.words[address + i] = w


class LoopLine:
    """An in-memory line (`read(n, timeout)`, `write`) wired straight to a ModbusSlave."""

    def __init__(self, slave: ModbusSlave | None, *, corrupt: bool = False) -> None:
        self.slave = slave
        self.rx = bytearray()
        self.sent: list[bytes] = []
        self.corrupt = corrupt
        self.t = 0
        if slave is not None:
            slave.send = self._reply

    def _reply(self, adu: bytes) -> None:
        if self.corrupt:
            adu = adu[:-1] + bytes([adu[-1] ^ 0x55])
        self.rx += adu

    def write(self, data: bytes) -> None:
        self.sent.append(bytes(data))
        if self.slave is not None:
            self.t += 1_000_000_000
            self.slave.feed(data, self.t)
            self.slave.tick(self.t + 100_000_000)

    def read(self, n: int, timeout: float | None) -> bytes:
        if not self.rx and timeout:
            time.sleep(min(timeout, 0.01))
        out = bytes(self.rx[:n])
        del self.rx[:n]
        return out


def infos(name: str) -> ParamInfo:
    table = {
        "P2.000": ParamInfo("P2.000", 0x0200, 16, False),
        "P1.009": ParamInfo("P1.009", 0x0112, 32, True),  # example 3 (L15781)
        "P0.002": ParamInfo("P0.002", 0x0004, 16, True),  # -300..127 (L7088)
    }
    return table[name]


def loop(mode="rtu", corrupt=False, timeout_s=2.0, **words):
    """A master on a `LoopLine`: every answer is there at once, so the reply timeout (wall
    clock) only ends a wait for a reply that never comes; it is long enough for a loaded
    host (0.05 s failed once under two xdist workers)."""
    store = WordStore({0x0200: 0x00B1, 0x0201: 0x1F40, 0x0112: 0, 0x0113: 0, 0x0004: 0})
    slave = ModbusSlave(store, station=1, mode=mode)
    line = LoopLine(slave, corrupt=corrupt)
    drive = DeltaModbus(line, station=1, mode=mode, timeout_s=timeout_s, silence_s=0,
                        param_info=infos)  # fmt: skip
    return drive, line, store


@pytest.mark.parametrize("mode", ["rtu", "ascii"])
def test_manual_examples_from_the_master_side(mode):
    drive, line, store = loop(mode)
    assert drive.read_registers(0x0200, 2) == [0x00B1, 0x1F40]  # example 1
    drive.write_register(0x0200, 0x0064)  # example 2
    drive.write_registers(0x0112, [0x0BB8, 0x0000])  # example 3
    want = [
        H("01 03 02 00 00 02 C5 B3"), H("01 06 02 00 00 64 89 99"),
        H("01 10 01 12 00 02 04 0B B8 00 00 FC EB"),
    ] if mode == "rtu" else [
        b":010302000002F8\r\n", b":01060200006493\r\n", b":011001120002040BB8000013\r\n",
    ]  # fmt: skip
    assert line.sent == want
    assert store.words[0x0200] == 0x64


def test_params_by_name_32bit_low_word_first_and_signed():
    drive, line, store = loop()
    drive.write_param("P1.009", 3000)
    assert line.sent[-1] == H("01 10 01 12 00 02 04 0B B8 00 00 FC EB")  # L15838-L15852
    assert drive.read_param("P1.009") == 3000
    drive.write_param("P1.009", -2)
    assert (store.words[0x0112], store.words[0x0113]) == (0xFFFE, 0xFFFF)
    assert drive.read_param("P1.009") == -2
    drive.write_param("P0.002", -80)
    assert store.words[0x0004] == 0xFFB0 and drive.read_param("P0.002") == -80
    with pytest.raises(ValueError, match="16-bit"):
        drive.write_param("P2.000", 70000)


def test_exception_error_names_function_address_and_meaning():
    drive, _, _ = loop()
    with pytest.raises(ModbusExceptionError) as e:
        drive.read_registers(0x0200, 11)  # > 10 words (L15634)
    assert (e.value.function, e.value.address, e.value.code) == (3, 0x0200, 3)
    assert "illegal data value" in str(e.value) and "0200h" in str(e.value)
    with pytest.raises(ModbusExceptionError, match=r"\(10h\) at 0200h.*illegal data value"):
        drive.write_registers(0x0200, [0] * 9)  # > 8 words (L15781)
    with pytest.raises(ModbusExceptionError) as e:
        drive.read_registers(0x0700, 1)
    assert e.value.meaning == "illegal data address"


def test_exception_on_param_names_the_parameter():
    store = WordStore({0x0200: 0}, limit=2047)
    slave = ModbusSlave(store, station=1)
    drive = DeltaModbus(LoopLine(slave), station=1, silence_s=0, param_info=infos)
    with pytest.raises(ModbusExceptionError, match=r"P2\.000.*illegal data value"):
        drive.write_param("P2.000", 5000)


def test_timeout_names_what_was_sent():
    drive = DeltaModbus(LoopLine(None), station=1, timeout_s=0.02, silence_s=0)
    with pytest.raises(ModbusTimeoutError, match="01 03 02 00 00 02 c5 b3") as e:
        drive.read_registers(0x0200, 2)
    assert e.value.sent == H("01 03 02 00 00 02 C5 B3") and e.value.received == b""


def test_foreign_station_gets_no_answer_and_bad_crc_reply_is_reported():
    drive, _, _ = loop(timeout_s=0.05)  # no answer comes: the wait is the timeout
    with pytest.raises(ModbusTimeoutError):
        drive.read_registers(0x0200, 2, station=2)
    drive, _, _ = loop(corrupt=True)
    with pytest.raises(ModbusReplyError, match="CRC"):
        drive.read_registers(0x0200, 2)


def test_broadcast_and_auto_reply():
    drive, line, store = loop()
    assert drive.transact(mb.write_single_request(0x0200, 7), station=0) is None
    assert store.words[0x0200] == 7 and line.rx == b""
    assert drive.read_registers(0x0200, 1, station=0xFF) == [7]  # L10507


def test_param_address_formula():
    # (group << 8) + 2n (L6697); P3.004 0308H (L10571), P1.044 0158H (L8518), PM.004 FD08H.
    assert param_address("P3.004") == 0x0308
    assert param_address("P1.044") == 0x0158
    assert param_address("PM.004") == 0xFD08
    with pytest.raises(ValueError, match="parameter name"):
        param_address("Q1.000")


def test_param_table_lookup_is_lazy_and_typed():
    drive = DeltaModbus(LoopLine(None), station=1)
    assert drive._table is None
    info = drive.param("P1.009")
    assert (info.address, info.size, info.signed) == (0x0112, 32, True)
    assert drive.param("p1-42").address == 0x0154


def test_unknown_parameter_fails_loudly():
    """A name outside the chapter 8 table is an error, never a guessed 16-bit access."""
    drive = DeltaModbus(LoopLine(None), station=1)
    with pytest.raises(UnknownParameterError, match=r"P1\.255"):
        drive.param("P1.255")
    with pytest.raises(UnknownParameterError, match="not a parameter name"):
        drive.param("PM.004")


def test_unreadable_parameter_table_is_not_a_16_bit_fallback(monkeypatch):
    """The old driver fell back to 16-bit unsigned when the table could not be loaded, so
    P1.009 (32-bit, L7931-7934) would have been written as one word."""
    from hil.profile.params import ParamTable

    def broken(cls, path=None):
        raise OSError("a3_parameters.csv: no such file")

    monkeypatch.setattr(ParamTable, "load", classmethod(broken))
    drive = DeltaModbus(LoopLine(None), station=1)
    with pytest.raises(OSError, match="a3_parameters"):
        drive.param("P1.009")


# ---------------------------------------------------------------- over a real pty


@pytest.fixture
def pty_drive(tmp_path):
    """The virtual drive's face on a pty master; yields (device path, store, slave)."""
    master, slave_fd = os.openpty()
    tty.setraw(slave_fd)
    tty.setraw(master)
    path = os.ttyname(slave_fd)
    store = ParameterStore(autosave=False)
    face = ModbusSlave(store, station=1, baud=115200)
    runner = ModbusSlaveRunner(face, FdLine(master), poll_s=0.002).start()
    try:
        yield path, store, face
    finally:
        runner.stop()
        os.close(slave_fd)
        os.close(master)
        assert runner.error is None, runner.error


def test_end_to_end_over_pty(pty_drive):
    path, store, face = pty_drive
    with DeltaModbus(path, station=1, baud=115200, timeout_s=1.0) as drive:
        drive.write_param("P1.042", 100)
        assert drive.read_param("P1.042") == 100
        drive.write_param("P1.009", -12345)
        assert drive.read_param("P1.009") == -12345
        assert drive.read_registers(0x0154, 2) == [100, 0]
        t0 = time.monotonic()
        drive.read_registers(0x0154, 1)
        drive.read_registers(0x0154, 1)
        assert time.monotonic() - t0 >= 0.010  # the manual's 10 ms between frames (L15703)
        with pytest.raises(ModbusTimeoutError):
            drive.read_registers(0x0154, 1, station=9)
        assert drive.read_registers(0x0154, 1) == [100]  # recovers after the silence
        assert drive.last_round_trip_s is not None and drive.last_round_trip_s >= 0.00175
    assert store.read("P1.042") == 100 and store.read("P1.009") == -12345
    assert face.stats["foreign"] == 1


MBPOLL = shutil.which("mbpoll")


@pytest.mark.skipif(MBPOLL is None, reason="mbpoll not installed (apt-get install mbpoll)")
def test_mbpoll_reads_and_writes_over_pty(pty_drive, tmp_path):
    path, store, face = pty_drive
    link = Path(tmp_path) / "ttyA3"
    link.symlink_to(path)  # mbpoll needs a device path; the face holds the master fd
    base = [MBPOLL, "-m", "rtu", "-a", "1", "-b", "115200", "-P", "none", "-s", "2", "-0",
            "-t", "4", "-o", "1"]  # fmt: skip
    w = subprocess.run([*base, "-r", str(0x0154), str(link), "250"],
                       capture_output=True, text=True, timeout=20)  # fmt: skip
    assert w.returncode == 0, w.stdout + w.stderr
    r = subprocess.run([*base, "-r", str(0x0154), "-c", "2", "-1", str(link)],
                       capture_output=True, text=True, timeout=20)  # fmt: skip
    assert r.returncode == 0, r.stdout + r.stderr
    assert f"[{0x0154}]: \t250" in r.stdout or f"[{0x0154}]: 250" in r.stdout, r.stdout
    bad = subprocess.run([*base, "-r", str(0x0154), "-c", "11", "-1", str(link)],
                         capture_output=True, text=True, timeout=20)  # fmt: skip
    assert bad.returncode != 0 and "Illegal data value" in bad.stdout + bad.stderr
    assert store.read("P1.042") == 250
    assert face.stats["replies"] == 2 and face.stats["exceptions"] == 1


def test_end_to_end_over_transport_ptyline(tmp_path):
    """The face on the transport room's PtyLine (line timing emulated), driver on its link."""
    link = tmp_path / "ttyA3"
    line = serial_line.open_serial(f"pty:{link}?baud=115200")
    store = WordStore({0x0154: 0, 0x0155: 0})
    face = ModbusSlave(store, station=1, baud=115200)
    runner = ModbusSlaveRunner(face, line).start()
    try:
        with DeltaModbus(str(link), station=1, baud=115200, timeout_s=1.0, silence_s=0) as d:
            d.write_register(0x0154, 77)
            assert d.read_registers(0x0154, 2) == [77, 0]
            # request 8 B + reply 9 B at 115200 8N2 + t3.5: a real line's time at least
            wire = mb.frame_time_ns(8 + 9, 115200, 11) + 1_750_000
            assert d.last_round_trip_s * 1e9 >= 0.9 * wire
    finally:
        runner.stop()
        line.close()
    assert runner.error is None and face.stats["replies"] == 2
