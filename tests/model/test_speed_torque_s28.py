"""Speed and torque modes written afresh from the A3 manual (session 28, helper-107): PL/NL
in torque mode, the analog command's planning with P1.036 = 0, ZCLAMP with P2.065 bit 10 on
the analog command, TSPD at its threshold. Injected clock; a bench without limit switches
or hard stops (the default bench's travel would trip PL at speed)."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.model.options import ModelOptions
from hil.units import MS

SPEED = {"P2.011": 0x0109, "P2.012": 0x0114, "P2.013": 0x0115}  # DI2 TRQLM, DI3 SPD0, DI4 SPD1
TORQUE = {"P2.011": 0x0110, "P2.012": 0x0116, "P2.013": 0x0117}  # DI2 SPDLM, DI3 TCM0, DI4 TCM1


def make(mode: int, options: ModelOptions | None = None, son: bool = True, **params) -> Drive:
    """P1.001 = mode (2 S, 3 T, 4 Sz), the manual's DI defaults for it (L1862-1913); NL DI6 and
    PL DI7 (b-contact) closed, EMGS DI8 closed."""
    mech = Mechanics(nl_rev=-1e9, pl_rev=1e9, hard_stop_neg_rev=None, hard_stop_pos_rev=None)
    table = TORQUE if mode in (3, 5) else SPEED
    d = Drive(options=options, mechanics=mech, inputs={8: True, 6: True, 7: True},
              params={"P1.001": mode, **table, **params})
    if son:
        d.set_di(1, True)
        d.advance(10 * MS)
    return d


def rpm(d: Drive) -> float:
    return d.axis.velocity_rpm


def test_a_torque_command_does_not_run_towards_an_active_pl():
    """PL (0x23) "正向運轉禁止極限", all modes (L15186-15191): a torque command selected while
    PL is active ran the motor forward to P1.055 (3000 rpm)."""
    d = make(3, **{"P1.012": 20})
    d.set_di(7, False)  # PL (b-contact) open: active
    d.advance(50 * MS)
    d.set_di(3, True)  # TCM0: +20 % (P1.012)
    d.advance(500 * MS)
    assert abs(rpm(d)) < 1
    d.set_di(7, True)  # PL released: the command runs
    d.advance(300 * MS)
    assert rpm(d) > 1000


def test_an_analog_speed_command_has_no_trapezoid_while_p1036_is_0():
    """"若使用類比命令，P1.036 的設定需要大於 0 才能有梯形加減速規劃" (L8342, L8353)."""
    speeds = {}
    for p1036 in (0, 100):
        d = make(2, ModelOptions(analog_v_ref=10.0), son=False,
                 **{"P1.040": 3000, "P1.034": 1000, "P1.035": 1000, "P1.036": p1036})
        d.set_di(1, True)
        d.advance(60 * MS)
        speeds[p1036] = rpm(d)
    assert speeds[0] > 2900  # the speed loop's own lag only
    assert 100 < speeds[100] < 300  # on the 1000 ms / 3000 rpm ramp


def test_register_commands_keep_their_trapezoid_with_p1036_0():
    """"若使用內部命令，即使 P1.036 設為 0，仍有梯形加減速規劃" (L8342)."""
    d = make(4, **{"P1.009": 30000, "P1.034": 1000, "P1.036": 0})
    d.set_di(3, True)
    d.advance(100 * MS)
    assert 200 < rpm(d) < 400


def test_zclamp_bit10_on_the_analog_command_ramps_to_0():
    """P2.065 bit 10 = 1, analog source: "馬達速度經過 S 曲線後降至 0 rpm；當零速箝制不成立後，
    又經由 S 曲線追隨類比速度命令" (L9914-9916); it had stopped at once."""
    d = make(2, ModelOptions(analog_v_ref=0.6), **{
        "P2.014": 0x0105, "P1.038": 2000, "P1.034": 1000, "P1.035": 6000, "P1.036": 100,
        "P2.065": 1 << 10})  # DI5 ZCLAMP; 0.6 V x 3000 rpm / 10 V = 180 rpm < P1.038 200
    d.advance(1000 * MS)
    assert rpm(d) == pytest.approx(180, abs=1)
    d.set_di(5, True)
    d.advance(100 * MS)
    assert rpm(d) == pytest.approx(130, abs=3)  # on P1.035 slope: 3000 rpm in 6 s
    d.advance(2000 * MS)
    assert abs(rpm(d)) < 1
    d.set_di(5, False)
    d.advance(20 * MS)
    assert 10 < rpm(d) < 170  # back up the curve, not at once


def test_zclamp_bit10_on_a_register_command_is_0_at_once():
    """"命令來源為內部暫存器 ... 馬達速度直接設為 0 rpm" (L9918-9920)."""
    d = make(4, **{"P2.014": 0x0105, "P1.009": 1500, "P1.038": 2000, "P2.065": 1 << 10})
    d.set_di(3, True)
    d.advance(1000 * MS)
    assert rpm(d) == pytest.approx(150, abs=1)
    d.set_di(5, True)
    d.advance(20 * MS)
    assert abs(rpm(d)) < 1


@pytest.mark.parametrize("speed", [500, 1000, 2000])
def test_tspd_is_off_at_exactly_p1039(speed: int):
    """TSPD: speed "高於" (above) P1.039 (L8426, L15272); a speed settled on P1.039 read
    1000.0000000000001 rpm and turned it on."""
    d = make(4, **{"P2.020": 0x0104, "P1.039": speed, "P1.009": speed * 10})
    d.set_di(3, True)
    d.advance(1500 * MS)
    assert rpm(d) == pytest.approx(speed)
    assert not d.dio.do_function_state("TSPD")
    d.params.write("P1.039", speed - 1)
    d.advance(5 * MS)
    assert d.dio.do_function_state("TSPD")


def test_writing_p1036_replans_the_analog_command():
    """P1.036 decides whether the analog command has a trapezoid (L8342): a write of it
    mid-ramp takes effect, as a write of P1.034 does (helper-108)."""
    d = make(2, ModelOptions(analog_v_ref=10.0), son=False,
             **{"P1.040": 3000, "P1.034": 1000, "P1.035": 1000, "P1.036": 100})
    d.set_di(1, True)
    d.advance(60 * MS)
    assert rpm(d) < 300
    d.params.write("P1.036", 0)
    d.advance(50 * MS)
    assert rpm(d) > 2900
