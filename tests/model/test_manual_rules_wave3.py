"""Manual rules written afresh from the A3 manual (shared/seeds/002_…), issue 22.

Each test quotes the rule it checks; the lines were read before the model: TPOS in PR mode
(P1.054 L8689-8693, block diagram L8620-8632), MC_OK / P1.048 / AL380 (L8596-8632,
L20147-20151), write-PR alarms (table 13.1 L20044-20075), the command generator's 1 ms
cycle (L4178, L4909), NMT reset and transition 15 (L18250-18266, L20025), AL020 and the
1001h error register (L10571-10578, L19598-19602, L17534). Injected clock throughout.
"""

from __future__ import annotations

import random

import pytest

from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS
from tests.model.test_pr import make, put, run

REV_PUU = 100_000  # test_pr's bench: 100000 PUU per motor revolution


def tpos(d: Drive) -> bool:
    return d.dio.do_function_state("TPOS")


# -- 1. TPOS in PR mode -------------------------------------------------------------------


def test_pr_tpos_is_off_from_the_trigger_until_the_target_is_reached() -> None:
    """P1.054 PR: "當設定目標位置與實際馬達位置相差之偏差值小於設定之位置範圍 … 輸出 TPOS"
    (L8694); "命令觸發 … 同時清除信號 2、4、5、6" (L8624): a trigger clears TPOS (4)."""
    d = make()
    assert tpos(d)  # at rest, nothing to do
    put(d, 1, type_="single", data=REV_PUU, spd=4)
    d.params.write("P5.007", 1)
    d.advance(2 * MS)
    assert not tpos(d)
    seen_on_while_far = False
    for _ in range(2000):
        d.advance(MS)
        far = abs(d.snapshot()["position_puu"] - REV_PUU) >= 1000  # P1.054 = 0.01 rev
        seen_on_while_far |= tpos(d) and far
        if d.pr.cmd_ok:
            break
    assert not seen_on_while_far  # the following error is small all the way: not TPOS
    run(d, 0.2)
    assert tpos(d)
    assert abs(d.snapshot()["position_puu"] - REV_PUU) < 1000


