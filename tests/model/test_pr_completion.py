"""Cmd_OK after a PR program that ends on a statement (A3 §7.1.2, L4195-4197: "若此段 PR 命令有
設定延遲時間 ... 待延遲時間終了，PR 位置命令完成數位輸出[0x15]Cmd_OK 才會輸出訊號"): the DLY of a
last WRITE PR (counted from its issue, L4533) and of PR#0 homing with PATH 0 (P6.000 B,
L12627) hold Cmd_OK. helper-66 (session 17) found both ignored."""

from __future__ import annotations

from hil.units import MS
from tests.model.test_pr import make as make_with_params
from tests.model.test_pr import put, puu, times
from tests.model.test_pr_overlap_sum import make


def test_cmd_ok_waits_for_the_dly_of_a_last_write_pr() -> None:
    """A WRITE PR's DLY counts from when it is issued ("下達此跳躍命令後，驅動器即開始計算延遲時間",
    L4533), and Cmd_OK comes only once a PR's DLY has run out (L4195-4197): a program ending
    on a WRITE with DLY #2 (P5.042 = 200 ms) raises Cmd_OK 200 ms after that write."""
    d = make()
    put(d, 1, type_="auto", data=10_000, spd=4)
    put(d, 2, type_="write", data=600, dest="P5.064", dly=2)
    t0 = d.now // MS
    d.params.write("P5.007", 1)
    d.advance(1000 * MS)
    read = [t // MS - t0 for t, what in d.pr.trace if what.startswith("read:2")]
    cmd_ok = [t - t0 for t in times(d, "Cmd_OK:1")]
    assert len(read) == 1 and len(cmd_ok) == 1
    assert d.params.get("P5.064") == 600
    assert cmd_ok[0] == read[0] + 200, (read, cmd_ok)


def test_cmd_ok_after_homing_with_path_0_waits_for_p6000s_dly() -> None:
    """PR#0 homing with PATH 0 ("Stop：復歸完成，停止", P6.000 YX, L12617) and DLY B = 1
    (P5.041 = 100 ms, L12627-12628): Cmd_OK 100 ms after the homing completed (L4195-4197)."""
    d = make()
    d.params.write("P5.004", 0x8)  # X = 8: the current position is the origin
    d.params.write("P6.000", 0x0010_0000)  # B (DLY) = 1, PATH = 0
    d.params.write("P5.007", 0)
    d.advance(1000 * MS)
    assert d.homing.homed
    cmd_ok = times(d, "Cmd_OK:1")
    homed = [t // MS for t, what in d.homing.trace if what == "homed"]
    assert len(cmd_ok) == 1 and len(homed) == 1
    assert cmd_ok[0] == homed[0] + 100, (homed, cmd_ok)


def test_after_stp_tpos_mc_ok_and_p5007_say_the_target_was_not_reached() -> None:
    """PR mode TPOS: "當設定目標位置與實際馬達位置相差之偏差值小於設定之位置範圍(P1.054)" (L8694).
    STP (P5.007 = 1000, L11183) stops the axis short and keeps Cmd_E (000:605): the command
    is sent (Cmd_OK, L15319) but the motor is far from the set target, so TPOS and MC_OK stay
    off (MC_OK = Cmd_OK and TPOS, L8628) and P5.007 reads n + 10000, "命令發送完畢，但馬達
    定位未完成" (L11185-11188). INC 0 then completes the move (000:605): TPOS, MC_OK and
    n + 20000."""
    d = make()
    put(d, 1, type_="single", data=500_000, spd=4)
    put(d, 2, type_="single", data=0, cmd="INC", spd=4)
    d.params.write("P5.007", 1)
    d.advance(200 * MS)
    d.params.write("P5.007", 1000)
    d.advance(1000 * MS)
    assert d.pr.cmd_ok and d.dio.do_function_state("Cmd_OK")
    assert not d.dio.do_function_state("TPOS")
    assert not d.pr.mc_ok and not d.dio.do_function_state("MC_OK")
    assert d.params.get("P5.007") == 10001
    d.params.write("P5.007", 2)
    d.advance(3000 * MS)
    assert d.dio.do_function_state("TPOS") and d.pr.mc_ok
    assert d.params.get("P5.007") == 20002


def test_a_write_pr_reads_the_monitors_the_drive_keeps() -> None:
    """A WRITE PR's source may be a monitor variable (SOUR = 11, L4566-4575): 038, the
    battery voltage (L15477), and 043, the last CAP data (L15481), as P0.009-P0.013 show
    them, not only PR mode's own 000/001/002/064 (helper-66: refused as AL231)."""
    d = make()
    put(d, 1, type_="write", source="monitor", data=38, dest=5, dest_array=True, auto=True)
    put(d, 2, type_="write", source="monitor", data=43, dest=6, dest_array=True)
    d.pr.array[5] = d.pr.array[6] = 12345  # overwritten by the writes
    d.params.write("P5.007", 1)
    d.advance(100 * MS)
    assert not d.alarms.active
    assert d.pr.array[5] == d.hooks.monitors[38]() != 12345
    assert d.pr.array[6] == d.hooks.monitors[43]() != 12345


def test_a_stopped_speed_pr_keeps_tpos_and_raises_no_al380() -> None:
    """AL380 is a displacement after positioning (L8632, L20147); a speed PR sets no target
    position for L8694 to judge, so STP after it leaves TPOS (the following error's) and MC_OK
    as they were, with P1.048 = 0x10 (AL380 armed): no alarm (helper-92)."""
    d = make()
    d.params.write("P1.048", 0x10)
    put(d, 1, type_="speed", data=3000)  # 300 rpm
    d.params.write("P5.007", 1)
    d.advance(500 * MS)
    assert d.pr.mc_ok
    d.params.write("P5.007", 1000)
    d.advance(1000 * MS)
    assert not d.alarms.active
    assert d.pr.mc_ok and d.dio.do_function_state("TPOS")
    assert d.params.get("P5.007") == 20001


def test_tpos_during_a_last_write_prs_dly() -> None:
    """L4195-4197: with a DLY, TPOS comes on once the error is inside P1.054 and Cmd_OK when
    the DLY ran out. A WRITE with DLY #2 (200 ms) triggered with the motor at rest on its
    target: TPOS on at once, Cmd_OK 200 ms later (helper-92: TPOS waited for Cmd_OK)."""
    d = make()
    put(d, 1, type_="write", data=600, dest="P5.064", dly=2)
    d.advance(100 * MS)
    d.params.write("P5.007", 1)
    d.advance(10 * MS)
    assert d.dio.do_function_state("TPOS") and not d.pr.cmd_ok
    d.advance(200 * MS)
    assert d.pr.cmd_ok and d.pr.mc_ok


def test_servo_off_during_a_dly_ends_the_program() -> None:
    """Servo off ends a PR program (its Cmd_OK off): one waiting out a WRITE's DLY too, which
    then raises no Cmd_OK or MC_OK with the servo off (helper-92)."""
    d = make()
    put(d, 1, type_="write", data=600, dest="P5.064", dly=2)
    d.params.write("P5.007", 1)
    d.advance(50 * MS)
    d.set_di(1, False)  # SON off
    d.advance(400 * MS)
    assert not d.servo_on
    assert not d.pr.cmd_ok and not d.pr.mc_ok
    assert times(d, "Cmd_OK:1") == []


def test_a_jump_to_pr0_homes_after_the_jumps_dly() -> None:
    """A jump's DLY counts from its read and its target is read when it ran out (L4505):
    a jump to PR#0 with DLY #2 (200 ms) starts the homing 200 ms after the jump, and Cmd_OK
    stays off until the homing is over (helper-92: homing at once, Cmd_OK on for 1 ms)."""
    d = make()
    d.params.write("P5.004", 0x8)  # X = 8: the current position is the origin
    put(d, 1, type_="jump", data=0, dly=2)
    t0 = d.now // MS
    d.params.write("P5.007", 1)
    d.advance(500 * MS)
    read = [t // MS - t0 for t, what in d.pr.trace if what.startswith("read:1")]
    start = [t // MS - t0 for t, what in d.homing.trace if what.startswith("trigger:jump")]
    homed = [t // MS - t0 for t, what in d.homing.trace if what == "homed"]
    assert start == [read[0] + 200], (read, start)
    assert d.homing.homed
    assert [t - t0 for t in times(d, "Cmd_OK:1")] == homed


def test_a_write_pr_reads_the_position_monitors_p0009_shows() -> None:
    """Monitors 003-006 (positions in pulses, the pulse frequency, L15443-15446) and 049
    (CN1 pulses, L15483) are in the table AL231 guards (L20077): a WRITE PR reads them as
    P0.009 does (helper-92: AL231)."""
    d = make()
    put(d, 1, type_="auto", data=5000, spd=4)
    put(d, 2, type_="write", source="monitor", data=4, dest=7, dest_array=True, auto=True)
    put(d, 3, type_="write", source="monitor", data=49, dest=8, dest_array=True)
    d.pr.array[7] = d.pr.array[8] = 12345
    d.params.write("P5.007", 1)
    d.advance(1000 * MS)
    assert not d.alarms.active
    d.params.write("P0.017", 4)  # the command in pulses: the target, 5000 PUU
    assert d.pr.array[7] == d.params.read("P0.009") == round(5000 * 16777216 / 100000)
    assert d.pr.array[8] == d.params.read("P5.018")


def test_a_sequential_rel_pr_counts_from_the_motor_not_from_cmd_e() -> None:
    """REL: "目標位置為馬達目前位置加上位置命令的值" (L4469); only an internal interrupt (an INS
    PR) makes REL act as INC (L5000). A speed PR (AUTO, DLY) then a sequential REL +10000:
    the target is where the motor is when REL is issued plus 10000, not the old Cmd_E plus
    10000, which drove the motor back (helper-93)."""
    d = make()
    put(d, 1, type_="speed", data=3000, auto=True, dly=1)  # 300 rpm, DLY #1 = 100 ms
    put(d, 2, type_="single", data=10000, cmd="REL", spd=4)
    d.params.write("P5.007", 1)
    while not times(d, "motion:2"):
        d.advance(MS)
    at_issue = d.pr.monitor(0)
    d.advance(2000 * MS)
    assert abs(puu(d) - (at_issue + 10000)) <= 1, (at_issue, puu(d))
    assert puu(d) > 40000  # onwards, not back to the old Cmd_E + 10000


def test_an_index_pr_with_s_low_runs_in_hundredths_of_an_rpm() -> None:
    """Index PR OPT2 bit 0 S_LOW: the speed unit is 0.01 rpm instead of 0.1 rpm (L4633,
    L4637): SPD #4 (P5.064 = 3000) is 30 rpm, a tenth of the 300 rpm without it, so the same
    index move takes about ten times as long (helper-93: the bit was ignored)."""
    def duration(s_low: bool) -> int:
        d = make_with_params(**{"P2.052": 100000})
        d.params.write("P5.004", 8)  # X = 8: homed where it stands (L4360)
        d.params.write("P5.007", 0)
        d.advance(100 * MS)
        assert d.homing.homed
        put(d, 1, type_="index", data=25000, spd=4, s_low=s_low)
        d.params.write("P5.007", 1)
        d.advance(5000 * MS)
        start, done = times(d, "motion:1")[0], times(d, "done:1")[0]
        assert puu(d) == 25000
        return done - start
    fast, slow = duration(False), duration(True)
    # 25000 PUU = 0.25 rev (P1.044/P1.045 factory): 50 ms at 5 rev/s plus the 20 ms ramp of
    # P5.020 (200 ms per 3000 rpm); 500 ms at 0.5 rev/s, its ramps 2 ms
    assert 65 <= fast <= 75 and 495 <= slow <= 510, (fast, slow)


def test_a_write_pr_without_rom_is_lost_at_a_power_cycle() -> None:
    """A WRITE PR's ROM bit: "ROM 為同時寫入 RAM 與 EEPROM，提供參數斷電保持的功能" (L4533).
    Without it the write goes to RAM alone: after a power cycle the parameter has its old
    value again; with it the value stays (helper-93: both stayed)."""
    d = make()
    put(d, 1, type_="write", data=77, dest="P5.045", auto=True)
    put(d, 2, type_="write", data=88, dest="P5.046", rom=True)
    before = d.params.get("P5.045")
    d.params.write("P5.007", 1)
    d.advance(50 * MS)
    assert (d.params.get("P5.045"), d.params.get("P5.046")) == (77, 88)
    d.power_cycle()
    assert d.params.get("P5.045") == before != 77
    assert d.params.get("P5.046") == 88


def test_a_triggered_group_runs_its_ins_prs_while_its_lead_waits_for_the_generator() -> None:
    """Every ms the scheduler hands the lead PR *and its group* to the executor, which
    replaces the running group at once; writes are done as they are read, and only motion
    waits in the generator's one-command buffer (L4920-4928); the last motion PR of a group
    runs, an INS one merging with the running command (L4986, L5022). PR#1 moves to 200000;
    a trigger of PR#5 (no INS, AUTO) followed by PR#6 (INS, ABS 50000): PR#6 is read and
    runs at once, not after PR#1 has reached 200000 (helper-93); with PR#6 an INS write, the
    write is done at once and PR#5 runs when PR#1 is done."""
    d = make_with_params()
    put(d, 1, type_="single", data=200000, spd=4)
    put(d, 5, type_="auto", data=10000, cmd="INC", spd=4)
    put(d, 6, type_="single", data=50000, spd=4, ins=True)
    d.params.write("P5.007", 1)
    d.advance(100 * MS)
    t5 = d.now // MS
    d.params.write("P5.007", 5)
    d.advance(1500 * MS)
    assert times(d, "motion:6")[0] - t5 <= 1
    assert puu(d) == 50000 and not times(d, "done:1")  # never went on to 200000

    d = make_with_params()
    put(d, 1, type_="single", data=200000, spd=4)
    put(d, 5, type_="auto", data=10000, cmd="INC", spd=4)
    put(d, 6, type_="write", data=123, dest="P5.055", ins=True)
    d.params.write("P5.007", 1)
    d.advance(100 * MS)
    t5 = d.now // MS
    d.params.write("P5.007", 5)
    d.advance(1500 * MS)
    wrote = [t // MS for t, what in d.pr.trace if what == "write:6"]
    assert wrote and wrote[0] - t5 <= 1 and d.params.get("P5.055") == 123
    assert times(d, "motion:5")[0] == times(d, "done:1")[0]  # from the buffer when PR#1 ends
    assert puu(d) == 210000  # INC: PR#1's Cmd_E + 10000


def test_a_software_limit_stop_drops_a_buffered_lead() -> None:
    """AL283 stops the program (L20105-20116); a lead waiting in the one-command buffer is
    part of it and does not run after the stop ramp (helper-94: it drove to -30000)."""
    d = make_with_params(**{"P5.008": 50000})
    put(d, 1, type_="single", data=100000, spd=4)  # crosses P5.008
    put(d, 2, type_="single", data=-30000, spd=4)
    d.params.write("P5.007", 1)
    d.advance(60 * MS)
    d.params.write("P5.007", 2)  # PR#1 still runs: PR#2 waits in the buffer
    d.advance(3000 * MS)
    assert "AL283" in d.alarms.active
    assert times(d, "motion:2") == [] and puu(d) > 50000


def test_an_inc_pr_after_an_interrupted_homing_adds_to_the_cmd_e_it_showed() -> None:
    """While PR#0 runs Cmd_E = Cmd_O (L4396) and INC adds to Cmd_E (L4470): an INC PR that
    replaces a running homing (L4920) moves on from where the homing's command was, not from
    the Cmd_E before the homing (helper-94: the motor was driven back)."""
    d = make_with_params(**{"P5.004": 0x4, "P5.006": 100})  # X=4: next Z forward, 10 rpm
    put(d, 1, type_="single", data=10000, cmd="INC", spd=4)
    d.params.write("P5.007", 0)
    d.advance(1500 * MS)
    shown = d.pr.monitor(64)
    assert shown == d.pr.monitor(1) > 10000
    d.params.write("P5.007", 1)
    d.advance(3000 * MS)
    assert abs(puu(d) - (shown + 10000)) <= 100, (shown, puu(d))


def test_a_communication_write_after_a_ram_only_write_is_kept() -> None:
    """A WRITE PR without ROM writes RAM alone (L4533); a later write by communication goes
    to EEPROM as ever, so it survives the power cycle (helper-94: the value before the PR came
    back). P2.030 = 8 backs every value in RAM up to EEPROM (L9501)."""
    d = make()
    put(d, 1, type_="write", data=77, dest="P5.045")
    d.params.write("P5.007", 1)
    d.advance(50 * MS)
    d.params.modbus_write(d.params.table.spec("P5.045").modbus_address, [55, 0])
    d.power_cycle()
    assert d.params.get("P5.045") == 55
    d.params.write("P5.007", 1)
    d.advance(50 * MS)
    d.params.write("P2.030", 8)
    d.power_cycle()
    assert d.params.get("P5.045") == 77
