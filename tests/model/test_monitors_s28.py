"""Monitor variables written afresh from table 8.3 (L15440-15483), P0.044/P0.045 (L7442-7458)
and P0.008 (L7129-7145), from an outside probe (session 28, helper-111): most codes read 0
through P0.009-P0.013 although the model had the values. Injected clock."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS, S

PV = 3


def spinning(rpm: int = 1000) -> Drive:
    """CiA 402 PV at `rpm` on a bench without limit switches."""
    mech = Mechanics(nl_rev=-1e9, pl_rev=1e9, hard_stop_neg_rev=None, hard_stop_pos_rev=None)
    d = Drive(inputs={8: True, 6: True, 7: True}, mechanics=mech)
    d.write_object(0x6060, 0, PV)
    d.write_object(0x60FF, 0, rpm * 10)  # 0.1 rpm
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
        d.advance(5 * MS)
    d.advance(1000 * MS)
    return d


def monitor(d: Drive, code: int) -> int:
    d.params.write("P0.017", code)
    return d.params.read("P0.009")


def test_speed_and_torque_codes_follow_the_cia402_objects():
    """007/051 speed feedback and 009/050 speed command in 0.1 rpm, 054/053 torque in 0.1 %,
    011 torque command in % (L15447-15451, L15486-15489); 606Ch and 6077h carry the same."""
    d = spinning(1000)
    assert monitor(d, 7) == monitor(d, 51) == d.read_object(0x606C, 0) == 10000
    assert monitor(d, 9) == monitor(d, 50) == 10000
    assert monitor(d, 54) == d.read_object(0x6077, 0)
    assert monitor(d, 11) == round(monitor(d, 53) / 10)


def test_status_codes_are_the_status_registers():
    """039 = the DI state (P4.007), 040 = the DO outputs (P4.009), 041 = P0.046 (L15477-15479),
    096 = the firmware version (L15509), 123 = what P0.002 shows (L15483)."""
    d = spinning(500)
    assert monitor(d, 39) == d.params.read("P4.007") != 0
    assert monitor(d, 40) == d.params.read("P4.009") != 0
    assert monitor(d, 41) == d.params.read("P0.046") != 0
    assert monitor(d, 96) == d.params.read("P0.000") == 100
    d.params.write("P0.002", 7)
    assert monitor(d, 123) == 5000


def test_the_inertia_ratio_and_the_dc_bus():
    d = spinning(0)
    ratio = d.mech.load_inertia / d.mech.motor_inertia
    assert monitor(d, 15) == round(ratio * 10) != 0  # 0.1 x (L15455)
    assert monitor(d, 14) > 0 and monitor(d, 56) == monitor(d, 14) * 10  # V / 0.1 V


@pytest.mark.parametrize("angle", [0.0, 0.25])
def test_the_offset_from_z_over_a_turn(angle: float):
    """018: "與 Z 相重疊處，其值為 0", -4999 .. +5000 (L15462); the bench's Z is `index_angle`
    past each whole turn (helper-112: it had ignored the angle)."""
    mech = Mechanics(index_angle=angle)
    d = Drive(inputs={8: True}, mechanics=mech)
    d.advance(10 * MS)
    cpr = d.axis.cpr
    for frac, want in ((angle, 0), (angle + 0.1, 1000), (angle - 0.3, -3000)):
        d.axis.position = d.axis.demand = frac * cpr
        assert monitor(d, 18) == want, frac


def test_p0044_reads_the_code_p0045_selects():
    """P0.044 "同參數 P0.009", P0.045 "同參數 P0.017" (L7442-7458): it read 0 whatever P0.045."""
    d = spinning(1000)
    for code in (7, 0, 3):
        d.params.write("P0.045", code)
        d.params.write("P0.017", code)
        assert d.params.read("P0.044") == d.params.read("P0.009")
    d.params.write("P0.045", 7)
    assert d.params.read("P0.044") == 10000


def test_mapped_monitor_codes_read_the_registers_and_never_loop():
    """023-026 return P0.009-P0.012 (L15465-15468): a selection that loops through them or
    through 123 (P0.002) reads 0 instead of recursing (helper-112: RecursionError)."""
    d = spinning(1000)
    d.params.write("P0.018", 7)
    assert monitor(d, 24) == 10000  # P0.010 = speed
    assert monitor(d, 23) == 0  # P0.009 mapped on 23: itself
    d.params.write("P0.002", 23)
    assert monitor(d, 123) == 0
    d.params.write("P0.045", 123)
    assert d.params.read("P0.044") == 0


@pytest.mark.parametrize("hours", [0.5, 2.2])
def test_p0008_counts_whole_hours_on_and_servo_on(hours: float):
    """High word Servo On hours, low word power-on hours; "未滿 1 小時不會紀錄" (L7139)."""
    d = Drive(inputs={8: True})
    d.advance(int(hours * 3600 * S))  # powered, servo off
    d.set_di(1, True)  # SON
    d.advance(int(hours * 3600 * S))
    whole_on, whole_servo = int(2 * hours), int(hours)
    assert d.params.read("P0.008") == whole_servo << 16 | whole_on


def test_p0008_keeps_counting_across_a_power_cycle():
    d = Drive(inputs={8: True})
    d.advance(int(0.6 * 3600 * S))
    d.power_cycle(off_for=int(5 * 3600 * S))  # off: nothing counts
    d.advance(int(0.6 * 3600 * S))
    assert d.params.read("P0.008") == 0x0001


def test_a_pr_write_reads_any_monitor_the_drive_has():
    """A WRITE PR's monitor source (L4178-4183) is read as P0.009 reads it: 054 had raised
    AL231 (helper-112)."""
    from tests.model.test_pr import make, put

    d = make()
    put(d, 1, type_="write", data=54, source="monitor", dest="P5.055")
    d.params.write("P5.007", 1)
    d.advance(50 * MS)
    assert d.alarms.active == ()


def test_mapping_parameters_read_and_write_their_targets():
    """P0.035 = 0x02030205 maps P0.025 on P2.003 (high word) and P2.005 (low): writing
    0x00050064 sets P2.003 = 5 and P2.005 = 100; the same word twice is one 32-bit parameter
    (P6.010, 0x060A060A) (L7326-7372). Monitors 019-022 read P0.025-P0.028 (L15463-15466);
    they had read 0 (helpers 111, 114)."""
    d = Drive(inputs={8: True})
    d.params.write("P0.035", 0x02030205)
    d.params.write("P0.025", 0x00050064)
    assert d.params.read("P2.003") == 5 and d.params.read("P2.005") == 100
    d.params.write("P2.005", 120)
    assert d.params.read("P0.025") == 0x00050078
    d.params.write("P0.036", 0x060A060A)
    d.params.write("P0.026", 0x00050064)
    assert d.params.read("P6.010") == 0x00050064
    d.params.write("P0.037", 0x01090109)  # P1.009, 32-bit
    d.params.write("P1.009", 12345)
    assert monitor(d, 21) == 12345 and monitor(d, 19) == 0x00050078
    with pytest.raises(Exception, match=r"P2\.003"):
        d.params.write("P0.025", 0x7FFF0064)  # P2.003 refuses 32767: the register too
    assert d.params.read("P2.003") == 5


def test_mapping_targets_are_checked_when_they_are_set():
    """A target must be a parameter and not a mapping register: P0.025 on itself (or two on
    each other) had recursed for ever, an unknown target failed every read (helper-116)."""
    from hil.model.errors import ModelError

    d = Drive(inputs={8: True})
    for bad in (0x00190019, 0x001A001A, 0x0FFF0FFF, 0x00220022):  # P0.025, P0.026, P15.255, P0.034
        with pytest.raises(ModelError):
            d.params.write("P0.035", bad)
    assert d.params.read("P0.035") == 0


def test_a_one_word_modbus_write_keeps_the_other_target():
    """A function-06 write of one half of P0.025 combines it with the other half as the
    targets hold it (the stored register had been used: P1.006 was overwritten with 0)."""
    d = Drive(inputs={8: True})
    d.params.write("P0.035", 0x01060107)  # P1.006 high, P1.007 low
    d.params.write("P1.006", 500)
    address = d.params.table.spec("P0.025").modbus_address
    d.params.modbus_write(address, [300])  # the low word alone
    assert d.params.read("P1.006") == 500 and d.params.read("P1.007") == 300


def test_an_unsigned_32_bit_target_writes_back_what_it_reads():
    d = Drive(inputs={8: True})
    d.params.write("P0.035", 0x05030503)  # P5.003, 0 .. 0xFFFFFFFF
    value = d.params.read("P0.025")
    d.params.write("P0.025", value)
    assert d.params.read("P5.003") == value & 0xFFFFFFFF


def test_a_modbus_write_through_a_mapping_moves_the_array_pointer_once():
    """P0.025 on P5.012 (the data array's window): a Modbus write of it is one write of P5.012
    (entry P5.011, then the pointer +1); the mapping's peek had read P5.012 and moved the
    pointer first (helper-117)."""
    d = Drive(inputs={8: True})
    d.params.write("P0.035", 0x050C050C)
    for via in ("P0.025", "P5.012"):
        d.pr.array[0], d.pr.array[1] = 0x00010002, 0x00030004
        d.params.write("P5.011", 0)
        d.params.modbus_write(d.params.table.spec(via).modbus_address, [0x0099, 0x0000])
        assert d.params.get("P5.011") == 1 and d.pr.array[0:2] == [0x99, 0x00030004], via


def test_a_looping_target_given_before_the_check_is_unmapped(tmp_path):
    """A bench's params and a parameter file are written before P0.035's check exists: a
    value that names a mapping register or no parameter is set to 0 at construction."""
    d = Drive(inputs={8: True}, params={"P0.035": 0x00190019})
    assert d.params.read("P0.035") == 0 and d.params.read("P0.025") == 0


def test_writes_through_a_mapping_stay_ram_only_when_the_write_is():
    d = Drive(inputs={8: True})
    d.params.write("P0.035", 0x01060107)  # P1.006, P1.007
    d.params.write("P1.006", 5)
    d.params.write("P0.025", 40 << 16 | 50, ram_only=True)  # a PR WRITE without ROM
    assert (d.params.read("P1.006"), d.params.read("P1.007")) == (40, 50)
    d.power_cycle()
    assert (d.params.read("P1.006"), d.params.read("P1.007")) == (5, 0)
