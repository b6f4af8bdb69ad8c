"""PR mode PR#1-#99 on the virtual drive (A3 manual chapter 7), on the injected clock.

Bench: DI1 SON, DI2 CTRG, DI3 POS0, DI4 POS1, DI5 STP, DI6 EV1, DI10 ARST; EMGS (DI8, b)
closed; no sensors. Default gear: 100000 PUU per motor rev. P5.064 = 300 rpm.
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ModelError, OutOfRange
from hil.model.options import ModelOptions
from hil.profile.pr import PrError, check_table, decode, encode, pr_params
from hil.units import MS

BENCH = {
    "P1.001": 0x0001,  # PR mode
    "P2.010": 0x0101,  # DI1 SON
    "P2.011": 0x0108,  # DI2 CTRG
    "P2.012": 0x0111,  # DI3 POS0
    "P2.013": 0x0112,  # DI4 POS1
    "P2.014": 0x0146,  # DI5 STP
    "P2.015": 0x0139,  # DI6 EV1
}


def make(pr: dict | None = None, **params: int) -> Drive:
    d = Drive(options=ModelOptions(extra={"pr": pr or {}}), inputs={8: True},
              params=BENCH | {"P2.016": 0, "P2.036": 0} | params, sensors={})
    d.set_di(1, True)
    d.advance(400 * MS)
    assert d.servo_on
    return d


def put(d: Drive, n: int, **kw) -> None:
    p_def, p_data = pr_params(n)
    definition, data = encode(**kw)
    d.params.write(p_def, definition)
    d.params.write(p_data, data)


def puu(d: Drive) -> int:
    return d.snapshot()["position_puu"]


def times(d: Drive, prefix: str) -> list[int]:
    return [t // MS for t, what in d.pr.trace if what.startswith(prefix)]


def run(d: Drive, seconds: float) -> None:
    d.advance(int(seconds * 1000) * MS)


# ---------------------------------------------------------------- decoder
def test_pr_parameters_follow_8_3_numbering() -> None:
    """PR#1 = P6.002/P6.003 (L12666), PR#50 = P7.000 (L13652), PR#99 = P7.098 (L4840)."""
    assert pr_params(1) == ("P6.002", "P6.003")
    assert pr_params(49) == ("P6.098", "P6.099")
    assert pr_params(50) == ("P7.000", "P7.001")
    assert pr_params(99) == ("P7.098", "P7.099")
    with pytest.raises(PrError, match="AL249"):
        pr_params(100)


def test_decode_layout_dcba_uzyx() -> None:
    """Position PR: X TYPE, Y OPT (INS bit0, OVLP bit1, CMD bits 3-2), Z ACC, U DEC, A SPD,
    B DLY (L4478-4501)."""
    p = decode(7, 0x00351E83, 5000)  # B=3 A=5 U=1 Z=E, OPT=8 (INC), AUTO
    assert (p.type, p.cmd, p.ins, p.ovlp) == (3, "INC", False, False)
    assert (p.acc, p.dec, p.spd, p.dly, p.data) == (0xE, 1, 5, 3, 5000)
    assert decode(1, *encode("write", 10, dest="P5.055", ins=True)).dest_param == "P5.055"


def test_check_rejects_what_the_drive_refuses() -> None:
    """Jump > 99 (AL249, L20099), speed beyond ±60000 (L4451), TYPE undefined (L4148-4155),
    statement PRs need ASDA-Soft (L4649)."""
    bad = check_table({
        "P6.002": 0x7, "P6.003": 100,
        "P6.004": 0x1, "P6.005": 60001,
        "P6.006": 0x5,
        "P6.008": 0xB,
        "P6.010": 0x2, "P6.011": 1000,  # fine
    })
    assert len(bad) == 4
    assert "AL249" in bad[0] and "60000" in bad[1] and "TYPE 5" in bad[2] and "ASDA-Soft" in bad[3]


