"""Alarm clear rules, P0.001, history P4.000-P4.004, 1001h / 1003h."""

from __future__ import annotations

import pytest

from hil.model.alarms import AlarmManager, AlarmOptions
from hil.model.events import AlarmChanged
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler
from hil.profile.alarms import AlarmTable, UnknownAlarm
from hil.profile.params import ParamTable


@pytest.fixture(scope="module")
def table() -> AlarmTable:
    return AlarmTable.load()


@pytest.fixture(scope="module")
def ptable() -> ParamTable:
    return ParamTable.load()


def make(table, ptable, options=None):
    params = ParameterStore(ptable)
    events: list[AlarmChanged] = []
    mgr = AlarmManager(table, Scheduler(), params, events.append, options)
    return mgr, params, events


def test_table_complete(table: AlarmTable) -> None:
    assert len(table) >= 120  # chapter 13.1: general, STO, CANopen, PR (L19323-19491)
    assert table.spec("AL500").clear == "reset"  # L20199
    assert table.spec("AL501").clear == "power_cycle"  # L20205
    assert table.spec("AL013").kind == "WARN" and table.spec("AL013").servo_off
    assert not table.spec("AL014").servo_off  # WARN, servo stays ON (L19339)
    assert table.spec("AL011").emcy == 0x7305  # L17577-17588
    with pytest.raises(UnknownAlarm):
        table.spec("AL999")


def test_al500_reset_only_after_cause_gone(table, ptable) -> None:
    mgr, params, events = make(table, ptable)
    mgr.set_cause("AL500", True)
    assert mgr.active == ("AL500",) and mgr.servo_off_required and mgr.alrm
    assert params.read("P0.001") == 0x500
    assert mgr.reset("di") is True  # cause still present: stays
    mgr.set_cause("AL500", False)
    assert mgr.active == ("AL500",)  # reset class: not auto
    assert mgr.reset("6040h") is False
    assert mgr.active == () and params.read("P0.001") == 0
    assert [(e.code, e.active) for e in events] == [("AL500", True), ("AL500", False)]


def test_p0001_write_zero_resets(table, ptable) -> None:
    mgr, params, _ = make(table, ptable)
    mgr.raise_alarm("AL009")
    params.write("P0.001", 0)  # L7079-7083
    assert mgr.active == ()
    mgr.raise_alarm("AL009")
    mgr.raise_alarm("AL501")
    params.write("P0.001", 0)
    assert mgr.active == ("AL501",)
    assert params.read("P0.001") == 0x501


def test_al501_power_cycle_and_override(table, ptable) -> None:
    mgr, _, _ = make(table, ptable)
    mgr.raise_alarm("AL501")
    mgr.reset("di")
    assert mgr.active == ("AL501",)  # L20201-20205: power cycle only
    mgr.power_cycle()
    assert mgr.active == ()
    assert mgr.history == ["AL501"]  # kept
    mgr2, _, _ = make(table, ptable, AlarmOptions(clear_override={"AL501": "reset"}))
    mgr2.raise_alarm("AL501")
    mgr2.reset("di")
    assert mgr2.active == ()


def test_auto_alarms(table, ptable) -> None:
    mgr, _, _ = make(table, ptable)
    mgr.set_cause("AL013", True)  # EMGS (L19554-19557)
    mgr.set_cause("AL014", True)  # NL (L19559-19563)
    assert mgr.warn and not mgr.alrm
    assert mgr.servo_off_required  # AL013 servo OFF
    mgr.set_cause("AL013", False)
    assert mgr.active == ("AL014",)
    assert not mgr.servo_off_required  # AL014 keeps servo on
    mgr.set_cause("AL014", False)
    assert mgr.active == ()


def test_nmt_reset_class(table, ptable) -> None:
    mgr, _, _ = make(table, ptable)
    mgr.raise_alarm("AL180")
    mgr.reset("di")
    assert mgr.active == ("AL180",)
    mgr.reset("nmt")
    assert mgr.active == ()
    with pytest.raises(ValueError):
        mgr.reset("panel")


def test_al003_follows_p2066_bit2(table, ptable) -> None:
    mgr, params, _ = make(table, ptable)
    mgr.set_cause("AL003", True)
    mgr.set_cause("AL003", False)
    assert mgr.active == ("AL003",)  # P2.066 bit2 = 0: needs ARST (L19512)
    mgr.reset("di")
    params.write("P2.066", params.read("P2.066") | 0x4)
    mgr.set_cause("AL003", True)
    mgr.set_cause("AL003", False)
    assert mgr.active == ()


def test_history_and_error_objects(table, ptable) -> None:
    mgr, params, _ = make(table, ptable)
    for code in ("AL011", "AL009", "AL013", "AL500", "AL006", "AL001"):
        mgr.raise_alarm(code)
    assert mgr.history == ["AL001", "AL006", "AL500", "AL013", "AL009"]
    assert params.read("P4.004") & 0xFFFF == 0x0009
    mgr.raise_alarm("AL001")  # already active: no new record
    assert mgr.history[0] == "AL001" and mgr.history[1] == "AL006"
    mgr2, params2, _ = make(table, ptable)
    mgr2.raise_alarm("AL011")
    assert params2.read("P4.000") == (0x7305 << 16) | 0x0011  # L10790-10792
    assert mgr2.error_history == [0x00117305]  # 1003h, L17584-17588
    assert mgr2.error_register & 0x01
    mgr2.raise_alarm("AL001")  # 0x2310 current
    assert mgr2.error_register & 0x02


def test_an_alarm_reset_request_is_an_event_with_its_source():
    """ARST, P0.001 := 0 and a 6040h fault reset are the resets L20199 names for AL500: each
    is recorded as an AlarmReset event with its source, for the specs (sto.yaml); a CANopen
    NMT reset, which clears only its own alarms, is none."""
    from hil.model.drive import Drive
    from hil.model.events import AlarmReset
    from hil.units import MS

    d = Drive(inputs={8: True})
    seen: list = []
    d.subscribe(lambda e: isinstance(e, AlarmReset) and seen.append(e.source))
    d.params.write("P0.001", 0)
    d.write_object(0x6040, 0, 0x00)
    d.write_object(0x6040, 0, 0x80)
    d.set_di(5, True)  # ARST (factory DI5)
    d.advance(10 * MS)
    d.alarms.reset("nmt")
    assert seen == ["p0001", "6040h", "di"]
