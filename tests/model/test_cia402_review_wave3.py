"""CiA 402 objects against the manual, written from it (an outside review found these
departures): 607Fh/6080h are P1.055, bit 4 is the main circuit, PP target reached is the
window around 607Ah."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ObjectError
from hil.units import MS


def mk() -> Drive:
    return Drive(inputs={6: True, 7: True, 8: True}, sensors={})


def enable(d: Drive, mode: int) -> None:
    d.write_object(0x6060, 0, mode)
    for cw in (6, 7, 15):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)


def test_p1055_written_limits_pv_at_once_and_is_6080h():
    """6080h "is P1.055" and 607Fh is P1.055 x 10 (L18713-18718, L18730-18735); P1.055 has no
    power-cycle mark (L8700) and limits every mode (L4034)."""
    d = mk()
    d.write_object(0x2137, 0, 1000)  # P1.055 (2137h) = 1000 rpm
    assert (d.read_object(0x6080, 0), d.read_object(0x607F, 0)) == (1000, 10000)
    enable(d, 3)
    d.write_object(0x60FF, 0, 20000)  # 2000 rpm asked
    d.advance(500 * MS)
    assert d.read_object(0x606C, 0) == 10000  # 1000 rpm


def test_6080h_written_is_p1055_and_keeps_its_range():
    d = mk()
    d.write_object(0x6080, 0, 500)
    assert d.params.read("P1.055") == 500
    with pytest.raises(ObjectError) as e:  # P1.055 is 10 ~ max (L8702)
        d.write_object(0x6080, 0, 0)
    assert e.value.abort_code == 0x06090032
    assert d.params.read("P1.055") == 500


@pytest.mark.parametrize("alarm", ["AL003", "AL022"])
def test_statusword_bit4_is_off_without_the_main_circuit(alarm):
    """Bit 4 "voltage enabled: the drive's input side is powered" (L18307)."""
    d = mk()
    d.advance(5 * MS)
    assert d.read_object(0x6041, 0) & 0x10
    d.raise_alarm(alarm)
    d.advance(5 * MS)
    assert not d.read_object(0x6041, 0) & 0x10


def test_pp_target_reached_is_the_window_around_607ah_whatever_the_profile():
    """Bit 10: the error between 607Ah and 6064h inside 6067h for 6068h (L18469): with a
    5000 PUU window the bit is on while the motor is still 4900 PUU from the target."""
    d = mk()
    d.write_object(0x6067, 0, 5000)
    d.write_object(0x6068, 0, 0)
    enable(d, 1)
    d.write_object(0x6081, 0, 100000)
    d.write_object(0x607A, 0, 20000)
    d.write_object(0x6040, 0, 0x1F)
    seen = None
    for _ in range(300):
        d.advance(MS)
        if d.read_object(0x6041, 0) & 0x400:
            seen = 20000 - d.read_object(0x6064, 0)
            break
    assert seen is not None and 4000 < seen < 5000  # at the window, not at the end
