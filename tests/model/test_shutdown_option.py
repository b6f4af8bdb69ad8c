"""605Bh shutdown option code decides the stop of a CiA 402 servo off (issue 13, item 3).

L18342-18358: 605Bh = 0: at servo off the dynamic brake does not act, free run (friction
only); 605Bh = 1: the dynamic brake acts. P1.032.Y (L8321-8327) keeps deciding for a SON
servo off, alarms and EMGS. Choice: `ModelOptions.shutdown_option_scope`.
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS

SHUTDOWN, SWITCH_ON, ENABLE = 0x06, 0x07, 0x0F  # L18272-18281


def speed_after_cia402_shutdown(p605b: int, *, p1032: int = 0, **opts) -> float:
    drive = Drive(options=ModelOptions(**opts), inputs={8: True}, params={"P1.032": p1032})
    drive.write_object(0x605B, 0, p605b)
    drive.write_object(0x6060, 0, 3)  # PV
    drive.write_object(0x60FF, 0, 10000)  # 1000.0 rpm (0.1 rpm units)
    for cw in (SHUTDOWN, SWITCH_ON, ENABLE):
        drive.write_object(0x6040, 0, cw)
    drive.advance(500 * MS)
    assert drive.axis.velocity_rpm > 900
    drive.write_object(0x6040, 0, SHUTDOWN)  # transition 8: servo off
    assert not drive.servo_on
    drive.advance(30 * MS)
    return drive.axis.velocity_rpm


def test_605b_0_coasts_and_1_uses_the_dynamic_brake() -> None:
    coast = speed_after_cia402_shutdown(0)
    dyn = speed_after_cia402_shutdown(1)
    assert dyn < coast  # the dynamic brake stops faster than free run (L18356-18358)


def test_605b_wins_over_p1032_for_a_state_machine_servo_off() -> None:
    # P1.032.Y = 1 (coast, L8325) but 605Bh = 1 (dynamic brake): the brake acts.
    assert speed_after_cia402_shutdown(1, p1032=0x10) == pytest.approx(
        speed_after_cia402_shutdown(1, p1032=0x00)
    )
    assert speed_after_cia402_shutdown(1, p1032=0x10) < speed_after_cia402_shutdown(0, p1032=0x10)


def test_scope_never_leaves_p1032_in_charge() -> None:
    a = speed_after_cia402_shutdown(0, shutdown_option_scope="never")
    b = speed_after_cia402_shutdown(1, shutdown_option_scope="never")
    assert a == pytest.approx(b)


def test_son_servo_off_keeps_p1032() -> None:
    # A SON servo off is P1.032.Y's (L8321) whatever 605Bh says.
    def after_son_off(p605b: int) -> float:
        drive = Drive(inputs={8: True}, params={"P1.032": 0x10})  # coast
        drive.write_object(0x605B, 0, p605b)
        drive.set_di(1, True)
        drive.advance(10 * MS)
        drive.set_di(1, False)
        drive.advance(10 * MS)
        return drive.axis.stop_mode

    assert after_son_off(0) == after_son_off(1) == 1


def test_bad_scope_is_refused() -> None:
    with pytest.raises(ValueError, match="shutdown_option_scope"):
        ModelOptions.from_dict({"shutdown_option_scope": "sometimes"})
