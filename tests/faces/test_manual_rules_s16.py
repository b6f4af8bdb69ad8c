"""CANopen and Modbus face rules written fresh from the manual by an outside review (wave 3,
session 16, helper-58); each test failed before its fix. The drive is the real model on its
injected clock; its CANopen face is fed frame by frame."""

from __future__ import annotations

import struct
import uuid

import can
import pytest

from hil.faces.canopen_slave import CanopenSlave
from hil.faces.modbus_slave import ModbusSlave
from hil.model.drive import Drive
from hil.protocol import modbus as mb
from hil.units import MS, S

NODE = 5


class Rig:
    """A `Drive` behind a `CanopenSlave` on a private bus; frames fed in, time stepped."""

    def __init__(self) -> None:
        self.drive = Drive(inputs={8: True})
        ch = f"s16-{uuid.uuid4().hex}"
        self.bus = can.Bus(interface="virtual", channel=ch, ignore_config=True)
        self.out = can.Bus(interface="virtual", channel=ch, ignore_config=True)
        self.slave = CanopenSlave(self.bus, self.drive, node_id=NODE, own_timer=False,
                                  clock=lambda: self.drive.now)
        self.slave.start()
        self.drain()

    def close(self) -> None:
        self.slave.close()
        self.bus.shutdown()
        self.out.shutdown()

    def feed(self, cid: int, data: bytes = b"", remote: bool = False) -> None:
        # stamped on the drive's clock, which the slave measures SYNC periods on (a wall
        # stamp gave a 1 ms SYNC sequence a false AL3E2: helper-115)
        msg = can.Message(arbitration_id=cid, data=data, is_extended_id=False,
                          is_remote_frame=remote, timestamp=self.drive.now / 1e9)
        with self.slave.lock:
            self.slave.handle_frame(msg)

    def run(self, ms: int) -> None:
        end = self.drive.now + ms * MS
        while self.drive.now < end:
            self.drive.advance(MS)
            self.slave.tick(self.drive.now)

    def drain(self) -> list[can.Message]:
        out = []
        while (m := self.out.recv(0.005)) is not None:
            out.append(m)
        return out

    def sdo(self, data: bytes) -> bytes:
        self.drain()
        self.feed(0x600 + NODE, data)
        got = [bytes(m.data) for m in self.drain() if m.arbitration_id == 0x580 + NODE]
        assert got, "no SDO answer"
        return got[0]

    def write(self, index: int, sub: int, value: int, size: int = 4) -> int | None:
        """An expedited download; None when acknowledged, else the abort code."""
        cs = 0x23 | (4 - size) << 2
        r = self.sdo(struct.pack("<BHB", cs, index, sub)
                     + (value & ((1 << 8 * size) - 1)).to_bytes(size, "little").ljust(4, b"\0"))
        return None if r[0] == 0x60 else struct.unpack_from("<I", r, 4)[0]

    def read(self, index: int, sub: int = 0) -> int:
        r = self.sdo(struct.pack("<BHBI", 0x40, index, sub, 0))
        assert r[0] & 0xE0 == 0x40, r.hex()
        return struct.unpack_from("<I", r, 4)[0]

    def map_pdo(self, comm: int, entries: list[int], ttype: int) -> None:
        """The manual's sequence (L17980-L18024): disable, count 0, entries, count, type,
        enable; then NMT start."""
        cob = (0x200 if comm < 0x1800 else 0x180) + NODE
        mapping = comm + 0x200
        assert self.write(comm, 1, 0x80000000 | cob) is None
        assert self.write(mapping, 0, 0, 1) is None
        for i, e in enumerate(entries, 1):
            assert self.write(mapping, i, e) is None
        assert self.write(mapping, 0, len(entries), 1) is None
        assert self.write(comm, 2, ttype, 1) is None
        assert self.write(comm, 1, cob) is None
        self.feed(0x000, bytes([0x01, NODE]))


@pytest.fixture
def rig():
    r = Rig()
    try:
        yield r
    finally:
        r.close()


def test_p3_001_written_over_canopen_sets_only_digit_z(rig):
    """L10542 note 1: "當由 CANopen 設定本參數時，只能設定位數 Z，其它則不改變". 0x0400 meant
    Z = 4 (1 Mbit/s, L16844); the RS-485 digit X (3: 38400) had become 0 (4800)."""
    assert rig.read(0x2301) == 0x0203  # the default (L10512)
    assert rig.write(0x2301, 0, 0x0400, 2) is None
    assert rig.read(0x2301) == 0x0403
    assert rig.write(0x2301, 0, 0x0005, 2) is None  # X = 5 asked: only Z (0) is taken
    assert rig.read(0x2301) == 0x0003


def test_an_rpdo_to_a_parameter_whose_writing_is_restricted_raises_al132(rig):
    """AL132 (L20015-L20019): "利用 CAN 寫入參數時，該參數當下的狀態為禁止寫入". P4.016
    without P2.008 = 22 is refused by an SDO (0800 0020h); by an RPDO nothing was raised."""
    assert rig.write(0x2410, 0, 1, 2) == 0x08000020
    rig.map_pdo(0x1400, [0x24100010], 255)
    rig.feed(0x200 + NODE, (1).to_bytes(2, "little"))
    rig.run(2)
    assert "AL132" in rig.drive.alarms.active
    assert rig.drive.params.read("P4.016") == 0


@pytest.mark.parametrize("data", [(2222).to_bytes(4, "little") + b"\x01",  # DLC 5
                                  (3333).to_bytes(2, "little")])            # DLC 2