# ---------------------------------------------------------------- triggers
def test_ctrg_with_pos_bits_after_the_p2009_filter() -> None:
    """CTRG rising with POS0+POS1 = PR#3 (L4834-4840); the DI passes the P2.009 filter (2 ms,
    L9229) and the command starts on the next 1 ms tick (L4909)."""
    d = make()
    put(d, 3, type_="single", data=20000, spd=4)
    d.set_di(3, True)
    d.set_di(4, True)
    d.advance(10 * MS + 300_000)  # t = 410.3 ms
    d.set_di(2, True)
    run(d, 0.5)
    assert times(d, "dispatch:3") == [413]  # 410.3 + 2 ms filter -> tick 413
    assert puu(d) == 20000


def test_p5007_readback_and_refusal() -> None:
    """P5.007: write 1..99 runs, reads n / n+10000 / n+20000 (L11185); 100..999 is refused
    (L11176); 1000 stops (L11183)."""
    d = make()
    put(d, 5, type_="single", data=100000, spd=4, dly=2)  # DLY 200 ms
    d.params.write("P5.007", 5)
    d.advance(100 * MS)
    assert d.params.read("P5.007") == 5
    seen = set()
    for _ in range(100):
        d.advance(5 * MS)
        seen.add(d.params.read("P5.007"))
    assert seen >= {5, 20005}
    with pytest.raises(ModelError, match="L11176"):
        d.params.write("P5.007", 150)


def test_event_triggers_p5098_p5099() -> None:
    """P5.098 = 0x05D2: EV1 rising -> PR#52; P5.099 = 0x790A: EV1 falling -> PR#60
    (000:633-638, L12497-12551)."""
    d = make()
    d.params.write("P5.098", 0x05D2)
    d.params.write("P5.099", 0x790A)
    put(d, 52, type_="single", data=1000, spd=4)
    put(d, 60, type_="single", data=-1000, spd=4)
    d.set_di(6, True)
    run(d, 0.2)
    assert puu(d) == 1000
    d.set_di(6, False)
    run(d, 0.2)
    assert puu(d) == -1000
    assert [w for _, w in d.pr.trace if w.startswith("dispatch")] == ["dispatch:52", "dispatch:60"]


def test_same_ms_priority_and_third_dropped() -> None:
    """Same ms: CTRG > P5.007 > Event; the second a ms later, a third dropped (L4916)."""
    d = make()
    for n in (1, 2, 51):
        put(d, n, type_="write", data=n, dest="P5.055", ins=True)
    d.params.write("P5.098", 0x1)
    d.set_di(3, True)  # POS0 -> PR#1
    d.advance(5 * MS)
    d.set_di(2, True)
    d.set_di(6, True)
    d.advance(2 * MS)  # both filtered edges land in the same ms
    d.params.write("P5.007", 2)
    run(d, 0.05)
    order = [w for _, w in d.pr.trace if w.startswith(("dispatch", "dropped"))]
    assert order == ["dropped:51:EV_RISE", "dispatch:1", "dispatch:2"]
    assert times(d, "dispatch:2")[0] == times(d, "dispatch:1")[0] + 1


# ---------------------------------------------------------------- sequencing
def test_sequential_dly_after_position_reached() -> None:
    """Without INS the next PR starts DLY after the command reached its target (L4934-4961)."""
    d = make()
    put(d, 1, type_="auto", data=50000, spd=4, dly=1)  # P5.041 = 100 ms
    put(d, 2, type_="single", data=0, spd=4)
    d.params.write("P5.007", 1)
    run(d, 1.0)
    done, start2 = times(d, "done:1")[0], times(d, "motion:2")[0]
    assert start2 - done == 100
    assert puu(d) == 0


