"""Table 8.1 DI functions that act on the motion (issue 13 item 6), on the injected clock.

PFQS L15253 (+ AL35F/AL3CF L20141-20157, P5.003 L11084-11100), JOGU/JOGD L15209-15212
(P4.005 L10846-10861), TRQLM L15101 (P1.012-P1.014 L7993-8031, P1.002 L7815-7845, L4042-4044),
SPDLM L15121 (P1.009-P1.011 L7931-7991, L4034-4036), ZCLAMP L15091 (P2.065 bit 10
L9904-9920), CCLR L15088 (P2.050 L9742-9753), GAINUP L15085 (P2.027 L9423-9466).
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.events import AlarmChanged
from hil.model.options import ModelOptions
from hil.units import MS, S

PV, PT, PP = 3, 4, 1  # 6060h modes
# EMGS wired closed (DI8), BRKR on DO6; DI5 and DI10 carry the function under test.
BENCH = {"P2.041": 0x0108, "P2.014": 0x0000, "P2.037": 0x0000}


def make(di5: int = 0, di10: int = 0, options: ModelOptions | None = None,
         **params: int) -> tuple[Drive, list]:
    """A drive with DI5 = `di5` and DI10 = `di10` (a-contacts), servo on over CiA 402."""
    bench = BENCH | {"P2.014": di5 and 0x0100 | di5, "P2.037": di10 and 0x0100 | di10}
    drive = Drive(options=options, inputs={8: True}, params=bench | params)
    events: list = []
    drive.subscribe(events.append)
    return drive, events


def enable(drive: Drive, mode: int) -> None:
    drive.write_object(0x6060, 0, mode)
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
    drive.advance(1 * MS)
    assert drive.servo_on


def run_pv(drive: Drive, rpm: float, accel_ms: int = 100) -> None:
    drive.write_object(0x6083, 0, accel_ms)
    drive.write_object(0x6084, 0, accel_ms)
    drive.write_object(0x60FF, 0, round(rpm * 10))  # 0.1 rpm


def raised(events: list, code: str) -> list[int]:
    return [e.t for e in events if isinstance(e, AlarmChanged) and e.active and e.code == code]


def press(drive: Drive, n: int, closed: bool = True) -> int:
    """Set DI n; return when the P2.009 filter (2 ms) accepted it."""
    drive.set_di(n, closed)
    drive.advance(drive.params.get("P2.009") * MS)
    return drive.now


# -- PFQS ------------------------------------------------------------------------------------


def test_pfqs_al35f_ramp_with_p5003_c_then_al3cf_and_servo_off() -> None:
    """L15253: AL35F, decelerate with P5.003.C (E -> P5.034 = 50 ms / 3000 rpm, L11084-11100),
    at 0 AL3CF and Servo Off (L20143, L20155)."""
    drive, events = make(di5=0x47)
    enable(drive, PV)
    run_pv(drive, 1500)
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(1500, abs=1)
    t0 = press(drive, 5)
    assert raised(events, "AL35F") == [t0]
    assert drive.servo_on  # AL35F: WARN, servo on (L19413)
    run_pv(drive, 3000)  # the host's new command does not restart the motor
    drive.advance(20 * MS)
    assert 0 < drive.axis.velocity_rpm < 1500 * (1 - 20 / 25) + 50
    drive.advance(10 * MS)
    [t_cf] = raised(events, "AL3CF")
    assert t0 + 24 * MS <= t_cf <= t0 + 27 * MS  # 1500 rpm at 50 ms / 3000 rpm = 25 ms
    assert not drive.servo_on  # AL3CF: servo off (L19414)
    assert drive.alarms.active == ("AL3CF",)  # AL35F was "decelerating" (pfqs_keeps_al35f)
    assert drive.cia402.state != "OPERATION ENABLED"


def test_pfqs_alarms_clear_by_power_cycle_not_arst() -> None:
    """Chapter 13: "重上電清除" (L20145, L20157); ARST leaves them (default choice)."""
    drive, _ = make(di5=0x47)
    enable(drive, PV)
    press(drive, 5)
    drive.advance(10 * MS)
    assert "AL3CF" in drive.alarms.active
    drive.alarms.reset("di")
    assert "AL3CF" in drive.alarms.active
    drive.set_di(5, False)
    drive.power_cycle()
    assert drive.alarms.active == ()


def test_pfqs_option_reset_follows_the_di_table() -> None:
    """L15253: "若欲重新 Servo On，需要異警重置" (option pfqs_clear = "reset")."""
    drive, _ = make(di5=0x47, options=ModelOptions(pfqs_clear="reset", pfqs_keeps_al35f=True))
    enable(drive, PV)
    press(drive, 5)
    drive.advance(10 * MS)
    assert set(drive.alarms.active) == {"AL35F", "AL3CF"}
    drive.alarms.reset("di")
    assert drive.alarms.active == ()


def test_a_servo_off_during_the_pfqs_ramp_ends_it_with_al3cf() -> None:
    """SON/CiA 402 servo off while AL35F ramps: the quick stop ends there (AL3CF) and nothing
    stays locked (choice, docs/manual-choices.md#di-functions)."""
    drive, _ = make(di5=0x47)
    enable(drive, PV)
    run_pv(drive, 1500)
    drive.advance(300 * MS)
    press(drive, 5)
    drive.write_object(0x6040, 0, 0x07)  # disable operation: servo off mid-ramp
    drive.advance(5 * MS)
    assert not drive.servo_on
    assert drive.alarms.active == ("AL3CF",)
    assert drive.axis.locks == frozenset()


def test_pfqs_acts_in_s_not_in_tz() -> None:
    """PFQS modes: PT, PR, T, S (L15253); Tz (P1.001 = 5) is not one of them."""
    drive, events = make(di5=0x47, **{"P1.001": 0x0005})
    drive.params.write("P2.030", 1)  # forced servo on (L9496)
    assert drive.servo_on and drive.difunc.control_mode() == "Tz"
    press(drive, 5)
    drive.advance(10 * MS)
    assert raised(events, "AL35F") == [] and drive.servo_on


# -- JOGU / JOGD -----------------------------------------------------------------------------


def test_jogu_runs_at_p4005_while_held_and_stops_on_release() -> None:
    """JOGU: forward jog while on (L15209); speed P4.005 (L10846-10861)."""
    drive, _ = make(di5=0x37, di10=0x38, **{"P4.005": 300})
    enable(drive, PP)
    press(drive, 5)
    drive.advance(100 * MS)  # 300 rpm at 500 ms / 3000 rpm = 50 ms ramp
    assert drive.axis.velocity_rpm == pytest.approx(300, abs=1)
    drive.write_object(0x607A, 0, 0)  # a PP set-point during the jog is not taken
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(10 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(300, abs=1)
    press(drive, 5, False)
    drive.advance(100 * MS)  # 50 ms ramp, then the position loop settles
    assert abs(drive.axis.velocity_rpm) < 0.5


def test_jogd_runs_backwards_both_held_stops() -> None:
    """JOGD: reverse jog (L15212); both held is no direction: the motor stops (choice)."""
    drive, _ = make(di5=0x37, di10=0x38, **{"P4.005": 300})
    enable(drive, PV)
    press(drive, 10)
    drive.advance(100 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(-300, abs=1)
    press(drive, 5)
    drive.advance(150 * MS)
    assert abs(drive.axis.velocity_rpm) < 0.5


def test_jog_needs_the_servo_on() -> None:
    """L2937: jog only works while Servo On; it starts when the servo comes on."""
    drive, _ = make(di5=0x37, **{"P4.005": 300})
    press(drive, 5)
    drive.advance(100 * MS)
    assert drive.axis.velocity_rpm == 0.0
    enable(drive, PV)
    drive.advance(100 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(300, abs=1)


def test_jog_through_p4005_speed_then_4998_ccw_4999_cw_0_stop() -> None:
    """P4.005 communication control (L10863-10866): 1-5000 speed, 4998 CCW, 4999 CW, 0 stop.
    P1.001.Z = 0: CCW is the positive direction (docs/manual-choices.md, P1.001.Z)."""
    drive, _ = make()
    enable(drive, PV)
    drive.params.write("P4.005", 600)
    drive.advance(50 * MS)
    assert drive.axis.velocity_rpm == 0.0  # a speed alone does not move
    drive.params.write("P4.005", 4998)
    drive.advance(200 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(600, abs=1)
    drive.params.write("P4.005", 4999)
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(-600, abs=1)
    drive.params.write("P4.005", 0)
    drive.advance(300 * MS)
    assert abs(drive.axis.velocity_rpm) < 0.5


def test_jog_through_p4005_needs_the_servo_on() -> None:
    """Jogging works only while Servo On (L2937)."""
    drive, _ = make()
    drive.params.write("P4.005", 4998)
    enable(drive, PV)
    drive.advance(200 * MS)
    assert drive.axis.velocity_rpm == 0.0


# -- TRQLM / SPDLM -------------------------------------------------------------------------


def peak_torque(drive: Drive, rpm: float) -> float:
    run_pv(drive, rpm, accel_ms=1)  # a step: the speed loop asks for all the torque it can
    peak = 0.0
    for _ in range(20):
        drive.advance(1 * MS)
        peak = max(peak, abs(drive.axis.torque))
    return peak / 10.0  # %


def test_trqlm_limits_torque_to_p1012_selected_by_tcm0() -> None:
    """TRQLM on + TCM0 (DI3, factory 0x0116) -> P1.012 % (L15101, L4044, L7993-8009)."""
    drive, _ = make(di5=0x09, **{"P1.012": -30})  # the sign does not matter (L8007)
    enable(drive, PV)
    press(drive, 3)  # TCM0
    press(drive, 5)  # TRQLM
    assert drive.difunc.torque_limit_pct == 30.0
    assert peak_torque(drive, 3000) == pytest.approx(30.0, abs=0.1)


def test_do_tql_while_the_torque_is_at_the_trqlm_limit() -> None:
    """DO.TQL "當扭矩限制中時" (L15278): on while accelerating against the 30 % limit, off at
    cruise (DO4 mapped to TQL, P2.021 = 0x0106)."""
    drive, _ = make(di5=0x09, **{"P1.012": 30, "P2.021": 0x0106})
    enable(drive, PV)
    press(drive, 3)
    press(drive, 5)
    assert not drive.do(4)
    run_pv(drive, 1000, accel_ms=1)
    drive.advance(5 * MS)
    assert drive.do(4)
    drive.advance(1 * 1000 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(1000, abs=1)
    assert not drive.do(4)


def test_without_trqlm_the_torque_is_not_limited() -> None:
    drive, _ = make(di5=0x09, **{"P1.012": 30})
    enable(drive, PV)
    press(drive, 3)
    assert peak_torque(drive, 3000) > 100.0


def test_p1002_y_limits_without_the_di_and_tcm1_picks_p1013() -> None:
    """P1.002.Y = 1 turns the limit on for good, OR with DI.TRQLM (L7845); TCM1 -> P1.013."""
    drive, _ = make(**{"P1.002": 0x0010, "P1.013": 45})
    enable(drive, PV)
    press(drive, 4)  # TCM1
    assert peak_torque(drive, 3000) == pytest.approx(45.0, abs=0.1)


def test_trqlm_analog_source_uses_t_ref_and_p1041() -> None:
    """TCM0 = TCM1 = 0: the analog T_REF x P1.041 / 10 V (L4042, L8466-8470)."""
    drive, _ = make(di5=0x09, options=ModelOptions(analog_t_ref=2.5))
    enable(drive, PV)
    press(drive, 5)
    assert peak_torque(drive, 3000) == pytest.approx(25.0, abs=0.1)


def test_trqlm_does_not_limit_the_torque_command_of_t_mode() -> None:
    """TRQLM modes PT, PR, S (L15101): in T the torque command is not limited by it."""
    drive, _ = make(di5=0x09, **{"P1.012": 30})
    enable(drive, PT)
    press(drive, 3)
    press(drive, 5)
    drive.write_object(0x6087, 0, 0)
    drive.write_object(0x6071, 0, 500)  # 50 %
    drive.advance(2 * MS)
    assert drive.axis.torque == pytest.approx(500, abs=1)


def test_spdlm_limits_speed_in_torque_mode_to_p1009() -> None:
    """SPDLM + SPD0 -> P1.009 (0.1 rpm) in T mode (L15121, L4036, L7931-7951)."""
    drive, _ = make(di5=0x10, di10=0x14, **{"P1.009": -5000})  # 500 rpm, sign irrelevant
    enable(drive, PT)
    press(drive, 10)  # SPD0
    press(drive, 5)  # SPDLM
    drive.write_object(0x6087, 0, 0)
    drive.write_object(0x6071, 0, 300)
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(500, abs=0.5)
    press(drive, 5, False)  # the limit goes: P1.055 (3000 rpm) again
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm > 1000


def test_spdlm_has_no_effect_in_speed_mode() -> None:
    """P1.002.X: "只在 T / Tz 模式有效" (L7831)."""
    drive, _ = make(di5=0x10, di10=0x14, **{"P1.009": 5000})
    enable(drive, PV)
    press(drive, 10)
    press(drive, 5)
    run_pv(drive, 1000)
    drive.advance(300 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(1000, abs=1)


# -- ZCLAMP ----------------------------------------------------------------------------------


def test_zclamp_holds_the_motor_while_the_speed_command_is_below_p1038() -> None:
    """L9904-9912: speed mode, DI.ZCLAMP on, ramped command < P1.038 (10 rpm): the position
    is locked where the clamp began."""
    drive, _ = make(di5=0x05)
    enable(drive, PV)
    press(drive, 5)
    start = drive.axis.position
    run_pv(drive, 5)  # below 10 rpm
    drive.advance(500 * MS)
    assert drive.axis.position == pytest.approx(start, abs=2)
    run_pv(drive, 100)  # above: the motor follows
    drive.advance(500 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(100, abs=0.5)
    run_pv(drive, 0)
    drive.advance(100 * MS)
    drive.advance(200 * MS)
    held = drive.axis.position
    drive.advance(200 * MS)
    assert drive.axis.position == pytest.approx(held, abs=1)
    assert abs(drive.axis.velocity_rpm) < 0.01


def test_without_zclamp_a_slow_command_turns_the_motor() -> None:
    drive, _ = make(di5=0x05)
    enable(drive, PV)
    run_pv(drive, 5)
    drive.advance(500 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(5, abs=0.1)


def test_zclamp_bit10_commands_zero_speed() -> None:
    """P2.065 bit 10 = 1, internal command: "馬達速度直接設為 0 rpm" (L9920)."""
    drive, _ = make(di5=0x05, **{"P2.065": 1 << 10})
    enable(drive, PV)
    press(drive, 5)
    assert drive.axis.zero_clamp == "zero"
    run_pv(drive, 5)
    drive.advance(300 * MS)
    assert abs(drive.axis.velocity_rpm) < 0.01


def test_zclamp_is_a_speed_mode_function() -> None:
    """ZCLAMP mode column: S (L15091); in PT (profile torque, T) it does nothing."""
    drive, _ = make(di5=0x05)
    enable(drive, PT)
    press(drive, 5)
    assert drive.axis.zero_clamp == ""


# -- CCLR ------------------------------------------------------------------------------------


def test_cclr_rising_edge_clears_the_position_error() -> None:
    """P2.050 = 0: rising edge; the accumulated error becomes 0 (L9749-9751)."""
    drive, _ = make(di5=0x04)
    enable(drive, PP)
    drive.write_object(0x607A, 0, 2_000_000)  # 20 rev
    drive.write_object(0x6081, 0, 1_000_000)
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(100 * MS)
    assert abs(drive.axis.following_error) > 100
    press(drive, 5)
    assert drive.axis.following_error == pytest.approx(0, abs=1)
    drive.advance(300 * MS)
    assert drive.axis.velocity == 0.0  # the pending command was dropped


def test_cclr_level_keeps_the_error_cleared_while_on() -> None:
    """P2.050 = 1: level-triggered (L9753): while on no position command turns the motor."""
    drive, _ = make(di5=0x04, **{"P2.050": 1})
    enable(drive, PP)
    press(drive, 5)
    start = drive.axis.position
    drive.write_object(0x607A, 0, 500_000)
    drive.write_object(0x6081, 0, 1_000_000)
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(200 * MS)
    assert drive.axis.position == start
    press(drive, 5, False)  # a new set-point starts: the dropped one does not block it
    drive.write_object(0x6040, 0, 0x0F)
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(1 * S)
    assert drive.axis.position != start


def test_cclr_does_nothing_in_speed_mode() -> None:
    """CCLR modes: PT, PR (L15088)."""
    drive, _ = make(di5=0x04)
    enable(drive, PV)
    run_pv(drive, 300)
    drive.advance(200 * MS)
    press(drive, 5)
    drive.advance(10 * MS)
    assert drive.axis.velocity_rpm == pytest.approx(300, abs=1)


# -- GAINUP ----------------------------------------------------------------------------------


@pytest.mark.parametrize(("p2027", "di_on", "switched"),
                         [(0x01, True, True), (0x01, False, False), (0x05, False, True),
                          (0x05, True, False), (0x00, True, False)])
def test_gainup_switches_by_p2027_x(p2027: int, di_on: bool, switched: bool) -> None:
    """P2.027.X = 1: switched while GAINUP is on; 5: while it is off; 0: never (L9435-9447);
    Y = 0: position gain x P2.001 (L9454-9460). The state shows in the snapshot."""
    drive, _ = make(di5=0x03, **{"P2.027": p2027, "P2.001": 200, "P2.005": 150})
    enable(drive, PP)
    base = drive.axis.base_kpp
    if di_on:
        press(drive, 5)
    assert drive.snapshot()["gain_switched"] is switched
    assert drive.axis.kpp == pytest.approx(base * (2.0 if switched else 1.0))


def cruise_following_error(drive: Drive) -> float:
    """Following error 500 ms into a 300 rpm PP move (constant speed after 100 ms): signed,
    demand minus feedback."""
    drive.write_object(0x607A, 0, 500_000)  # 5 rev
    drive.write_object(0x6081, 0, 500_000)  # 5 rev/s = 300 rpm
    drive.write_object(0x6083, 0, 1000)
    drive.write_object(0x6084, 0, 1000)
    drive.write_object(0x6040, 0, 0x1F)
    drive.advance(500 * MS)
    return drive.axis.following_error


def test_gainup_position_loop_runs_with_p2001_times_the_gain() -> None:
    """GAINUP with P2.001 = 300 %: the position gain is tripled (L15085, L9454-9460). At
    cruise the axis' loop gives Kpp x e = (1 - feed-forward) x v (the error sampled at the
    start of each 1 ms cycle: the feedback follows the command causally)."""
    errors = []
    for di_on in (False, True):
        drive, _ = make(di5=0x03, **{"P2.027": 0x01, "P2.001": 300})
        enable(drive, PP)
        if di_on:
            press(drive, 5)
        errors.append(cruise_following_error(drive))
    v = 300 / 60 * 16777216  # counts/s
    kpp = [0.05 * v / e for e in errors]
    assert kpp[0] == pytest.approx(100.0, rel=1e-3)
    assert kpp[1] == pytest.approx(300.0, rel=1e-3)


def test_gainup_integrator_switch_is_recorded_only() -> None:
    """P2.027.Y = 1 switches P2.006/P2.026 on (L9456, L9461-9462): the axis has no integrator."""
    drive, _ = make(di5=0x03, **{"P2.027": 0x11, "P2.001": 200})
    enable(drive, PP)
    press(drive, 5)
    assert drive.difunc.gain_switched
    assert drive.axis.kpp == drive.axis.base_kpp


def test_gainup_not_in_torque_mode() -> None:
    """GAINUP modes: PT, PR, S (L15085)."""
    drive, _ = make(di5=0x03, **{"P2.027": 0x01})
    enable(drive, PT)
    press(drive, 5)
    assert not drive.difunc.gain_switched
