"""DO functions and a level DI at power-up, written from table 8.2 and chapter 8 (an outside
review found these departures)."""

from __future__ import annotations

import pytest

from hil.model.dio import INERT_DO_FUNCTIONS
from hil.model.drive import Drive
from hil.model.errors import InertFunction, ObjectError
from hil.units import MS


def mk(**p: int) -> Drive:
    return Drive(inputs={8: True}, params=p)


def enable(d: Drive, mode: int) -> None:
    d.write_object(0x6060, 0, mode)
    for cw in (6, 7, 15):
        d.write_object(0x6040, 0, cw)
    d.advance(MS)


def pv(d: Drive, rpm: float) -> None:
    for i in (0x6083, 0x6084):
        d.write_object(i, 0, 100)
    d.write_object(0x60FF, 0, round(rpm * 10))


@pytest.mark.parametrize("rpm", [500, -500])
def test_tspd_in_either_direction(rpm):
    """TSPD: "when the motor's forward or reverse speed is above P1.039" (L8426, L15272)."""
    d = mk(**{"P1.001": 0x0C, "P1.039": 200})
    enable(d, 3)
    pv(d, rpm)
    d.advance(1000 * MS)
    assert abs(d.axis.velocity_rpm) == pytest.approx(500, abs=1)
    assert d.dio.do_function_state("TSPD")
    assert d.params.get("P0.046") & 0x08  # P0.046 bit 3 follows TSPD (L7460-7475)


def test_tpos_is_off_outside_pt_and_pr():
    """TPOS is a PT / PR output (L15275): in speed mode (CiA 402 PV) it stays off."""
    d = mk(**{"P1.001": 0x0C})
    enable(d, 3)
    pv(d, 300)
    d.advance(1000 * MS)
    assert not d.dio.do_function_state("TPOS")


def test_tpos_in_pp_is_the_target_minus_the_motor_position():
    """In PR, TPOS compares the target with the motor position against P1.054 (L8694); the
    drive runs CiA 402 PP as PR: far from the target, TPOS is off however small the
    following error; at the target it is on."""
    d = mk(**{"P1.001": 0x0C})
    enable(d, 1)
    for i, v in ((0x6081, 500000), (0x6083, 100), (0x6084, 100), (0x607A, 10000000)):
        d.write_object(i, 0, v)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(MS)
    d.write_object(0x6040, 0, 0x0F)
    d.advance(500 * MS)
    assert abs(d.axis.target - d.axis.position) > 1e6
    assert not d.dio.do_function_state("TPOS")
    d.write_object(0x607A, 0, 0)
    d.write_object(0x6040, 0, 0x3F)  # change set immediately, back to 0
    d.advance(MS)
    d.write_object(0x6040, 0, 0x0F)
    d.advance(30_000 * MS)
    assert d.read_object(0x6064, 0) == 0 and d.dio.do_function_state("TPOS")


@pytest.mark.parametrize("alarm", ["AL003", "AL022"])
def test_srdy_is_off_without_main_circuit_power(alarm):
    """SRDY: control *and main-circuit* power in, and no fault (L15263). AL003
    (undervoltage, L19509) and AL022 (main circuit lost, L19604) say it is not in."""
    d = mk()
    d.advance(5 * MS)
    assert d.dio.do_function_state("SRDY")
    d.alarms.raise_alarm(alarm)
    d.advance(MS)
    assert not d.dio.do_function_state("SRDY") and not d.params.get("P0.046") & 0x01


@pytest.mark.parametrize("symbol,code", [("OLW", 0x10), ("SP_OK", 0x19), ("CAM_AREA1", 0x18),
                                         ("CAM_AREA2", 0x1A), ("Zon1", 0x2C), ("Zon4", 0x2F)])
def test_a_do_function_nothing_drives_is_refused_when_mapped(symbol, code):
    """Mapped, a DO function the virtual drive never drives would sit at its idle level (a
    b-contact one conducting): the mapping is refused, as an unmodelled DI function's is,
    over SDO with 0609 0030 (table 8.2, L15304-L15347)."""
    assert symbol in INERT_DO_FUNCTIONS
    d = mk()
    with pytest.raises(InertFunction):
        d.params.write("P2.019", 0x0100 | code)  # DO2
    with pytest.raises(ObjectError) as e:
        d.write_object(0x2213, 0, code)  # P2.019 (2213h)
    assert e.value.abort_code == 0x06090030
    assert d.params.read("P2.019") != 0x0100 | code


def test_a_level_cclr_held_from_power_up_holds_the_axis():
    """P2.050 = 1: CCLR is level-triggered (L9753) and, like every level function, acts from
    power-up: a PP move commanded while it is held does not run (DI5 = CCLR)."""
    d = Drive(inputs={8: True, 5: True}, params={"P2.014": 0x0104, "P2.050": 1})
    d.advance(5 * MS)
    enable(d, 1)
    for i, v in ((0x6081, 500000), (0x6083, 100), (0x6084, 100), (0x607A, 1000000)):
        d.write_object(i, 0, v)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == 0 and abs(d.read_object(0x6064, 0)) < 10
