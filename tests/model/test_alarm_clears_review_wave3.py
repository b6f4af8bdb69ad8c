"""How alarms clear, against the A3 alarm chapter, from an outside review (helper-40): each
rule written from its manual line and seen failing on the model before its fix."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.units import MS, S

ABS = {"P2.069": 1, "P2.011": 0x011D, "P2.012": 0x011F}  # absolute; DI2 ABSE, DI3 ABSC


def _drive(**params: int) -> Drive:
    d = Drive(inputs={6: True, 7: True, 8: True}, params=params)
    d.advance(50 * MS)
    assert d.dio.di_function(5) == "ARST"
    return d


def _arst(d: Drive) -> None:
    d.set_di(5, True)  # through the DI filter (P2.009)
    d.advance(10 * MS)
    assert d.dio.function_active("ARST")
    d.set_di(5, False)
    d.advance(10 * MS)


def test_al017_during_running_clears_with_an_alarm_reset():
    """"若運轉中發生，請進行異警重置" (L19582): during running, an alarm reset clears it."""
    d = _drive()
    d.alarms.raise_alarm("AL017")
    _arst(d)
    assert "AL017" not in d.alarms.active


def test_al053_clears_at_servo_off():
    """"將伺服切至 Servo Off 狀態即可解除此異警" (L19725): not by a reset while SON is on."""
    d = _drive()
    d.set_di(1, True)
    d.advance(20 * MS)
    d.alarms.raise_alarm("AL053")
    d.advance(MS)
    _arst(d)
    assert "AL053" in d.alarms.active  # SON still on
    d.set_di(1, False)
    d.advance(20 * MS)
    assert "AL053" not in d.alarms.active
    d.alarms.raise_alarm("AL053")  # raised while Servo On is not asked: no Servo Off clears it
    d.advance(20 * MS)
    assert "AL053" in d.alarms.active


def test_al07d_clears_with_arst_and_al07c_stays_until_a_normal_origin():
    """AL07D: "使用 DI.ARST 清除；此異警清除後，會發生 AL07C" (L19864); AL07C is released by a
    normal clear of the absolute position (L19857). A power cycle with AL07C gives AL07D."""
    d = Drive(inputs={6: True, 7: True, 8: True}, params=ABS)
    d.params.write("P2.008", 271)
    d.params.write("P2.071", 1)
    d.set_di(1, True)
    d.advance(5 * MS)
    d.axis.run_velocity(500, 50, 50)
    d.advance(S)
    d.params.write("P2.071", 1)  # above 200 rpm: AL07C (L19855)
    assert "AL07C" in d.alarms.active
    d.power_cycle()
    assert {"AL07C", "AL07D"} <= set(d.alarms.active)
    _arst(d)
    assert "AL07D" not in d.alarms.active and "AL07C" in d.alarms.active
    d.power_cycle()
    assert "AL07D" in d.alarms.active  # AL07C still not cleared
    _arst(d)
    d.params.write("P2.008", 271)
    d.params.write("P2.071", 1)  # at rest: the normal clear
    d.advance(MS)
    assert not {"AL07C", "AL07D"} & set(d.alarms.active)


def test_service_alarms_survive_a_power_cycle():
    """AL555 "無" (no clearing, L20227), AL503 "contact the distributor" (L20217), AL07F
    "replace the motor" (L19877), AL086 repair (L19893): a power cycle does not repair."""
    for code in ("AL555", "AL503", "AL07F", "AL086"):
        d = _drive()
        d.alarms.raise_alarm(code)
        d.power_cycle()
        _arst(d)
        assert code in d.alarms.active, code


def test_al3f1_is_cleared_by_the_absolute_origin_not_a_power_cycle():
    """AL3F1: "build the absolute origin" (L20175)."""
    d = Drive(inputs={6: True, 7: True, 8: True}, params=ABS)
    d.params.write("P2.008", 271)
    d.params.write("P2.071", 1)
    d.alarms.raise_alarm("AL3F1")
    d.power_cycle()
    assert "AL3F1" in d.alarms.active
    d.params.write("P2.008", 271)
    d.params.write("P2.071", 1)
    assert "AL3F1" not in d.alarms.active


@pytest.mark.parametrize(("param", "line", "alarm"), [("P2.017", 8, "AL013"),
                                                        ("P2.015", 6, "AL014")])
def test_an_unmapped_emgs_or_limit_alarm_clears_with_an_alarm_reset(param, line, alarm):
    # L2979-2981: P2.015-P2.017 set to 0 cancels NL/PL/EMGS; "if the drive then shows an
    # abnormal signal (the factory defaults include NL, PL and EMGS), restart the power or
    # close DI5 (alarm reset) to clear it"
    from hil.model.drive import Drive
    from hil.units import MS

    inputs = {6: True, 7: True, 8: True}
    inputs[line] = False  # that switch open at power-up: its alarm
    d = Drive(inputs=inputs, sensors={})  # the switches are the test's, not the mechanics'
    d.advance(10 * MS)
    assert alarm in d.alarms.active
    d.params.write(param, 0)
    d.set_di(5, True)  # ARST
    d.advance(10 * MS)
    assert alarm not in d.alarms.active
