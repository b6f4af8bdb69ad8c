"""The S/Sz speed and T/Tz torque modes by their internal commands (A3 §6.3.1 L3709-3721,
DI.SPD0/SPD1 L15151-15157, DI.TCM0/TCM1 L15162-15168, P1.034/P1.035 L8334-8350), on the
injected clock. They had been accepted (P1.001 = 2-5) and run nothing (an outside review,
helper-67, wave 3 session 17)."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS
from tests.model.test_capture import pv

# DI1 SON, DI3 SPD0 / TCM0, DI4 SPD1 / TCM1 (a-contacts), DI8 EMGS closed
SPEED = {"P2.012": 0x0114, "P2.013": 0x0115}
TORQUE = {"P2.012": 0x0116, "P2.013": 0x0117}


def make(mode: int, options: ModelOptions | None = None, **params: int) -> Drive:
    table = TORQUE if mode in (3, 5) else SPEED
    d = Drive(options=options, inputs={8: True, 6: True, 7: True},
              params={"P1.001": mode, **table, **params})
    d.set_di(1, True)
    d.advance(10 * MS)
    assert d.servo_on
    return d


@pytest.mark.parametrize("mode", [2, 4])
def test_spd0_spd1_select_the_internal_speed_at_once(mode: int) -> None:
    """L3709-3721: SPD1 SPD0 = 01 P1.009, 10 P1.010, 11 P1.011 (0.1 rpm), effective at once
    without CTRG; 00 in Sz is 0 rpm."""
    d = make(mode, **{"P1.009": 10000, "P1.010": -5000, "P1.011": 20000})
    d.advance(300 * MS)
    if mode == 4:
        assert d.axis.velocity_rpm == 0.0  # Sz, 00: no command
    for di3, di4, rpm in ((True, False, 1000.0), (False, True, -500.0), (True, True, 2000.0),
                          (False, False, 0.0)):
        d.set_di(3, di3)
        d.set_di(4, di4)
        d.advance(1000 * MS)
        assert d.axis.velocity_rpm == pytest.approx(rpm, abs=0.5), (di3, di4)


def test_p1034_is_the_time_from_zero_to_the_rated_speed() -> None:
    """P1.034 = 300 ms from 0 to the rated 3000 rpm (L8334-8340): 1500 rpm after 150 ms;
    P1.035 = 600 ms back down: 750 rpm 150 ms after the command went to 0."""
    d = make(4, **{"P1.009": 30000, "P1.034": 300, "P1.035": 600})
    d.set_di(3, True)
    d.advance(150 * MS)
    assert d.axis.velocity_rpm == pytest.approx(1500.0, abs=30.0)
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == pytest.approx(3000.0, abs=0.5)
    d.set_di(3, False)
    d.advance(2 * MS + 300 * MS)  # the P2.009 filter, then half the way down
    assert d.axis.velocity_rpm == pytest.approx(1500.0, abs=60.0)


def test_s_mode_takes_the_analog_v_ref_when_no_register_is_selected() -> None:
    """S, SPD0 = SPD1 = 0: V_REF x P1.040 / 10 V (L3712): 5 V -> 1500 rpm at P1.040 = 3000."""
    d = make(2, ModelOptions(analog_v_ref=5.0), **{"P1.040": 3000})
    d.advance(1000 * MS)
    assert d.axis.velocity_rpm == pytest.approx(1500.0, abs=0.5)


def test_no_speed_command_runs_towards_an_active_limit() -> None:
    """PL/NL forbid running towards them in every mode (L15188-15191)."""
    d = make(4, **{"P1.009": 10000, "P1.010": -10000})
    d.set_di(7, False)  # PL (b-contact) active
    d.advance(10 * MS)
    d.set_di(3, True)
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == 0.0
    d.set_di(3, False)
    d.set_di(4, True)  # away from PL: runs
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == pytest.approx(-1000.0, abs=0.5)


@pytest.mark.parametrize("mode", [3, 5])
def test_tcm0_tcm1_select_the_internal_torque(mode: int) -> None:
    """L15162-15168: TCM1 TCM0 = 01 P1.012 % of the rated torque; Tz with 00 gives none."""
    d = make(mode, **{"P1.012": 50})
    d.advance(50 * MS)
    if mode == 5:
        assert d.snapshot()["torque_pct"] == 0.0
    d.set_di(3, True)
    d.advance(4 * MS)
    assert d.snapshot()["torque_pct"] == pytest.approx(50.0, abs=0.5)
    assert d.axis.velocity_rpm > 0.0  # an unloaded motor accelerates


def test_the_command_comes_back_after_a_servo_off_and_on() -> None:
    d = make(4, **{"P1.009": 10000})
    d.set_di(3, True)
    d.advance(500 * MS)
    d.set_di(1, False)
    d.advance(1000 * MS)
    assert not d.servo_on
    d.set_di(1, True)
    d.advance(1000 * MS)
    assert d.axis.velocity_rpm == pytest.approx(1000.0, abs=0.5)


def test_a_cia402_velocity_mode_keeps_its_own_target() -> None:
    """In CANopen mode a PV mode is "S" for the DI table (6061h decides), but it runs on
    60FFh: a refresh of the DI functions (a P1.034 write here) must not replace its target
    with the SPD0/SPD1 command (0 rpm)."""
    d = Drive(inputs={8: True, 6: True, 7: True}, params={"P1.001": 0x0C})
    pv(d, 600.0)  # CiA 402 profile velocity, 60FFh = 600 rpm
    assert d.control_mode() == "S"
    d.params.write("P1.034", 100)
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == pytest.approx(600.0, abs=0.5)
