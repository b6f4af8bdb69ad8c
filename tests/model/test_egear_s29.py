"""6093h and P1.044/P1.045 are one gear, written from the manual (seed 002; found by an
outside probe, helper-127): 6093h sub 1/2 are P1.044/P1.045 ("伺服對應參數 P1.044",
L18838-18854), 1~2^29-1 and 1~2^31-1 (L8521, L8537), ▲ not writable while Servo On
(L8527, L8551, L6721)."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ObjectError
from hil.units import MS, S

REV = 16_777_216  # counts per turn (24-bit single turn)


def _drive() -> Drive:
    # CANopen mode with P3.012.Z = 0: 6093h (and so P1.044/P1.045) is 1/1 at power-up (L10744)
    d = Drive(inputs={8: True}, params={"P1.001": 0x000C, "P3.012": 0x0000})
    d.advance(5 * MS)
    return d


def test_a_gear_written_as_the_parameters_is_the_cia402_gear_at_once() -> None:
    """Written through 212Ch/212Dh, the gear stayed 1/1 on the CiA 402 side until a power
    cycle: a PP move of 100 000 PUU with 16777216/100000 went 100 000 counts, not a turn."""
    d = _drive()
    d.write_object(0x212C, 0, REV)  # P1.044
    d.write_object(0x212D, 0, 100_000)  # P1.045: 100 000 PUU a turn
    assert (d.read_object(0x6093, 1), d.read_object(0x6093, 2)) == (REV, 100_000)
    d.write_object(0x6060, 0, 1)
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)
    d.write_object(0x607A, 0, 100_000)
    d.write_object(0x6081, 0, 200_000)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(3 * S)
    assert abs(d.axis.position - REV) < 2  # one turn
    assert d.read_object(0x6064, 0) == 100_000


def test_6093h_keeps_the_parameters_ranges() -> None:
    d = _drive()
    for sub, value in ((1, 2**29), (1, 0), (2, 2**31)):
        with pytest.raises(ObjectError):
            d.write_object(0x6093, sub, value)
    assert (d.params.get("P1.044"), d.params.get("P1.045")) == (1, 1)
    d.write_object(0x6093, 1, 2**29 - 1)  # the top of the range is taken
    assert d.params.get("P1.044") == 2**29 - 1


def test_6093h_is_not_writable_while_the_servo_is_on_by_di_son() -> None:
    """Checked only for a servo on by 6040h: with DI.SON, 6093h changed P1.044 with the
    motor on (and 6064h jumped)."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x0001})  # PR mode, SON is DI1
    d.advance(5 * MS)
    d.set_di(1, True)
    d.advance(50 * MS)
    assert d.servo_on
    with pytest.raises(ObjectError) as e:
        d.write_object(0x6093, 1, 1000)
    assert e.value.abort_code == 0x08000022  # data cannot be stored: state
    assert d.params.get("P1.044") == REV