def test_pr_tpos_is_cleared_by_a_trigger_even_for_a_target_inside_the_window() -> None:
    """L8624: a trigger clears TPOS; it comes back once the command reached its target."""
    d = make()
    put(d, 1, type_="single", data=100, spd=4)  # 100 PUU: inside the 1000 PUU window
    d.params.write("P5.007", 1)
    d.advance(MS + MS // 2)
    assert not tpos(d)
    run(d, 0.1)
    assert tpos(d)


# -- 2. MC_OK hold and AL380 at standstill ------------------------------------------------


def _positioned(p1048: int) -> Drive:
    d = make(**{"P1.048": p1048})
    put(d, 1, type_="single", data=10_000, spd=4)
    d.params.write("P5.007", 1)
    run(d, 0.5)
    assert d.dio.do_function_state("MC_OK")
    return d


def test_p1054_write_at_standstill_drops_mc_ok_and_raises_al380() -> None:
    """MC_OK = Cmd_OK and TPOS (L8629); P1.048.Y = 1: TPOS off after MC_OK -> AL380
    (L8632, L20147). A P1.054 of 0 puts every position outside the window (L8694)."""
    d = _positioned(0x10)
    d.params.write("P1.054", 0)
    d.advance(MS)
    assert not tpos(d)
    assert not d.dio.do_function_state("MC_OK")  # X = 0: not held (L8609)
    assert "AL380" in d.alarms.active


def test_p1048_x_holds_mc_ok_when_the_position_is_pushed_out() -> None:
    """P1.048.X = 1: "一旦輸出 On 後則保持，不論信號 4 是否變成 Off" (L8630-8631)."""
    d = _positioned(0x11)
    d.axis.position += 5_000_000  # pushed by hand at standstill (0.3 rev)
    d.advance(MS)
    assert "AL380" in d.alarms.active
    assert d.dio.do_function_state("MC_OK")


def test_without_p1048_y_no_al380() -> None:
    """P1.048.Y = 0: AL380 不作用 (L8612)."""
    d = _positioned(0x00)
    d.params.write("P1.054", 0)
    d.advance(MS)
    assert "AL380" not in d.alarms.active
    assert not d.dio.do_function_state("MC_OK")


# -- 3. write-PR alarms ---------------------------------------------------------------------


@pytest.mark.parametrize(("write", "alarm"), [
    # "伺服 ON 不可寫入" (AL217, L20065-20069): P1.002 may be written at servo off only
    ({"source": "constant", "data": 1, "dest": "P1.002"}, "AL217"),
    # "來源參數群組超出範圍" (AL207, L20044-20047): there is no group P9
    ({"source": "parameter", "data": 0x0905, "dest": "P5.064"}, "AL207"),
    # "來源參數編號超出範圍" (AL209, L20049-20052): P5.250 does not exist
    ({"source": "parameter", "data": 0x05FA, "dest": "P5.064"}, "AL209"),
    # "參數數值設定錯誤" (AL213, L20054-20057): a value outside P1.054's 0 ~ 16777216
    ({"source": "constant", "data": -5, "dest": "P1.054"}, "AL213"),
])  # fmt: skip
def test_write_pr_alarm_codes(write: dict, alarm: str) -> None:
    d = make()
    put(d, 1, type_="write", **write)
    d.params.write("P5.007", 1)
    run(d, 0.05)
    assert alarm in d.alarms.active, d.alarms.active
    assert d.servo_on  # all of them are WARN: the servo stays on (L19470-19476)


# -- 4. the command generator's own 1 ms grid -----------------------------------------------


def _profile(slices) -> list[tuple[int, int]]:
    """(Cmd_O, Fb_PUU) at every ms of a 300 ms PR move, the model advanced in `slices`."""
    d = make()
    put(d, 1, type_="single", data=REV_PUU, spd=4)
    d.params.write("P5.007", 1)
    t0, out = d.now, []
    for k in range(1, 301):
        while d.now < t0 + k * MS:
            d.advance(min(slices(), t0 + k * MS - d.now))
        out.append((d.pr.monitor(1), d.pr.monitor(0)))
    return out


def test_results_do_not_depend_on_how_the_caller_slices_time() -> None:
    """The drive computes its command every 1 ms (PR monitor variables, L4178; the 1 ms
    PR cycle, L4909): any slicing of the same scenario gives the same command (and
    feedback) at every ms."""
    ref = _profile(lambda: MS)
    for seed in range(4):
        rng = random.Random(seed)
        assert _profile(lambda rng=rng: rng.randint(1, 3 * MS)) == ref
    assert _profile(lambda: MS // 10) == ref


def test_the_command_is_the_ideal_trapezoid_and_the_feedback_follows_it() -> None:
    """300 rpm (P5.064) with the 200 ms ramp of P5.020 (ms per 3000 rpm, L11330): 20 ms to
    speed, then 500 PUU per ms, from the next 1 ms PR tick after the P5.007 write (L4916);
    while the command speeds up or cruises, the feedback never runs ahead of it."""
    prof = _profile(lambda: MS)
    start_ms, accel_ms, per_ms = 1, 20, 300 / 60 * REV_PUU / 1000
    ideal = per_ms * (100 - start_ms - accel_ms / 2)  # at 100 ms
    # the generator integrates its 1 ms cycle semi-implicitly: at most half a cycle ahead
    # of the ideal trapezoid (docs/manual-choices.md, model substep)
    assert ideal <= prof[99][0] <= ideal + per_ms / 2
    speeding_up_or_cruising = prof[:190]  # the deceleration starts at about 201 ms
    assert all(fb <= cmd for cmd, fb in speeding_up_or_cruising)
    assert prof[-1] == (REV_PUU, REV_PUU)


# -- 5. NMT reset and the CiA 402 state ------------------------------------------------------


def _faulted_by_al180() -> Drive:
    d = Drive(inputs={8: True})
    d.raise_alarm("AL180")  # heartbeat consumer, servo off (L19453)
    d.advance(MS)
    assert d.cia402.state == "FAULT"
    return d


@pytest.mark.parametrize("kind", ["reset node", "reset communication"])
def test_nmt_reset_clears_al180_and_leaves_fault(kind: str) -> None:
    """AL180 "將 NMT 重置或使用 0x6040 重置" (L20025); transition 15 "Alarm 清除" (L18265):
    after the NMT reset the drive is no longer in FAULT and 06h/07h/0Fh enable it."""
    d = _faulted_by_al180()
    d.nmt_reset(kind)
    assert d.params.read("P0.001") == 0
    assert d.cia402.state == "SWITCH ON DISABLED"
    assert d.read_object(0x6041, 0) & 0x4F == 0x40
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)
    assert d.cia402.state == "OPERATION ENABLED" and d.servo_on


def test_nmt_reset_keeps_fault_while_a_servo_off_alarm_remains() -> None:
    """An alarm an NMT reset does not clear (AL009: alarm reset, L19539-19542) keeps FAULT."""
    d = _faulted_by_al180()
    d.raise_alarm("AL009")
    d.nmt_reset("reset communication")
    assert d.cia402.state == "FAULT"


def test_nmt_reset_option_off_keeps_the_old_reading() -> None:
    d = Drive(options=ModelOptions(nmt_reset_reinit_402=False), inputs={8: True})
    d.raise_alarm("AL180")
    d.advance(MS)
    d.nmt_reset("reset communication")
    assert d.cia402.state == "FAULT"


# -- 8. NMT Stop while moving -----------------------------------------------------------------


def _pv_running(**opts) -> Drive:
    d = Drive(options=ModelOptions(**opts), inputs={8: True})
    d.write_object(0x6060, 0, 3)
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
        d.advance(2 * MS)
    d.write_object(0x60FF, 0, 1000)  # 100 rpm
    d.advance(500 * MS)
    assert d.axis.velocity_rpm == pytest.approx(100, abs=1)
    return d


def test_nmt_stop_disables_a_moving_drive_by_default() -> None:
    """A stopped node takes no RxPDO and no SDO controlword (L17089-17095), so the master
    cannot stop the axis; the safe default disables it (P1.032.Y stop, brake)."""
    d = _pv_running()
    d.nmt_stop()
    d.advance(2000 * MS)
    assert not d.servo_on
    assert d.axis.velocity_rpm == pytest.approx(0, abs=0.01)


def test_nmt_stop_option_none_keeps_the_axis_turning() -> None:
    d = _pv_running(nmt_stop_action="none")
    d.nmt_stop()
    d.advance(200 * MS)
    assert d.servo_on and d.axis.velocity_rpm == pytest.approx(100, abs=1)


# -- 9. AL020 reset and the EMCY error register ----------------------------------------------


def test_al020_sets_the_communication_bit_of_1001h() -> None:
    """1001h bit 4 "通訊錯誤 Communication Error" (L17534); AL020 is an RS-485 timeout."""
    d = Drive(inputs={8: True})
    d.raise_alarm("AL020")
    assert d.alarms.error_register & 0x11 == 0x11


@pytest.mark.parametrize(("scope", "cleared"), [("alarm_reset", True), ("listed", False)])
def test_al020_and_the_6040h_fault_reset(scope: str, cleared: bool) -> None:
    """AL020's remedy is "異警重置" only (L19602); `fault_reset_clears` chooses whether the
    6040h fault reset (L18231) counts as one. DI.ARST always clears it (L15082)."""
    d = Drive(options=ModelOptions(fault_reset_clears=scope), inputs={8: True})
    d.raise_alarm("AL020")
    d.write_object(0x6040, 0, 0x00)
    d.write_object(0x6040, 0, 0x80)  # bit 7 rising edge
    assert ("AL020" not in d.alarms.active) is cleared
    d.alarms.reset("di")
    assert "AL020" not in d.alarms.active


@pytest.mark.parametrize("inside_us", [1, 300, 999])
def test_a_command_inside_a_cycle_acts_from_the_next_cycle(inside_us: int) -> None:
    """Causal: a set-point given inside a 1 ms cycle moves nothing before that cycle ends,
    and from then on exactly as one given at the cycle's end."""
    def run(offset_ns: int) -> list[float]:
        d = Drive(inputs={8: True})
        d.write_object(0x6060, 0, 3)
        for cw in (0x06, 0x07, 0x0F):
            d.write_object(0x6040, 0, cw)
            d.advance(2 * MS)
        d.advance(100 * MS)  # at rest, brake released
        t_cycle = (d.now // MS + 1) * MS
        d.advance_to(t_cycle - MS + offset_ns)
        at_command = d.axis.position
        d.write_object(0x60FF, 0, 1000)  # 100 rpm
        out = []
        for k in range(5):
            d.advance_to(t_cycle + k * MS)
            out.append(d.axis.position - at_command)
        return out

    inside = run(inside_us * 1000)
    at_end = run(MS)
    assert inside[0] == 0.0  # the cycle the command arrived in ran without it
    assert inside == at_end


@pytest.mark.parametrize("path", [
    {"type_": "write", "source": "constant", "data": 100, "dest": "P5.064"},
    {"type_": "jump", "data": 3},  # to an empty path
])
def test_tpos_returns_after_a_trigger_that_moves_nothing(path: dict) -> None:
    """L8624 clears TPOS at the trigger; with no motion the command is output at once, so
    TPOS (the target is where the motor is) and MC_OK come back."""
    d = make()
    put(d, 1, **path)
    d.params.write("P5.007", 1)
    run(d, 0.1)
    assert d.pr.cmd_ok
    assert tpos(d) and d.dio.do_function_state("MC_OK")


@pytest.mark.parametrize(("code", "register"), [
    ("AL009", 0x01), ("AL014", 0x01), ("AL015", 0x01), ("AL056", 0x01),  # the drive's own
    ("AL180", 0x11), ("AL185", 0x11), ("AL111", 0x11), ("AL3E3", 0x11),  # the bus's
])
def test_1001h_bit_4_only_for_communication_errors(code: str, register: int) -> None:
    """1001h bits (L17526-L17535): b0 generic, b1 current, b2 voltage, b3 temperature, b4
    communication error, b5 reserved. A following error, a limit switch or overspeed is no
    communication error (it set b4 from its 8xxxh EMCY code; found by helper-23)."""
    d = Drive(inputs={8: True})
    d.raise_alarm(code)
    assert d.alarms.error_register == register
