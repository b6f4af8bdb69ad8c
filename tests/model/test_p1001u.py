"""P1.001.U, written afresh from the A3 manual (session 28, helpers 104 and 107): "U：DIO 設定值
控制(斷電不保持) ... 1：模式切換時，DIO (P2.010 ~ P2.022) 可重置為相對應各模式之預設值"
(L7811-7813); "請將 P1.001.U 設為 1，重上電後可重置為相對應的各個模式之預設值" (L1887); the
defaults per mode are the tables L1862-1913. Injected clock."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive

DI = ("P2.010", "P2.011", "P2.012", "P2.013", "P2.014", "P2.015", "P2.016", "P2.017")
DO = ("P2.018", "P2.019", "P2.020", "P2.021", "P2.022")


def _after(p1001: int) -> Drive:
    d = Drive(inputs={8: True})
    d.params.write("P1.001", p1001)  # ●: in effect at the power cycle
    d.power_cycle()
    return d


def _functions(d: Drive) -> list[str]:
    return [d.dio.di_function(n) for n in range(1, 9)]


@pytest.mark.parametrize(("mode", "di", "do3"), [
    (0x1002, ["SON", "TRQLM", "SPD0", "SPD1", "ARST", "NL", "PL", "EMGS"], "TSPD"),  # S
    (0x1003, ["SON", "SPDLM", "TCM0", "TCM1", "ARST", "NL", "PL", "EMGS"], "TSPD"),  # T
    (0x1001, ["SON", "CTRG", "POS0", "POS1", "ARST", "NL", "PL", "EMGS"], "HOME"),  # PR
])
def test_u1_loads_the_modes_dio_defaults_at_the_power_up(mode, di, do3):
    d = _after(mode)
    assert _functions(d) == di
    assert d.dio.do_function(3) == do3
    # the limits and EMGS keep the factory b-contact, the others a-contact (L9238-9256)
    assert [d.params.read(p) >> 8 for p in DI] == [1, 1, 1, 1, 1, 0, 0, 0]
    assert d.params.read("P1.001") == mode & 0x0FFF  # U "斷電不保持"


def test_u0_leaves_the_mapping_as_it_is():
    d = Drive(inputs={8: True})
    before = [d.params.read(p) for p in DI + DO]
    d.params.write("P1.001", 0x0002)
    d.power_cycle()
    assert [d.params.read(p) for p in DI + DO] == before


def test_u1_in_canopen_mode_resets_the_dos_only():
    """The DI table has no column for the CANopen mode; its DOs are the "通訊模式" column."""
    d = Drive(inputs={8: True})
    d.params.write("P2.011", 0x0109)  # DI2 TRQLM
    d.params.write("P2.020", 0x0104)  # DO3 TSPD
    d.params.write("P1.001", 0x100C)
    d.power_cycle()
    assert d.dio.di_function(2) == "TRQLM" and d.dio.do_function(3) == "HOME"


def test_u1_given_at_construction_or_left_in_the_file_applies_at_that_power_up(tmp_path):
    """A drive made with P1.001 = 0x1003 (a bench's values) powers up with U = 1 in effect;
    so does one whose parameter file still holds U = 1 (helper-108)."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x1003})
    assert d.dio.di_function(2) == "SPDLM" and d.params.read("P1.001") == 0x0003
    path = tmp_path / "state"
    first = Drive(inputs={8: True}, state_path=path, params={"P1.001": 0x1002})
    assert first.params.read("P1.001") == 0x0002
    again = Drive(inputs={8: True}, state_path=path)  # the file says U = 0 now
    assert again.params.read("P1.001") == 0x0002 and again.dio.di_function(2) == "TRQLM"