@pytest.mark.parametrize(("dly", "start2"), [(0, 100), (1, 101), (3, 401)])
def test_overlap_starts_at_the_deceleration_dly_from_the_command_start(dly, start2) -> None:
    """OVLP: the next PR starts when PR#1 begins to decelerate (started at 1 ms, 50000 PUU
    at 300 rpm with 20 ms ramps: from 100 ms); a DLY counts from PR#1's command start, so
    DLY #3 (P5.043 = 400 ms) holds PR#2 until 401 ms (L5051)."""
    d = make()
    put(d, 1, type_="auto", data=50000, cmd="INC", spd=4, ovlp=True, dly=dly)
    put(d, 2, type_="single", data=30000, cmd="INC", spd=4)
    t0 = d.now // MS
    d.params.write("P5.007", 1)
    run(d, 1.0)
    assert times(d, "motion:1")[0] - t0 == 1
    assert times(d, "motion:2")[0] - t0 == start2
    assert puu(d) == 80000


def test_internal_interrupt_only_last_motion_of_a_group() -> None:
    """A2 case 2 (000:945, L5022): lead PR#1 then INS jump/write/INC: only PR#11 moves,
    0 -> 300000; P5.055 = 10 then 12 in the same ms."""
    d = make()
    put(d, 1, type_="auto", data=200000, cmd="INC", spd=1)
    put(d, 2, type_="jump", data=10, ins=True)
    put(d, 10, type_="write", data=10, dest="P5.055", ins=True, auto=True)
    put(d, 11, type_="auto", data=300000, cmd="INC", spd=5, ins=True)
    put(d, 12, type_="write", data=12, dest="P5.055", ins=True)
    d.params.write("P5.007", 1)
    run(d, 2.0)
    assert [w for _, w in d.pr.trace if w.startswith("motion")] == ["motion:11"]
    assert puu(d) == 300000
    assert d.params.get("P5.055") == 12


def test_internal_interrupt_after_dly_merges_inc() -> None:
    """A2 case 4 (000:986-997): PR#1 DLY 10 ms runs 10 ms, then INC PR#11 merges: total is
    200000 + 300000 PUU."""
    d = make()
    d.params.write("P5.041", 10)
    put(d, 1, type_="auto", data=200000, cmd="INC", spd=1, dly=1)
    put(d, 2, type_="jump", data=11, ins=True)
    put(d, 11, type_="single", data=300000, cmd="INC", spd=5, ins=True)
    d.params.write("P5.007", 1)
    run(d, 3.0)
    m = times(d, "motion")
    assert m[1] - m[0] == 10
    assert puu(d) == 500000


def test_sequential_jump_waits_for_the_motion() -> None:
    """A2 case 3 (000:969-971): a jump without INS waits for PR#1; P5.055 changes at its end."""
    d = make()
    put(d, 1, type_="auto", data=100000, spd=4)
    put(d, 2, type_="jump", data=10)
    put(d, 10, type_="write", data=77, dest="P5.055", ins=True)
    d.params.write("P5.007", 1)
    run(d, 0.1)
    assert d.params.get("P5.055") != 77
    run(d, 1.0)
    assert d.params.get("P5.055") == 77
    assert times(d, "write:10") == times(d, "done:1")


def test_stp_keeps_remainder_inc0_finishes() -> None:
    """STP stops and keeps the remainder: INC 0 completes the move (000:601-605, L15249)."""
    d = make()
    put(d, 1, type_="single", data=300000, spd=4)
    put(d, 2, type_="single", data=0, cmd="INC", spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.2)
    d.set_di(5, True)
    run(d, 0.3)
    stopped = puu(d)
    assert 0 < stopped < 300000
    assert not d.axis.moving
    d.params.write("P5.007", 2)
    run(d, 1.5)
    assert puu(d) == 300000


def test_speed_pr_ended_by_event() -> None:
    """A speed PR runs until another PR interrupts it (000:540-544); EV1 -> PR#51 stops it."""
    d = make()
    d.params.write("P5.098", 0x1)
    put(d, 1, type_="speed", data=1000)  # 100.0 rpm
    put(d, 51, type_="speed", data=0, ins=True)
    d.params.write("P5.007", 1)
    run(d, 0.5)
    assert abs(d.axis.velocity_rpm - 100.0) < 0.5
    d.set_di(6, True)
    run(d, 0.5)
    assert d.axis.velocity_rpm == 0.0


