"""Level-triggered DI functions act from power-up (issue 13, items 1 and 7).

Table 8.1 marks EMGS, NL and PL as level-triggered (準位, L15184-15191); the factory DI6-DI8
are NL/PL/EMGS b-contacts, so a drive powered up with them open shows AL013 (L2829-2831).
OPERATION ENABLED means "servo on" (L18326), so under EMGS the drive is not in that state.
"""

from __future__ import annotations

import pytest

from hil.model.cia402 import OPERATION_ENABLED, SWITCH_ON_DISABLED, SWITCHED_ON
from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS

BENCH = {"P2.041": 0x0108}  # BRKR on DO6
SHUTDOWN, SWITCH_ON, ENABLE = 0x06, 0x07, 0x0F  # controlword commands (L18272-18281)


def close_son(drive: Drive) -> None:
    drive.set_di(1, True)
    drive.advance(20 * MS)  # well past the P2.009 filter (2 ms, L9229)


def enable_over_cia402(drive: Drive) -> None:
    for cw in (SHUTDOWN, SWITCH_ON, ENABLE):
        drive.write_object(0x6040, 0, cw)
        drive.advance(2 * MS)


def test_emgs_open_at_power_up_shows_al013_and_blocks_son() -> None:
    # L2829-2831: power-up with DI8 (EMGS, b-contact, L9314) open shows AL013.
    drive = Drive(params=BENCH)  # DI8 not wired closed: EMGS active from power-up
    assert "AL013" in drive.alarms.active
    assert drive.params.get("P0.001") == 0x13  # P0.001 shows the alarm number
    close_son(drive)
    assert not drive.servo_on  # AL013 is servo OFF (L19338)
    assert not drive.do(6)  # BRKR never released
    assert drive.cia402.statusword & 0x6F != 0x27  # not OPERATION ENABLED (L18326)


def test_emgs_open_blocks_son_after_power_cycle_too() -> None:
    drive = Drive(params=BENCH)
    drive.power_cycle(off_for=10 * MS)
    assert "AL013" in drive.alarms.active
    close_son(drive)
    assert not drive.servo_on
    drive.set_di(8, True)  # EMGS released: AL013 clears itself (L19557), SON is level
    drive.advance(20 * MS)
    assert "AL013" not in drive.alarms.active
    assert drive.servo_on


def test_son_closed_during_power_off_does_not_switch_on_under_emgs() -> None:
    drive = Drive(inputs={1: True}, params=BENCH)  # SON and EMGS both present at power-up
    assert not drive.servo_on
    drive.power_cycle(off_for=10 * MS)
    assert not drive.servo_on and "AL013" in drive.alarms.active


@pytest.mark.parametrize(("di", "code"), [(6, "AL014"), (7, "AL015")])
def test_limit_open_at_power_up_shows_its_warning(di: int, code: str) -> None:
    # DI6 = NL, DI7 = PL, both b-contacts (L9294, L9305; L15188-15191): AL014 / AL015.
    closed = {n: True for n in (6, 7, 8) if n != di}
    drive = Drive(inputs=closed, sensors={}, params=BENCH)
    assert drive.alarms.active == (code,)
    bit = 0x8000 if di == 6 else 0x4000  # statusword bits 15 / 14 (L18316-18317)
    assert drive.cia402.statusword & bit


def test_axis_starting_on_a_limit_switch_shows_the_warning() -> None:
    # The bench's own PL switch (DEFAULT_SENSORS, DI7 b-contact) is actuated at power-up.
    from hil.model.mechanics import Mechanics

    drive = Drive(mechanics=Mechanics(pl_rev=0.0), inputs={8: True}, params=BENCH)
    assert drive.alarms.active == ("AL015",)
    drive.power_cycle()
    assert drive.alarms.active == ("AL015",)


def test_all_three_open_at_power_up() -> None:
    # L2829-2831 with DI6-DI8 all unwired: AL013, AL014, AL015 present (P0.001 shows one).
    drive = Drive(sensors={}, params=BENCH)
    assert set(drive.alarms.active) == {"AL013", "AL014", "AL015"}


def test_cia402_cannot_reach_operation_enabled_under_emgs() -> None:
    drive = Drive(params=BENCH)
    enable_over_cia402(drive)
    assert drive.cia402.state == SWITCHED_ON  # transition 4 refused: servo cannot go on
    assert not drive.servo_on
    assert drive.cia402.statusword & 0x6F == 0x23  # SWITCHED ON bits (L18325)
    drive.set_di(8, True)  # EMGS released
    drive.advance(20 * MS)
    drive.write_object(0x6040, 0, ENABLE)
    assert drive.cia402.state == OPERATION_ENABLED and drive.servo_on


def test_emgs_while_operation_enabled_leaves_the_state() -> None:
    # L18326: OPERATION ENABLED = servo on; EMGS switches the servo off (AL013, L19338).
    drive = Drive(inputs={8: True}, params=BENCH)
    enable_over_cia402(drive)
    assert drive.cia402.state == OPERATION_ENABLED
    drive.set_di(8, False)
    drive.advance(20 * MS)
    assert not drive.servo_on
    assert drive.cia402.state == SWITCH_ON_DISABLED
    assert drive.cia402.statusword & 0x4F == 0x40  # L18323


def test_blocked_state_option_keeps_the_old_reading() -> None:
    opts = ModelOptions(extra={"cia402": {"servo_blocked_state": "operation_enabled"}})
    drive = Drive(options=opts, inputs={8: True}, params=BENCH)
    enable_over_cia402(drive)
    drive.set_di(8, False)
    drive.advance(20 * MS)
    assert not drive.servo_on and drive.cia402.state == OPERATION_ENABLED


def test_edge_functions_are_not_applied_at_power_up() -> None:
    # ARST acts on the rising edge only (L15082): closed at power-up is no reset request.
    drive = Drive(inputs={5: True, 8: True}, params=BENCH | {"P2.014": 0x0102})
    drive.alarms.raise_alarm("AL009")  # reset-class alarm, raised after power-up
    drive.advance(20 * MS)
    assert "AL009" in drive.alarms.active
