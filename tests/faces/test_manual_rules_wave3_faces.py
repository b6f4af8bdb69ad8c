"""Manual rules of the drive's CANopen / Modbus faces written afresh (issue 22).

PDO defaults (1400h L17940, 1600h L17995, 1800h L18069/L18107, 1A00h L18124: all 0;
"PDO 必須設定通訊參數與映射參數才能使用" L16910), P3.009 E (L10629-10645, AL3E2 remedy
"適度放寬同步誤差範圍設定，P3.009 E" L20159-20163), NMT Stop (L17089-17095), AL020 and
P3.004 (L10571-10578, L19598-19602). A real Drive behind the face, injected clock.
"""

from __future__ import annotations

import configparser
import struct

import pytest
from test_comm_faults import NODE, Rig

from hil.faces.modbus_slave import ModbusSlave
from hil.model.drive import Drive
from hil.paths import fixture
from hil.units import MS

S = 1_000_000_000


@pytest.fixture
def rig():
    r = Rig()
    yield r
    r.close()


def upload(r: Rig, index: int, sub: int) -> int:
    """Expedited SDO upload through the face (CiA 301)."""
    r.emcys()  # drain
    r.feed(0x600 + NODE, struct.pack("<BHB", 0x40, index, sub) + bytes(4))
    while (m := r.out.recv(0.5)) is not None:
        if m.arbitration_id == 0x580 + NODE:
            assert m.data[0] & 0xE0 == 0x40, bytes(m.data).hex()
            return int.from_bytes(m.data[4:8], "little")
    raise AssertionError("no SDO answer")


PRINTED_ZERO = [(0x1400, 2), (0x1400, 5), (0x1600, 0), (0x1800, 2), (0x1800, 5), (0x1A00, 0)]


@pytest.mark.parametrize(("index", "sub"), PRINTED_ZERO)
def test_pdo_defaults_are_the_printed_zeros(rig: Rig, index: int, sub: int) -> None:
    """Every PDO communication/mapping default the manual prints is 0 (see module doc)."""
    assert upload(rig, index, sub) == 0


@pytest.mark.parametrize(("index", "sub"), PRINTED_ZERO)
def test_the_eds_agrees_with_the_manual(index: int, sub: int) -> None:
    eds = configparser.ConfigParser()
    eds.read(fixture("drive", "a3.eds"))
    section = f"{index:X}sub{sub:X}"
    assert int(eds[section]["DefaultValue"], 0) == 0


def test_no_unrequested_tpdo_after_start(rig: Rig) -> None:
    """With no mapping there is no TPDO1: nothing on 180h+node after NMT start."""
    rig.start()
    rig.run(100)
    seen = []
    while (m := rig.out.recv(0.01)) is not None:
        seen.append(m.arbitration_id)
    assert 0x180 + NODE not in seen


def _sync_ip(r: Rig, e: int) -> None:
    """IP mode (6060h = 7) with 1006h = 10 ms, P3.009 E = `e`, NMT operational."""
    r.drive.params.write("P3.009", 0x5050 | e)
    r.drive.write_object(0x6060, 0, 7)
    r.sdo_write(0x1006, 0, 10_000)
    r.start()


@pytest.mark.parametrize(("e", "early_us", "alarm"), [
    (5, 80, True),   # 80 us early > E x 10 us = 50 us
    (9, 80, False),  # widened E (90 us): the remedy the alarm table gives
    (9, 120, True),
])  # fmt: skip
def test_p3009_e_is_the_early_sync_tolerance(e: int, early_us: int, alarm: bool) -> None:
    r = Rig(sync_tolerance="p3009")
    try:
        _sync_ip(r, e)
        r.feed(0x080, at_ms=0)
        r.feed(0x080, at_ms=10 - early_us / 1000)
        assert ("AL3E2" in r.drive.alarms.active) is alarm
    finally:
        r.close()


def test_default_sync_reading_raises_only_on_half_a_cycle(rig: Rig) -> None:
    """The default `sync_tolerance: ratio` (docs/manual-choices.md): 4 ms early is tolerated,
    a SYNC after 4 ms of a 10 ms cycle is early."""
    _sync_ip(rig, 5)
    rig.feed(0x080, at_ms=0)
    rig.feed(0x080, at_ms=6)
    assert "AL3E2" not in rig.drive.alarms.active
    rig.feed(0x080, at_ms=10)
    assert "AL3E2" in rig.drive.alarms.active


def test_nmt_stop_through_the_face_disables_the_moving_axis(rig: Rig) -> None:
    """NMT Stop (cs 02h) while turning: the face stops, the drive disables (safe default)."""
    d = rig.drive
    d.write_object(0x6060, 0, 3)
    rig.enable()
    d.write_object(0x60FF, 0, 1000)
    rig.start()
    rig.run(400)
    assert d.axis.velocity_rpm > 90
    rig.feed(0x000, bytes([0x02, NODE]))
    assert rig.slave.state == "STOPPED"
    rig.run(1500)
    assert not d.servo_on and abs(d.axis.velocity_rpm) < 0.01


