"""AL060 / AL06A clear once a new absolute origin is set (issue 13, item 2).

L16397: "座標設定完成後，警告 AL06A (或 AL060)會自動清除"; AL060's own clearing procedure is
rebuilding the origin (L19767), AL06A clears after initialisation (L19801).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.units import MS

ABS = {"P2.069": 1, "P2.011": 0x011D, "P2.012": 0x011F}  # absolute; DI2 ABSE, DI3 ABSC


def origin_by_p2071(drive: Drive) -> None:
    drive.params.write("P2.008", 271)  # key first (L10074-10081)
    drive.params.write("P2.071", 1)


def origin_by_absc(drive: Drive) -> None:
    drive.set_di(2, True)  # ABSE on, then ABSC rising edge (L16436-16441)
    drive.advance(50 * MS)
    drive.set_di(3, True)
    drive.advance(50 * MS)


@pytest.mark.parametrize("set_origin", [origin_by_p2071, origin_by_absc])
def test_al060_clears_when_the_origin_is_rebuilt(set_origin) -> None:
    drive = Drive(inputs={8: True}, params=ABS)
    origin_by_p2071(drive)
    assert not {"AL06A", "AL060"} & set(drive.alarms.active)
    drive.power_cycle(battery=False)  # battery lost while off: coordinate lost (L19759)
    assert "AL060" in drive.alarms.active
    set_origin(drive)
    assert "AL060" not in drive.alarms.active  # L16397, L19767: no power cycle needed
    assert drive.params.get("P0.001") == 0


def test_al06a_clears_when_the_first_origin_is_set() -> None:
    drive = Drive(inputs={8: True}, params=ABS)
    assert "AL06A" in drive.alarms.active  # first use: no coordinate yet (L16397, L19795)
    origin_by_p2071(drive)
    assert "AL06A" not in drive.alarms.active


def test_homing_origin_clears_al060() -> None:
    # PR homing sets the origin too (L16458): establish_origin ends AL060 as well.
    drive = Drive(inputs={8: True}, params=ABS)
    origin_by_p2071(drive)
    drive.power_cycle(battery=False)
    drive.absolute.establish_origin()
    assert "AL060" not in drive.alarms.active
