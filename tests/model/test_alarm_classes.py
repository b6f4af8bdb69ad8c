"""Alarm classes and clears written afresh from the A3 manual (shared/seeds/002_…): P2.066
bit 9 (L9973-9975, AL003's row L19510) and AL401's remedy (L20183-20187). Injected clock."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.units import MS


def _undervoltage(p2066: int) -> Drive:
    """Servo on by DI1 SON, DO6 mapped to WARN (a-contact), then the main circuit drops."""
    d = Drive(inputs={8: True}, params={"P2.066": p2066, "P2.041": 0x0111})
    d.set_di(1, True)
    d.advance(10 * MS)
    d.alarms.set_cause("AL003", True)
    d.advance(MS)
    return d


@pytest.mark.parametrize("p2066", [0x0000, 0x0020])
def test_al003_is_a_warning_while_p2066_bit9_is_0(p2066: int) -> None:
    """"Bit 9 設為 0，AL003 為 WARN" (L9975); "此異警預設為警告(Warning)" (L19510)."""
    d = _undervoltage(p2066)
    assert d.dio.do_function_state("WARN") and not d.dio.do_function_state("ALRM")
    assert d.do(5)  # DO5 = ALRM, b-contact (factory P2.022 = 0x0007): conducts without an ALM
    sw = d.cia402.statusword
    assert not sw & 0x08 and sw & 0x80  # no fault; warning bit 7


@pytest.mark.parametrize("p2066", [0x0200, 0x0220])
def test_al003_is_an_alarm_while_p2066_bit9_is_1(p2066: int) -> None:
    """"Bit 9 設為 1，AL003 為 ALM" (L9975); "若使用者欲設為異警(Alarm)，則可透過 P2.066
    [Bit 9]設定" (L19510): ALRM on (DO5, b-contact, opens), WARN off, 6041h FAULT."""
    d = _undervoltage(p2066)
    assert d.dio.do_function_state("ALRM") and not d.dio.do_function_state("WARN")
    assert not d.do(5) and not d.do(6)
    assert d.cia402.statusword & 0x08
    assert not d.servo_on


def test_al401_is_cleared_by_a_later_nmt_reset() -> None:
    """AL401 "Servo On 時收到 NMT Reset 命令" (L20185); remedy "將 NMT 重置或使用 0x6040 重置"
    (L20186), clear "異警重置" (L20187): the NMT reset that raises it does not clear it, the
    next one (servo off now) does."""
    d = Drive(inputs={8: True})
    d.set_di(1, True)
    d.advance(10 * MS)
    d.nmt_reset("reset communication")
    d.advance(MS)
    assert d.alarms.active == ("AL401",) and not d.servo_on
    d.nmt_reset("reset communication")
    d.advance(MS)
    assert "AL401" not in d.alarms.active


@pytest.mark.parametrize("how", ["arst", "p0001", "6040h"])
def test_al401_is_cleared_by_an_alarm_reset(how: str) -> None:
    """L20187 "異警重置": DI.ARST (L15082), P0.001 := 0 (L7079-7083), 6040h (L20186)."""
    d = Drive(inputs={8: True})
    d.set_di(1, True)
    d.advance(10 * MS)
    d.nmt_reset("reset node")
    d.advance(MS)
    assert d.alarms.active == ("AL401",)
    if how == "arst":
        d.set_di(5, True)  # ARST (factory DI5)
    elif how == "p0001":
        d.params.write("P0.001", 0)
    else:
        d.write_object(0x6040, 0, 0)
        d.write_object(0x6040, 0, 0x80)
    d.advance(10 * MS)
    assert d.alarms.active == ()