def test_al020_counts_again_from_an_alarm_reset() -> None:
    """P3.004 = 1 s: a silent line raises AL020 after 1 s (L10571-10578); after the alarm
    reset the line is still silent, so (al020_rearm: reset) it comes again 1 s later."""
    d = Drive(inputs={8: True})
    d.params.write("P3.004", 1)
    fired: list[int] = []
    slave = ModbusSlave(d.params, station=1, mode="rtu", baud=115200,
                        on_timeout=lambda t: (fired.append(t), d.raise_alarm("AL020")))
    d.subscribe(lambda ev: getattr(ev, "code", "") == "AL020" and not ev.active
                and slave.rearm_timeout(ev.t))
    for _ in range(1500):
        d.advance(MS)
        slave.tick(d.now)
    assert len(fired) == 1 and "AL020" in d.alarms.active
    reset_at = d.now
    d.alarms.reset("di")
    for _ in range(1500):
        d.advance(MS)
        slave.tick(d.now)
    assert len(fired) == 2
    assert fired[1] - reset_at == pytest.approx(S, abs=2 * MS)


@pytest.mark.integration  # a real pty and the drive host in real time
def test_al020_rearm_in_a_drive_process_counts_from_the_reset(tmp_path) -> None:
    """The same rule through `VirtualDriveStack` (the face's line clock and the model's clock
    differ): after the reset AL020 stays off for P3.004, then comes again."""
    import time

    from hil.virtual.stack import DriveSpec, VirtualDriveStack

    spec = DriveSpec(name="al020", rs485=f"pty:{tmp_path / 'tty'}?baud=115200", station=1)
    with VirtualDriveStack(spec) as stack:
        d = stack.drive

        def active() -> bool:
            return stack.host.call(lambda: "AL020" in d.alarms.active)

        stack.host.call(d.params.write, "P3.004", 1)
        end = time.monotonic() + 5
        while not active() and time.monotonic() < end:
            time.sleep(0.02)
        assert active()
        stack.host.call(d.alarms.reset, "di")
        t_reset = time.monotonic()
        time.sleep(0.5)
        assert not active()  # not at the next tick: P3.004 = 1 s counts from the reset
        while not active() and time.monotonic() < t_reset + 5:
            time.sleep(0.02)
        assert active()
        assert 0.9 <= time.monotonic() - t_reset <= 3.0


def _emcy_code(frame: bytes) -> tuple[int, int]:
    return int.from_bytes(frame[:2], "little"), int.from_bytes(frame[3:5], "little")


@pytest.mark.parametrize("priority", ["class", "latest"])
def test_emcy_carries_one_alarm_a_higher_priority_one_overrides(priority: str) -> None:
    """"緊急物件每次僅能傳輸一個異警。當有優先權更高的異警時 ... 優先權較高的異警會覆蓋前次"
    (L17063): with AL011 (ALM) active a later AL020 (WARN) neither replaces it in 603Fh nor
    sends an EMCY; clearing AL020 sends nothing, clearing AL011 then announces AL020, and
    0000h comes once none is left. `emcy_priority: latest` keeps the old reading."""
    r = Rig(emcy_priority=priority)
    try:
        r.start()
        r.run(5)
        r.emcys()
        r.drive.alarms.raise_alarm("AL011")
        r.run(2)
        assert [_emcy_code(f) for f in r.emcys()] == [(0x7305, 0x011)]
        r.drive.alarms.raise_alarm("AL020")  # WARN, lower priority
        r.run(2)
        sent = [_emcy_code(f) for f in r.emcys()]
        if priority == "latest":
            assert sent == [(0x7510, 0x020)] and upload(r, 0x603F, 0) == 0x7510
            return
        assert sent == [] and upload(r, 0x603F, 0) == 0x7305
        r.drive.alarms.clear("AL011")
        r.run(2)
        assert [_emcy_code(f) for f in r.emcys()] == [(0x7510, 0x020)]
        assert upload(r, 0x603F, 0) == 0x7510
        r.drive.alarms.raise_alarm("AL009")  # ALM: higher, overrides
        r.run(2)
        assert [_emcy_code(f) for f in r.emcys()][-1][1] == 0x009
        r.drive.alarms.clear("AL020")  # the lower one goes: nothing to announce
        r.run(2)
        assert r.emcys() == []
        r.drive.alarms.clear("AL009")
        r.run(2)
        assert [_emcy_code(f) for f in r.emcys()] == [(0, 0)]
    finally:
        r.close()