# ---------------------------------------------------------------- completion
def test_cmd_ok_then_tpos_then_mc_ok_with_dly() -> None:
    """Cmd_OK = command done + DLY (L15319); MC_OK = Cmd_OK and TPOS (L4201, L8624-8630)."""
    d = make()
    put(d, 1, type_="single", data=50000, spd=4, dly=2)  # 200 ms
    d.params.write("P5.007", 1)
    run(d, 1.0)
    done = times(d, "done:1")[0]
    assert times(d, "Cmd_OK:1") == [done + 200]
    assert times(d, "MC_OK:1") == [done + 200]
    assert d.pr.mc_ok and d.dio.do_function_state("MC_OK")


def test_al380_when_displaced_after_mc_ok() -> None:
    """P1.048.Y = 1: TPOS off after MC_OK -> AL380 (L8632, L20147); X = 1 holds MC_OK."""
    d = make()
    d.params.write("P1.048", 0x11)
    put(d, 1, type_="single", data=10000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.5)
    assert d.pr.mc_ok
    d.axis.position += 20_000_000  # pushed away by hand
    d.axis.moving = True
    d.advance(2 * MS)
    assert "AL380" in d.alarms.active
    assert d.pr.mc_ok  # held


# ---------------------------------------------------------------- limits and alarms
def test_software_limit_on_command_and_auto_clear() -> None:
    """AL283 when the command passes P5.008 (L20105-20109), stop with P5.003.Z, cleared
    automatically once the command is back inside."""
    d = make()
    d.params.write("P5.008", 50000)
    put(d, 1, type_="single", data=200000, spd=4)
    put(d, 2, type_="single", data=0, spd=4)
    d.params.write("P5.007", 1)
    run(d, 1.0)
    assert "AL283" in d.alarms.active and d.dio.do_function_state("SPL")
    assert 50000 < puu(d) < 200000
    d.params.write("P5.007", 2)
    run(d, 1.0)
    assert "AL283" not in d.alarms.active and puu(d) == 0


def test_jump_beyond_99_raises_al249() -> None:
    """A jump to a PR number > 99 raises AL249 (L4527, L20099); POS6 selects PR#64+ (L15133)."""
    d = make()
    d.params.write("P6.002", 0x7)
    d.params.write("P6.003", 120)
    d.params.write("P5.007", 1)
    run(d, 0.1)
    assert "AL249" in d.alarms.active


def test_pos6_selects_high_paths() -> None:
    """POS6 (0x1E) is bit 6 of the path number: POS6+POS1+POS0 = PR#67 (L4834-4840)."""
    d = make(**{"P2.016": 0x011E})  # DI7 POS6
    put(d, 67, type_="single", data=1000, spd=4)
    for n in (3, 4, 7):
        d.set_di(n, True)
    d.advance(5 * MS)
    d.set_di(2, True)
    run(d, 0.3)
    assert times(d, "dispatch:67") and puu(d) == 1000


def test_index_before_homing_al237() -> None:
    """An index PR without a defined index coordinate -> AL237 (L4593, L20093)."""
    d = make()
    put(d, 1, type_="index", data=1000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.1)
    assert "AL237" in d.alarms.active


def test_homing_then_path() -> None:
    """PR#0 X=8 (current position = origin) then PATH = PR#1 ABS P6.001 (L12607-12653)."""
    d = make()
    d.params.write("P5.004", 0x8)
    d.params.write("P6.001", 5000)
    d.params.write("P6.000", 0x01)
    put(d, 1, type_="single", data=0, spd=4)
    d.params.write("P5.007", 0)
    run(d, 0.5)
    assert d.homing.homed
    assert puu(d) == 0 and times(d, "motion:1")
    assert d.pr.cmd_e == 0


def test_write_pr_changes_speed_of_following_moves() -> None:
    """A write PR into the speed table changes every PR using it (000:403, 000:4007)."""
    d = make()
    put(d, 1, type_="write", data=600, dest="P5.064", auto=True)
    put(d, 2, type_="single", data=10000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.5)
    assert d.params.get("P5.064") == 600 and puu(d) == 10000


