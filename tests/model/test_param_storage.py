"""Where a written parameter is kept, written afresh from the A3 manual (session 28,
helper-106): P2.008 = 10 resets the parameters (L9222) but not P4.011-P4.021 (L10947-11039);
P2.030 = 5 keeps no value written after it (L9495); a parameter an RPDO writes goes to EEPROM
only with P3.011.X = 1 (L10764-10768, L10697). Injected clock."""

from __future__ import annotations

import struct

import pytest

from hil.model.drive import Drive
from hil.units import MS
from tests.faces.test_manual_rules_s16 import NODE, Rig  # the CANopen face's rig


def test_p2008_10_resets_the_parameters_but_not_the_calibration():
    """"10 參數重置(重置後請重新上電)" (L9222); P4.011-P4.021 "本參數無法重置" (L10947)."""
    d = Drive(inputs={8: True})
    d.params.write("P5.020", 300)  # default 200
    d.params.write("P1.042", 100)  # default 0
    d.params.write("P3.000", 5)  # ● node / station number, default 0x7F
    d.params.write("P2.008", 22)  # the key for P4.011-P4.021 (L16045)
    d.params.write("P4.011", 7)
    d.power_cycle()
    assert d.params.get("P3.000") == 5
    d.params.write("P2.008", 10)
    assert d.params.read("P5.020") == 200 and d.params.read("P1.042") == 0
    # "重置後請重新上電": in effect at the power cycle; the drive runs on what it has
    assert d.params.get("P3.000") == 5 and d.params.get("P5.020") == 300
    d.power_cycle()
    assert d.params.get("P3.000") == 0x7F and d.params.read("P2.008") == 0
    assert d.params.get("P5.020") == 200 and d.params.get("P1.042") == 0
    assert d.params.read("P4.011") == 7


def test_p2008_10_changes_nothing_in_effect_under_a_running_servo():
    """A reset under Servo On touched ▲ parameters (the e-gear) and left derived state
    stale (forced DO, 6080h, a forced servo on; helper-108): nothing takes effect before the
    power cycle."""
    d = Drive(inputs={8: True})
    d.params.write("P1.044", 1000000)
    d.params.write("P1.045", 1000000)
    d.params.write("P1.055", 1000)
    d.params.write("P2.030", 1)  # forced software servo on (L9496)
    d.advance(20 * MS)
    assert d.servo_on
    d.params.write("P2.008", 10)
    d.advance(20 * MS)
    assert d.servo_on and d.params.get("P1.044") == 1000000
    assert d.read_object(0x6080, 0) == d.params.get("P1.055") == 1000
    d.power_cycle()
    assert d.params.get("P1.044") == 16777216 and d.params.get("P1.055") == 3000


def test_p2030_5_keeps_no_value_written_after_it(tmp_path):
    """"5 設定後，各參數之設定值於斷電後不保持" (L9495), by any path (a parameter write, a
    Modbus write, a CiA 402 object that is a parameter); "-5" ends it (L9502), and so does
    the power (P2.030 reads 0 after power-up, L9505)."""
    path = tmp_path / "params.json"
    d = Drive(inputs={8: True}, state_path=path)
    d.params.write("P1.042", 100)
    d.params.write("P2.030", 5)
    d.params.write("P1.042", 200)
    d.params.write("P2.030", 8)  # 8 backs RAM up (L9501) ...
    d.params.write("P1.043", 50)  # ... but function 5 stays on until -5
    d.params.modbus_write(d.params.table.spec("P5.020").modbus_address, [300, 0])
    d.write_object(0x6080, 0, 2000)  # = P1.055 (L18713-18735)
    assert d.params.read("P1.043") == 50 and d.params.read("P5.020") == 300
    assert d.params.read("P1.055") == 2000
    restart = Drive(inputs={8: True}, state_path=path)  # what EEPROM holds
    assert restart.params.read("P1.043") == 0 and restart.params.read("P5.020") == 200
    d.power_cycle()
    assert d.params.read("P1.043") == 0 and d.params.read("P2.030") == 0
    assert d.params.read("P5.020") == 200 and d.params.read("P1.055") == 3000
    assert d.params.read("P1.042") == 200  # backed up by the 8
    d.params.write("P1.043", 30)
    d.power_cycle()
    assert d.params.read("P1.043") == 30  # function 5 ended with the power


def test_p2030_5_then_minus_5_stores_again():
    d = Drive(inputs={8: True})
    d.params.write("P2.030", 5)
    d.params.write("P1.042", 200)
    d.params.write("P2.030", -5)
    d.params.write("P1.043", 40)
    d.power_cycle()
    assert d.params.read("P1.042") == 0 and d.params.read("P1.043") == 40


@pytest.mark.parametrize(("p3011", "kept"), [(0x0000, 100), (0x0001, 555)])
def test_an_rpdo_parameter_write_is_kept_only_with_p3011_x_1(p3011: int, kept: int):
    """"X：1 為使用 ... 封包(PDO)寫入參數時會將參數存入 EEPROM；0 則不會" (L10697); an SDO
    write is stored (L10764)."""
    r = Rig()
    try:
        d = r.drive
        d.params.write("P3.011", p3011)
        r.write(0x212A, 0, 100, 2)  # P1.042 by SDO: to EEPROM
        r.map_pdo(0x1400, [0x212A0010], 255)  # RPDO1 = 212Ah (P1.042), event driven
        r.run(10)
        r.feed(0x200 + NODE, struct.pack("<H", 555))
        r.run(10)
        assert d.params.read("P1.042") == 555
        d.power_cycle()
        r.run(50)
        assert d.params.read("P1.042") == kept
    finally:
        r.close()


def test_an_sdo_write_of_a_cia402_object_that_is_a_parameter_is_kept(tmp_path):
    """6080h "is P1.055" (L18713-18735), 6093h = P1.044/P1.045 (L18838-18854): an SDO write
    stores the parameter (L10764) in the parameter file too (helper-110: a restart from the
    file had lost them)."""
    path = tmp_path / "state"
    d = Drive(inputs={8: True}, state_path=path)
    d.write_object(0x6080, 0, 2000)
    # (a ratio PT mode takes: 6093h is written as P1.044 is, its checks included)
    d.write_object(0x6093, 1, 1_000_000)
    again = Drive(inputs={8: True}, state_path=path)
    assert again.params.read("P1.055") == 2000 and again.params.read("P1.044") == 1_000_000
