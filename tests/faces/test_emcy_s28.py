"""EMCY around NMT states and resets, from an outside probe of the CiA 301 side (session 28,
helper-109): "當伺服偵測到異常時，會發送異警並透過緊急物件 ... 通知上位機" (L17061-L17063); EMCY
in PRE-OPERATIONAL and OPERATIONAL only, the boot-up alone in Initialization (L17089-L17095);
AL401 (L20183-L20187)."""

from __future__ import annotations

import pytest

from tests.faces.test_manual_rules_s16 import NODE, Rig

EMCY = 0x80 + NODE
BOOT = 0x700 + NODE


def _frames(r: Rig) -> list[tuple[int, bytes]]:
    return [(m.arbitration_id, bytes(m.data)) for m in r.drain()]


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def nmt(r: Rig, cs: int) -> None:
    r.feed(0x000, bytes([cs, NODE]))  # 01h start, 02h stop, 80h pre-operational


def emcys(r: Rig, ms: int = 2) -> list[bytes]:
    """The EMCY frames' data sent in the next `ms`."""
    r.run(ms)
    return [data for cid, data in _frames(r) if cid == EMCY]


def test_an_alarm_cleared_while_stopped_is_announced_when_it_comes_again(rig):
    nmt(rig, 0x01)
    rig.drive.alarms.raise_alarm("AL020")
    assert emcys(rig)[0][:2] == b"\x10\x75"  # 7510h
    nmt(rig, 0x02)  # stop: no EMCY (L17089-L17095)
    rig.drive.alarms.reset("di")
    assert emcys(rig) == []
    nmt(rig, 0x01)  # out of STOPPED: the clear it missed (helper-110)
    assert [e[:2] for e in emcys(rig)] == [b"\x00\x00"]
    rig.drive.alarms.raise_alarm("AL020")  # a new occurrence: a new EMCY
    [e] = emcys(rig)
    assert e[:2] == b"\x10\x75" and e[3:5] == b"\x20\x00"


@pytest.mark.parametrize("priority", ["class", "latest"])
def test_an_alarm_raised_while_stopped_is_announced_at_the_start(rig, priority):
    from hil.model.options import ModelOptions

    rig.drive.options = ModelOptions(emcy_priority=priority)
    nmt(rig, 0x02)
    rig.drive.alarms.raise_alarm("AL020")
    assert emcys(rig) == []
    nmt(rig, 0x80 if priority == "class" else 0x01)  # EMCY allowed again
    [e] = emcys(rig)
    assert e[3:5] == b"\x20\x00"


def test_al401_is_announced_after_the_boot_up_and_its_clear_too():
    r = Rig()
    try:
        r.feed(0x000, bytes([0x01, NODE]))
        r.drive.set_di(1, True)  # SON
        r.run(20)
        assert r.drive.servo_on
        _frames(r)
        r.feed(0x000, bytes([0x81, NODE]))  # reset node with the servo on: AL401
        r.run(2)
        seq = [f for f in _frames(r) if f[0] in (EMCY, BOOT)]
        assert [f[0] for f in seq] == [BOOT, EMCY]  # the boot-up first
        assert seq[1][1][3:5] == b"\x01\x04"  # AL401 in bytes 3-4 (L17069)
        r.drive.write_object(0x6040, 0, 0x00)
        r.drive.write_object(0x6040, 0, 0x80)  # fault reset clears AL401 (L20186)
        r.run(2)
        assert "AL401" not in r.drive.alarms.active
        assert [f[1][:3] for f in _frames(r) if f[0] == EMCY] == [b"\x00\x00\x00"]
    finally:
        r.close()


def test_a_regular_sync_fed_on_the_drive_clock_raises_nothing():
    """The rig stamps frames on the drive's clock: a 1 ms SYNC with 1006h = 1000 us in IP
    mode is no early SYNC (a wall-clock stamp had raised AL3E2 on the second; helper-115)."""
    r = Rig()
    try:
        r.run(2)
        r.write(0x1006, 0, 1000, 4)
        r.run(2)  # one SDO a ms (two within 1 ms are AL111, L19933)
        r.write(0x6060, 0, 7, 1)
        r.run(2)
        for cw in (0x06, 0x07, 0x0F):
            r.write(0x6040, 0, cw, 2)
            r.run(2)
        r.feed(0x000, bytes([0x01, NODE]))
        for _ in range(20):
            r.feed(0x080)
            r.run(1)
        assert r.drive.alarms.active == ()
    finally:
        r.close()