@pytest.mark.parametrize(("fields", "alarm"), [
    ({"source": "array", "data": 5000, "dest": "P5.064"}, "AL209"),
    ({"source": "array", "data": -1, "dest": "P5.064"}, "AL209"),
    ({"source": "constant", "data": 7, "dest": 4095, "dest_array": True}, "AL213"),
])
def test_write_pr_with_an_array_index_outside_the_array_raises_its_alarm(fields, alarm) -> None:
    """The data array has 800 entries (L5097). A write PR whose source index lies outside is
    a source number out of range (AL209, L20049-20052); a destination index outside is a
    parameter setting error (AL213, L20054-20057) (choice: docs/manual-choices.md). Before,
    the program ended with no alarm, and -1 would have read the last entry."""
    d = make()
    put(d, 1, type_="write", **fields)
    d.params.write("P5.007", 1)
    run(d, 0.2)
    assert alarm in d.alarms.active
    assert d.params.get("P5.064") != 7


def test_data_array_modbus_example() -> None:
    """L5124-5136: 0x10 at P5.011 {11, 100, 200}, {13, 300}; 0x06 P5.011 = 11; 0x03 reads
    11, 100, 200 then 13, 300, 0 (auto-increment)."""
    d = make()
    base = d.params.spec("P5.011").modbus_address
    d.params.modbus_write(base, [11, 0, 100, 0, 200, 0])
    d.params.modbus_write(base, [13, 0, 300, 0])
    assert d.pr.array[11:14] == [100, 200, 300]
    d.params.modbus_write(base, [11])
    assert d.params.modbus_read(base, 6) == [11, 0, 100, 0, 200, 0]
    assert d.params.modbus_read(base, 6) == [13, 0, 300, 0, 0, 0]


def test_data_array_refused_read_does_not_advance_p5011() -> None:
    """A 03h read over P5.012, P5.013 and the undefined 051CH (P5.014) is refused as a whole
    (exception 02h): the windows' auto-increment (L5108-5114) must not run for it, or the
    master's next read skips two array entries it never got."""
    d = make()
    d.pr.array[11:13] = [100, 200]
    base = d.params.spec("P5.011").modbus_address
    d.params.modbus_write(base, [11])
    with pytest.raises(ModelError):  # UnknownParameter: exception 02h at the face
        d.params.modbus_read(base + 2, 6)  # 0518H-051DH
    assert d.params.stored("P5.011") == 11
    assert d.params.modbus_read(base, 6) == [11, 0, 100, 0, 200, 0]


def test_data_array_one_word_write_keeps_the_entry_other_half() -> None:
    """06h writes only the low word of the 32-bit window P5.012 (L5124 lists 06h among the
    data-array commands). Its high half is that of the array entry written (docs/manual-
    choices.md#parameters), not the stale half of the previous entry: after -1 at #5, 7 at #6
    is 7, not 0xFFFF0007. The same for P5.100-P5.103 (address + k, L5138-5147)."""
    d = make()
    d.pr.array[6] = 0x00020000
    base = d.params.spec("P5.011").modbus_address
    d.params.modbus_write(base, [5])
    d.params.modbus_write(base + 2, [0xFFFF, 0xFFFF])  # #5 = -1, P5.011 -> 6
    d.params.modbus_write(base + 2, [7])  # low word of #6
    assert d.pr.array[5:7] == [-1, 0x00020007]
    assert d.params.stored("P5.011") == 7
    d.params.modbus_write(base, [5])
    p5100 = d.params.spec("P5.100").modbus_address
    d.params.modbus_write(p5100 + 2, [9])  # P5.101: #6, low word only
    assert d.pr.array[5:7] == [-1, 0x00020009]


