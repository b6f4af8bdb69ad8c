"""DI functions of table 8.1 the virtual drive does not model are refused when mapped.

Issue 13 item 6: a mapped function that silently does nothing is refused with a clear error
naming the function and why: by the P2.010-P2.017 / P2.036-P2.040 write (SDO abort
0609 0030, Modbus exception 03) and by `hil run --check` (tests/plan/test_malformed.py).
Refused (table 8.1, L15075-15255): CMDINV L15094, CTRY L15104, VPL L15107, VPRS L15113,
FEC L15117, S-P L15172, S-T L15176, T-P L15180, ALGN L15203, CAM L15206. Modelled, so
accepted (tests/model/test_di_functions.py, tests/model/test_pulse_train.py): GAINUP L15085,
CCLR L15088, ZCLAMP L15091, TRQLM L15101, SPDLM L15121, PT-PR L15200, JOGU/JOGD
L15209-15212, GNUM0/GNUM1 L15239, INHP L15244, PFQS L15253.
"""

from __future__ import annotations

import pytest

from hil.faces.modbus_slave import ModbusSlave
from hil.model.dio import INERT_DI_FUNCTIONS, inert_mapping
from hil.model.drive import Drive
from hil.model.errors import InertFunction, ObjectError
from hil.profile.dio import DI_PARAMS
from hil.protocol import modbus as mb

CODES = {"CMDINV": 0x06, "CTRY": 0x0A, "VPL": 0x0C, "VPRS": 0x0D, "FEC": 0x0E, "S-P": 0x18,
         "S-T": 0x19, "T-P": 0x20, "ALGN": 0x35, "CAM": 0x36}  # table 8.1 (L15075-15255)
MODELLED = {"GAINUP": 0x03, "CCLR": 0x04, "ZCLAMP": 0x05, "TRQLM": 0x09, "SPDLM": 0x10,
            "PT-PR": 0x2B, "JOGU": 0x37, "JOGD": 0x38, "GNUM0": 0x43, "GNUM1": 0x44,
            "INHP": 0x45, "PFQS": 0x47}  # issue 13 item 6, issue 26


def test_the_refused_set_is_the_unmodelled_list() -> None:
    assert set(INERT_DI_FUNCTIONS) == set(CODES)
    assert not set(INERT_DI_FUNCTIONS) & set(MODELLED)


@pytest.mark.parametrize("symbol", sorted(MODELLED))
def test_modelled_functions_map_over_sdo(symbol: str) -> None:
    drive = Drive(inputs={8: True})
    drive.write_object(0x220E, 0, 0x0100 | MODELLED[symbol])  # P2.014 (DI5)
    assert drive.params.read("P2.014") == 0x0100 | MODELLED[symbol]
    drive.power_cycle()  # the mapping acts after a power cycle (L9256)
    assert drive.dio.di_function(5) == symbol


@pytest.mark.parametrize("symbol", sorted(CODES))
def test_mapping_write_is_refused_naming_the_function(symbol: str) -> None:
    drive = Drive(inputs={8: True})
    before = drive.params.read("P2.014")
    with pytest.raises(InertFunction, match=rf"P2\.014: DI function {symbol} \(0x"):
        drive.params.write("P2.014", 0x0100 | CODES[symbol])
    assert drive.params.read("P2.014") == before  # nothing lost, nothing changed


@pytest.mark.parametrize("param", DI_PARAMS)
def test_every_di_mapping_parameter_refuses(param: str) -> None:
    assert inert_mapping(param, 0x0136)  # CAM
    assert inert_mapping(param, 0x0137) is None  # JOGU is modelled
    assert inert_mapping("P2.018", 0x0106) is None  # DO3 TQL: a DO, not CMDINV


def test_sdo_write_aborts_0609_0030() -> None:
    drive = Drive(inputs={8: True})
    with pytest.raises(ObjectError) as info:
        drive.write_object(0x220E, 0, 0x0136)  # P2.014 (DI5) = CAM (L18156: 2aBCh)
    assert info.value.abort_code == 0x06090030
    assert "CAM" in str(info.value)


def test_modbus_write_answers_exception_03() -> None:
    drive = Drive(inputs={8: True})
    out: list[bytes] = []
    slave = ModbusSlave(drive.params, send=out.append, station=1)
    address = drive.params.spec("P2.014").modbus_address  # 021CH
    slave.feed(mb.rtu_encode(1, mb.write_single_request(address, 0x0135)), 0)  # ALGN
    slave.tick(100_000_000)
    assert out == [mb.rtu_encode(1, mb.exception_response(0x06, mb.ILLEGAL_DATA_VALUE))]


def test_factory_default_cclr_is_modelled() -> None:
    """P2.011 factory value 0x0104 (CCLR, L1860-1880): the function acts (L15088)."""
    drive = Drive(inputs={8: True})
    assert drive.dio.di_function(2) == "CCLR"
    assert inert_mapping("P2.011", 0x0104) is None


@pytest.mark.parametrize(("param", "value"), [("P2.014", 0x0118), ("P2.014", 0x0106),
                                              ("P2.018", 0x0010)])
def test_a_drive_built_with_an_inert_mapping_is_refused(param, value) -> None:
    """`Drive(params=...)` wrote the values before DI/DO registered its check, so S-P,
    CMDINV or a b-contact OLW (which then conducted for ever) went through (an outside
    review, helper-67); a parameter write of the same values is refused."""
    with pytest.raises(InertFunction):
        Drive(inputs={8: True}, params={param: value})


def test_forced_do_mode_drives_the_outputs_from_p4006() -> None:
    """L2769, L9226-9227: P2.008 = 406 enters forced DO mode, P4.006 = 2 forces DO2 on
    alone, 5 DO1 and DO3; 400 (or a power cycle) goes back to the functions. Both writes had
    been accepted and done nothing (helper-67)."""
    from hil.units import MS

    d = Drive(inputs={8: True})
    d.advance(5 * MS)
    normal = d.dio.do_levels()
    d.params.write("P2.008", 406)
    d.params.write("P4.006", 2)
    assert d.dio.do_levels() == [False, True, False, False, False, False]
    d.params.write("P4.006", 5)
    assert d.dio.do_levels() == [True, False, True, False, False, False]
    assert d.params.read("P4.009") == 5
    d.params.write("P2.008", 400)
    assert d.dio.do_levels() == normal
    d.params.write("P2.008", 406)
    d.power_cycle(off_for=100 * MS)
    d.advance(10 * MS)
    assert not d.dio.forced_do_mode  # not kept at power-off (L2769)
