"""An RPDO value the drive refuses raises its PDO alarm (table 13: AL124 "data out of the
object's range", L19965-L19969), written from the digest (a3-comms.md §4.3); an outside
review (helper-23, wave 3 session 12) found it silently dropped."""

from __future__ import annotations

import struct
import time
import uuid

import can
import pytest

from hil.virtual.stack import DriveSpec, VirtualDriveStack

NODE = 5


@pytest.fixture
def drive():
    chan = f"rpdo-alarms-{uuid.uuid4().hex}"
    master = can.Bus(interface="virtual", channel=chan, ignore_config=True)
    stack = VirtualDriveStack(DriveSpec(name="d1", can=f"virtual:{chan}", node_id=NODE,
                                        inputs={6: True, 7: True, 8: True},
                                        params={"P1.001": 0x0C})).start()
    try:
        yield master, stack
    finally:
        stack.stop()
        master.shutdown()


def _sdo(master: can.Bus, data: bytes) -> bytes:
    master.send(can.Message(arbitration_id=0x600 + NODE, data=data, is_extended_id=False))
    end = time.monotonic() + 2.0
    while time.monotonic() < end:
        r = master.recv(0.1)
        if r is not None and r.arbitration_id == 0x580 + NODE:
            return bytes(r.data)
    raise AssertionError("no SDO answer")


def _write(master: can.Bus, index: int, sub: int, value: int, size: int) -> None:
    cs = {4: 0x23, 2: 0x2B, 1: 0x2F}[size]
    data = struct.pack("<BHB", cs, index, sub) + value.to_bytes(4, "little")
    assert _sdo(master, data)[0] == 0x60, (hex(index), sub)


def _alarms(stack: VirtualDriveStack) -> list[str]:
    return stack.host.call(lambda: list(stack.drive.alarms.active))


@pytest.mark.parametrize(("entry", "value", "size", "alarm"), [
    (0x60830020, 0, 4, "AL124"),        # 6083h: 1 ~ 65500 (L18395)
    (0x60830020, 70000, 4, "AL124"),
    (0x60710010, 3001, 2, "AL124"),     # 6071h: -3000 ~ 3000
    (0x60830020, 500, 4, None),         # in range: applied, no alarm
])
def test_an_rpdo_value_out_of_range_raises_al124(drive, entry, value, size, alarm):
    master, stack = drive
    # RPDO1 mapped as the manual's sequence: disable, zero the count, map, count, enable
    _write(master, 0x1400, 1, 0x80000000 | (0x200 + NODE), 4)
    _write(master, 0x1600, 0, 0, 1)
    _write(master, 0x1600, 1, entry, 4)
    _write(master, 0x1600, 0, 1, 1)
    _write(master, 0x1400, 2, 255, 1)
    _write(master, 0x1400, 1, 0x200 + NODE, 4)
    master.send(can.Message(arbitration_id=0x000, data=bytes([0x01, NODE]),
                            is_extended_id=False))  # NMT start: PDOs in operational
    time.sleep(0.05)
    master.send(can.Message(arbitration_id=0x200 + NODE,
                            data=value.to_bytes(size, "little", signed=True),
                            is_extended_id=False))
    end = time.monotonic() + 2.0
    while alarm is not None and alarm not in _alarms(stack) and time.monotonic() < end:
        time.sleep(0.01)
    if alarm is None:
        time.sleep(0.05)
        assert "AL124" not in _alarms(stack)
        assert stack.host.call(lambda: stack.drive.read_object(0x6083, 0)) == value
    else:
        assert alarm in _alarms(stack)