def test_a_position_pr_after_the_counter_overflowed_gives_al235() -> None:
    """The PUU counters are 32-bit: a command that carries them past 2^31 - 1 overflows them
    (HOME off, L15290); a positioning command after that gives AL235 and does not run
    (L20083-20087); homing again clears it (L20091)."""
    d = make(**{"P5.004": 0x008, "P6.001": 2147483000})  # PR homing X = 8: here = P6.001
    d.params.write("P5.007", 0)
    run(d, 0.2)
    assert d.homing.homed and puu(d) == 2147483000
    put(d, 1, type_="single", data=100000, cmd="INC", spd=4)
    d.params.write("P5.007", 1)
    run(d, 1.0)
    assert d.counters.overflowed and not d.dio.do_function_state("HOME")
    put(d, 2, type_="single", data=0, cmd="ABS", spd=4)
    here = d.axis.position
    d.params.write("P5.007", 2)
    run(d, 0.5)
    assert "AL235" in d.alarms.active and d.axis.position == here
    d.params.write("P5.007", 0)  # homing again
    run(d, 0.2)
    assert "AL235" not in d.alarms.active and not d.counters.overflowed


def test_a_jump_to_pr0_runs_homing() -> None:
    """A jump's target is PR#00-PR#99 (L4505, L4516), and PR#0 is homing: a jump to 0 homes
    the axis (P5.004 X = 8: here, at P6.001, L4336)."""
    d = make(**{"P5.004": 0x8, "P6.001": 777})
    d.params.write("P6.002", 0x7)  # PR#1: jump
    d.params.write("P6.003", 0)  # to PR#0
    d.params.write("P5.007", 1)
    run(d, 0.3)
    assert d.homing.homed and puu(d) == 777 and not d.alarms.active


def test_ovlp_without_a_next_motion_completes_at_its_end() -> None:
    """OVLP overlaps the *next* PR's motion (L5051-5057); a single position PR with OVLP has
    none, so Cmd_OK (the command done, L15319) comes when the command reaches its target,
    not when its deceleration begins."""
    d = make()
    put(d, 1, type_="single", data=50000, spd=4, dec=3, ovlp=True)
    d.params.write("P5.007", 1)
    while not d.pr.cmd_ok:
        d.advance(MS)
        assert d.now < 2_000 * MS
    assert d.pr.monitor(1) == 50000  # Cmd_O at the target
    assert d.params.read("P5.007") in (10001, 20001)  # done (L11185), not running


def test_a_write_pr_constant_is_the_32_bit_word() -> None:
    """A write PR's constant is its 32-bit data word (L4585): into P5.003 (range
    0x00000000~0xFFFFFFFF, L11085) 0xEEEFEEFF is that value, not a refused negative number;
    into the data array it is the signed entry the array holds (P5.012)."""
    d = make()
    put(d, 1, type_="write", data=0xEEEFEEFF, dest="P5.003", auto=True)
    put(d, 2, type_="write", data=0xEEEFEEFF, dest=5, dest_array=True)
    d.params.write("P5.007", 1)
    run(d, 0.05)
    assert not d.alarms.active and d.params.read("P5.003") == 0xEEEFEEFF
    assert d.pr.array[5] == 0xEEEFEEFF - 0x100000000


@pytest.mark.parametrize("param", ["P5.098", "P5.099"])
def test_event_digits_e_and_f_are_refused(param: str) -> None:
    """P5.098 / P5.099: each digit is 0 or 1-D = PR#51-#63 (L12509-L12551); E and F are not
    digits of it (they would start PR#64 / PR#65)."""
    d = make()
    for bad in (0x000E, 0x00F0, 0x0F00, 0xD0E0):
        with pytest.raises(OutOfRange, match="must be 0-D"):
            d.params.write(param, bad)
    d.params.write(param, 0xDDDD)
    assert d.params.read(param) == 0xDDDD