def test_an_rpdo_whose_length_is_not_its_mappings_raises_al123_and_is_not_applied(rig, data):
    """AL123 (L19959-L19963): "訊息中資料長度與指定的物件不符". 607Ah is mapped (32 bits, 4
    bytes); a 5-byte RPDO had been applied without an alarm."""
    rig.map_pdo(0x1400, [0x607A0020], 255)
    before = rig.drive.read_object(0x607A, 0)
    rig.feed(0x200 + NODE, data)
    rig.run(2)
    assert "AL123" in rig.drive.alarms.active
    assert rig.drive.read_object(0x607A, 0) == before
    rig.feed(0x000, bytes([0x81, NODE]))  # NMT reset clears it (L19963)
    rig.run(2)
    assert "AL123" not in rig.drive.alarms.active


def test_an_rpdo_of_its_mappings_length_is_applied(rig):
    rig.map_pdo(0x1400, [0x607A0020], 255)
    rig.feed(0x200 + NODE, (2222).to_bytes(4, "little"))
    rig.run(2)
    assert rig.drive.read_object(0x607A, 0) == 2222
    assert not rig.drive.alarms.active


def test_a_type_252_tpdo_sends_on_rtr_what_the_last_sync_sampled(rig):
    """1800h sub 2 = 252: synchronous, RTR only (L18075-L18083); CiA 301: the data is taken
    at the SYNC and sent on the RTR. It had sent the value at RTR time."""
    rig.map_pdo(0x1800, [0x60410010], 252)
    rig.run(2)
    rig.feed(0x080)  # SYNC
    at_sync = rig.drive.read_object(0x6041, 0)
    rig.drive.write_object(0x6040, 0, 0x06)  # Shutdown: the statusword changes after the SYNC
    rig.run(5)
    assert rig.drive.read_object(0x6041, 0) != at_sync
    rig.drain()
    rig.feed(0x180 + NODE, remote=True)
    got = [bytes(m.data) for m in rig.drain() if m.arbitration_id == 0x180 + NODE]
    assert got == [at_sync.to_bytes(2, "little")]


@pytest.mark.parametrize(("comm", "cob"), [(0x1800, 0x705), (0x1400, 0x000), (0x1400, 0x601),
                                          (0x1801, 0x585), (0x1400, 0x7E5)])
def test_a_pdo_on_a_restricted_cob_id_is_refused(rig, comm, cob):
    """CiA 301 §7.3.5: NMT, SDO and error-control identifiers are no PDO's; a TPDO on 705h
    went out as this node's heartbeat."""
    assert rig.write(comm, 1, 0x80000000 | cob) is None  # invalid: any identifier is kept
    assert rig.write(comm, 1, cob) == 0x06090030
    assert rig.write(comm, 1, 0x180 + NODE if comm >= 0x1800 else 0x200 + NODE) is None


def test_modbus_line_follows_p3_001_and_p3_002_written_any_way_after_a_power_cycle():
    """P3.001 and P3.002 set the RS-485 line (L10509-L10527, L10547); written other than
    by a Modbus write (an SDO, the keypad) they had never reached the face, even after a
    power cycle."""
    d = Drive(inputs={8: True})
    out: list[bytes] = []
    face = ModbusSlave(d.params, send=out.append)
    d.subscribe(lambda ev: type(ev).__name__ == "PowerCycled" and face.power_cycle())
    assert (face.line.mode, face.line.baud) == ("rtu", 38400)
    d.write_object(0x2302, 0, 1)  # P3.002 = 1: ASCII 7,E,1 (L10547)
    d.params.write("P3.001", 0x0201)  # X = 1: 9600
    d.power_cycle()
    assert (face.line.mode, face.line.baud) == ("ascii", 9600)
    t = S
    for adu, answered in ((mb.ascii_encode(0x7F, bytes([3, 0, 0, 0, 1])), True),
                          (mb.rtu_encode(0x7F, bytes([3, 0, 0, 0, 1])), False)):
        out.clear()
        t += S
        face.feed(adu, t)
        face.tick(t + 100 * MS)
        assert bool(out) == answered


def test_an_explicit_modbus_line_keeps_winning_over_a_power_cycle():
    d = Drive(inputs={8: True})
    face = ModbusSlave(d.params, mode="rtu", baud=115200)
    d.subscribe(lambda ev: type(ev).__name__ == "PowerCycled" and face.power_cycle())
    d.write_object(0x2302, 0, 1)
    d.power_cycle()
    assert (face.line.mode, face.line.baud) == ("rtu", 115200)


def test_review_p3_001_over_canopen_keeps_a_digit_written_before_the_power_cycle(rig):
    """The other digits come from the value stored (a write of X waiting for the power
    cycle), not the one in force: a pending X had been lost."""
    rig.drive.params.write("P3.001", 0x0201)  # X = 1 (9600), ● power cycle
    assert rig.write(0x2301, 0, 0x0400, 2) is None  # Z = 4 over CANopen
    rig.drive.power_cycle()
    assert rig.drive.params.get("P3.001") == 0x0401


def test_review_a_line_written_over_modbus_stays_after_a_power_cycle():
    """A face built with an explicit line (as every virtual drive's is: the port's rate)
    that is then moved by a Modbus write of P3.001 had gone back to the old rate at the power
    cycle, while P3.001 said the new one."""
    d = Drive(inputs={8: True})
    out: list[bytes] = []
    face = ModbusSlave(d.params, mode="rtu", baud=38400, send=out.append)
    d.subscribe(lambda ev: type(ev).__name__ == "PowerCycled" and face.power_cycle())
    t = S
    face.feed(mb.rtu_encode(0x7F, bytes([6, 0x03, 0x02, 0x02, 0x01])), t)  # P3.001 = 0x0201
    face.tick(t + 100 * MS)
    assert out and face.line.baud == 9600
    d.power_cycle()
    assert face.line.baud == 9600 and d.params.get("P3.001") == 0x0201
