"""The bench's mechanical brake follows the DO line its coil is wired to (issue 13, item 8).

BRKR (0x08, L15286) is a DO *function*: it controls the brake only through the DO it is
mapped to (P2.018-P2.022, P2.041, L9603). P2.041 = 0 maps BRKR to no output, so BRKR then
controls nothing. The mechanical delays are the motor's (Appendix A, L20485-20494).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS


def cycle_son(drive: Drive) -> list[bool]:
    """SON on 300 ms, off 300 ms; brake_released sampled every ms."""
    seen = []
    drive.set_di(1, True)
    for _ in range(300):
        drive.advance(MS)
        seen.append(drive.snapshot()["brake_released"])
    drive.set_di(1, False)
    for _ in range(300):
        drive.advance(MS)
        seen.append(drive.snapshot()["brake_released"])
    return seen


def test_brake_on_brkr_do_releases_and_clamps() -> None:
    # BRKR on DO6: release 20 ms after BRKR On, clamp 50 ms after BRKR Off (Mechanics data).
    drive = Drive(inputs={8: True}, params={"P2.041": 0x0108, "P1.042": 100})
    assert drive.brake_line == 6
    assert drive.snapshot()["brake_released"] is False  # unpowered coil holds
    seen = cycle_son(drive)
    assert seen[0] is False and True in seen and seen[-1] is False
    assert drive.axis.brake_clamped


def test_unmapped_brkr_controls_no_brake() -> None:
    # P2.041 = 0 (factory default, L9603): BRKR is mapped to no DO, so nothing clamps.
    drive = Drive(inputs={8: True}, params={"P2.041": 0, "P1.042": 100})
    assert drive.brake_line is None
    seen = cycle_son(drive)
    assert drive.brake.brkr is False  # the function itself still follows the servo
    assert all(seen)  # no brake wired: the shaft is never held
    assert not drive.axis.brake_clamped


def test_brake_follows_its_wired_line_not_the_function() -> None:
    # Bench wires the coil to DO4 (TPOS by default, L9359): the brake follows DO4's level,
    # whatever BRKR does on DO6.
    drive = Drive(
        mechanics=Mechanics(brake_do=4), inputs={8: True}, params={"P2.041": 0x0108}
    )
    assert drive.brake_line == 4
    level = drive.do(4)
    drive.advance(100 * MS)
    assert drive.snapshot()["brake_released"] is level


def test_bad_brake_do_is_refused() -> None:
    with pytest.raises(ValueError, match="brake_do"):
        Mechanics.from_dict({"brake_do": 7})