def test_cmd_ok_after_stp_comes_when_the_stop_ramp_ends() -> None:
    """Cmd_OK says the command is done (L15319), not that the motor has settled: after STP
    (P5.007 = 1000) with a 20 ms stop ramp from 300 rpm (P5.003.D = E: P5.034 = 20 ms per
    3000 rpm... here the whole ramp) it comes when the command stops changing."""
    d = make(**{"P5.003": 0x0EEFEEFF})
    put(d, 1, type_="single", data=300000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.2)
    t0 = d.now
    d.params.write("P5.007", 1000)
    last = d.pr.monitor(1)
    settled = None
    while not d.pr.cmd_ok:
        d.advance(MS)
        cmd_o = d.pr.monitor(1)
        settled = d.now if cmd_o != last else settled
        last = cmd_o
        assert d.now - t0 < 200 * MS
    assert (d.now - t0) // MS <= 25  # the ramp, not the motor's settling (~90 ms)
    assert settled is None or d.now - settled <= MS


def test_al237_clears_at_servo_on_and_al217_by_an_alarm_reset() -> None:
    """AL237 "can also be cleared at Servo On" (L20096); AL217 (a write PR refused) clears
    once the PR is corrected (L20069): the refused write leaves no cause, so an alarm reset
    (P0.001 = 0, L7079) clears it."""
    d = make()
    put(d, 1, type_="index", data=100, spd=4)  # index PR before homing: AL237 (L4593)
    d.params.write("P5.007", 1)
    run(d, 0.1)
    assert "AL237" in d.alarms.active
    d.set_di(1, False)
    run(d, 0.1)
    d.set_di(1, True)
    run(d, 0.1)
    assert d.servo_on and "AL237" not in d.alarms.active
    put(d, 2, type_="write", data=2, dest="P1.002")  # ▲ with the servo on: AL217 (L20067)
    d.params.write("P5.007", 2)
    run(d, 0.05)
    assert "AL217" in d.alarms.active
    d.params.write("P0.001", 0)
    run(d, 0.01)
    assert "AL217" not in d.alarms.active


def test_an_inc_path_after_a_power_cycle_adds_to_where_the_motor_starts() -> None:
    """At power-up an incremental coordinate starts at 0, and Cmd_E (monitor 064, L4180)
    with it: an INC +10 000 then moves 10 000 PUU. Cmd_E had kept the target from before
    the power-off, and the INC path moved 2.1 turns (the session's review)."""
    d = make()
    put(d, 1, type_="single", data=200000, spd=4)  # ABS 200 000
    put(d, 2, type_="single", data=10000, spd=4, cmd="INC")
    d.set_di(3, True)
    d.advance(10 * MS)
    d.set_di(2, True)
    run(d, 2.0)
    d.set_di(2, False)
    d.set_di(3, False)
    assert puu(d) == 200000
    d.power_cycle(battery=True, off_for=100 * MS)
    d.advance(50 * MS)
    assert puu(d) == 0 and d.pr.cmd_e == 0
    d.set_di(1, True)
    run(d, 0.5)
    d.set_di(4, True)
    d.advance(10 * MS)
    d.set_di(2, True)
    run(d, 5.0)
    assert puu(d) == 10000


def test_cclr_cuts_a_pr_move_short_and_the_program_does_not_complete() -> None:
    """CCLR clears the position error (L15088, L9749): a PR move it cuts short is not
    completed, so Cmd_OK and MC_OK stay off (MC_OK = a completed PR, L15326) and an AUTO
    path does not follow. They had come on, and PR#2 started (an outside review)."""
    d = make()
    d.params.write("P2.014", 0x0104)  # DI5 = CCLR
    put(d, 1, type_="auto", data=200000, spd=4)
    put(d, 2, type_="single", data=0, spd=4)
    d.set_di(3, True)
    d.advance(5 * MS)
    d.set_di(2, True)
    d.advance(100 * MS)
    d.set_di(5, True)  # CCLR rising edge mid-move
    run(d, 3.0)
    assert not d.pr.cmd_ok and not d.dio.do_function_state("MC_OK")
    assert not any(e.startswith("dispatch:2") for _t, e in d.pr.trace)
    assert 0 < puu(d) < 200000
