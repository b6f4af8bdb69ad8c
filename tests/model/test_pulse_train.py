"""PT mode of the virtual A3 (issue 26), each rule written from the manual, on the injected clock.

P1.000 input form / logic / filter L7660-7745; line driver 4 Mpps, open collector 200 kpps
L7700-7707; AL008 L19535-19538 and P2.065 bit 6 L9892; e-gear §6.2.5 L3578-3598, P1.044
L8518, P1.045 L8534-8547 (1/4 < Nx/M < 262144), GNUM0/GNUM1 with P2.060-P2.062 L9843-9850;
INHP only on DI8 L3550, L15244; P2.065 bit 11 L9926-9930; CCLR P2.050 L9742-9753; P1.068
L8832; P1.008 L7921; AL009 by P2.035 L9549-9556; TPOS by P1.054 L8685-8693; P1.046 OA/OB
L8556-8571 and AL018; OCZ C11 L1851; PT-PR L15200.
"""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import OutOfRange
from hil.model.mechanics import COUNTS_PER_REV
from hil.model.options import ModelOptions
from hil.model.pulse_train import filter_max_hz
from hil.units import MS, S

BENCH = {"P2.041": 0x0108}  # BRKR on DO6; SON is DI1 (factory P2.010), EMGS DI8 b-contact


def make(options: ModelOptions | None = None, **params: int) -> Drive:
    """Servo on in PT mode (P1.001 = 0, the A3-M default, L7749) by DI.SON."""
    d = Drive(options=options, inputs={8: True}, params=BENCH | params)
    d.set_di(1, True)
    d.advance(10 * MS)
    assert d.servo_on and d.difunc.control_mode() == "PT"
    return d


def run(d: Drive, freq: float, count: int, direction: int = 1, settle_ms: int = 300,
        **kw: object) -> None:
    d.pulse.segment(freq, direction, count, **kw)
    d.advance(int(count / freq * S) + settle_ms * MS)


# -- electronic gear ---------------------------------------------------------------------------


def test_gear_one_revolution_is_p1045_pulses_with_p1044_16777216() -> None:
    # 24-bit resolution, 16777216 pulses per revolution at gear 1 (L3578-3580)
    d = make(**{"P1.044": 16777216, "P1.045": 3000})
    run(d, 30_000, 3000)
    assert d.axis.position == pytest.approx(COUNTS_PER_REV, abs=1)
    assert d.snapshot()["pt_count"] == 3000


def test_gear_half_means_two_command_pulses_per_motor_pulse() -> None:
    # "電子齒輪比等於 0.5，則命令端每二個脈波所對應到馬達轉動脈波為 1 個脈波" (L3580)
    d = make(**{"P1.045": 2, "P1.044": 1})
    run(d, 10_000, 1000)
    assert d.axis.position == pytest.approx(500, abs=1)


def test_the_gear_remainder_is_carried_from_move_to_move_and_counted_exactly() -> None:
    # counts = pulses x N1/M (L3578-3598): with 16777216/10000 a pulse is 1677.7216 counts.
    # Twenty one-pulse moves are 33554.432 counts, of which 33554 whole; each move counted
    # afresh gave 20 x 1677 = 33540. And +10000 / -10000 pulses (one turn each way) return to
    # exactly where they began: a float sum of 50-pulse slices fell one count short a move
    d = make(**{"P1.044": 16777216, "P1.045": 10000})
    for _ in range(20):
        run(d, 1000, 1, settle_ms=50)
    assert d.pulse.command == 33554 and d.axis.position == 33554
    start = d.axis.position
    for i in range(7):
        run(d, 50_000, 10_000, direction=-1 if i % 2 else 1, settle_ms=50)
        assert d.pulse.command - start == (0 if i % 2 else COUNTS_PER_REV), i
    d.advance(500 * MS)  # the axis settles on the command
    assert d.axis.position - start == COUNTS_PER_REV


def test_servo_off_drops_the_gear_remainder_also_after_the_train_settled() -> None:
    # servo off: the command follows the feedback (L9749), and the remainder of a count the
    # gear carried goes with it, whether or not the last train had settled (a review: it
    # was kept when the train had, so the next train began 0.7216 counts on)
    d = make(**{"P1.044": 16777216, "P1.045": 10000})
    run(d, 1000, 1, settle_ms=50)  # 1677.7216 counts: 1677 whole, 0.7216 carried
    d.set_di(1, False)
    d.advance(200 * MS)
    d.set_di(1, True)
    d.advance(200 * MS)
    start = d.pulse.command
    run(d, 1000, 1, settle_ms=50)
    assert d.pulse.command - start == pytest.approx(1677, abs=1e-6)  # not 1678: not carried


@pytest.mark.parametrize("n, m, ok", [(1, 4, False), (1, 3, True), (2**24, 64, False),
                                       (2**24, 65, True)])
def test_gear_ratio_range_is_quarter_to_262144(n: int, m: int, ok: bool) -> None:
    # 1/4 < Nx/M < 262144 (L8547): a write leaving the range is refused (option "refuse")
    d = Drive(inputs={8: True}, params=BENCH | {"P1.045": 3, "P1.044": n})
    if ok:
        d.params.write("P1.045", m)
    else:
        with pytest.raises(OutOfRange, match="L8547"):
            d.params.write("P1.045", m)


def test_gear_ratio_check_off_accepts_the_write() -> None:
    d = Drive(options=ModelOptions(pt_gear_check="off"), inputs={8: True}, params=BENCH)
    d.params.write("P1.044", 1)
    assert d.params.get("P1.044") == 1


def test_gnum_selects_the_numerator() -> None:
    # GNUM0/GNUM1 select N1..N4 = P1.044, P2.060, P2.061, P2.062 (L9850, L15239)
    d = make(**{"P2.014": 0x0143, "P1.044": 16777216, "P1.045": 10000, "P2.060": 8388608})
    d.set_di(5, True)  # GNUM0 on -> N2 = P2.060 (half of N1)
    d.advance(5 * MS)
    run(d, 10_000, 10000)
    assert d.axis.position == pytest.approx(COUNTS_PER_REV / 2, abs=1)


# -- input form, logic, limits -------------------------------------------------------------------


def test_ab_phase_counts_four_per_period() -> None:
    # P1.000.X = 0: A/B phase pulse train (4x) (L7670)
    d = make(**{"P1.000": 0x1040, "P1.044": 16777216, "P1.045": 4000})
    run(d, 10_000, 1000, form="ab")
    assert d.axis.position == pytest.approx(COUNTS_PER_REV, abs=1)


def test_a_form_other_than_p1000_x_is_not_decoded() -> None:
    d = make()  # default P1.000 = 0x1042: pulse + sign (L7663)
    run(d, 10_000, 1000, form="cw_ccw")
    assert d.axis.position == pytest.approx(0, abs=1)
    assert d.pulse.lost_format == 1000


def test_pulse_sign_with_the_other_logic_runs_the_other_way() -> None:
    # P1.000.Z = 1 negative logic (L7674-7680): the sign level reads inverted
    d = make(**{"P1.000": 0x1142})
    run(d, 10_000, 1000, logic=0)
    assert d.axis.position < 0
    d2 = make(**{"P1.000": 0x1142})
    run(d2, 10_000, 1000, logic=1)
    assert d2.axis.position > 0


def test_filter_table_frequencies() -> None:
    # the table's kHz column (L7716-7733): U = 1, Y = 4 -> 0.5 us, 1000 kHz; U = 0, Y = 1
    # -> 2 us, 250 kHz; Y = 0 no filter
    assert filter_max_hz(0x1042) == pytest.approx(1_000_000)
    assert filter_max_hz(0x0012) == pytest.approx(250_000)
    assert filter_max_hz(0x1002) is None


def test_pulses_above_the_filter_are_lost_below_are_counted() -> None:
    d = make(**{"P1.000": 0x0012})  # 2 us filter: pulses faster than 250 kHz are noise
    run(d, 300_000, 3000)
    assert d.pulse.accepted == 0 and d.pulse.lost_limit == 3000
    run(d, 200_000, 2000)
    assert d.pulse.accepted == 2000


def test_al008_above_the_line_driver_rating_unless_p2065_bit6() -> None:
    # 4 Mpps line driver (L7705); AL008 "pulse command frequency above the rated input"
    # (L19535-19538); P2.065 bit 6 = 1 turns the protection off (L9892)
    d = make(**{"P1.000": 0x0002})
    d.pulse.segment(4_000_000, 1, 4000)
    d.advance(2 * MS)
    assert "AL008" not in d.alarms.active
    d.pulse.segment(4_100_000, 1, 4100)
    d.advance(2 * MS)
    assert "AL008" in d.alarms.active
    d2 = make(**{"P1.000": 0x0002, "P2.065": 0x0040})
    d2.pulse.segment(4_100_000, 1, 4100)
    d2.advance(2 * MS)
    assert "AL008" not in d2.alarms.active


def test_open_collector_is_rated_200_kpps() -> None:
    # open collector 200 Kpps (L7706, L2030)
    d = make(ModelOptions(pulse_interface="open_collector"), **{"P1.000": 0x0002})
    d.pulse.segment(250_000, 1, 250)
    d.advance(2 * MS)
    assert "AL008" in d.alarms.active


def test_no_pulse_counted_while_servo_off() -> None:
    d = Drive(inputs={8: True}, params=BENCH)
    d.advance(10 * MS)
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 0 and d.pulse.lost_off == 1000
    assert d.axis.position == 0


# -- INHP, limits, CCLR ------------------------------------------------------------------------


def test_inhp_on_di8_stops_accepting_pulses() -> None:
    d = make(**{"P2.017": 0x0145})  # DI8 = INHP (L3550: "needs P2.017 = 0x45")
    d.set_di(8, True)
    d.advance(5 * MS)
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 0 and d.pulse.lost_inhibit == 1000
    d.set_di(8, False)
    d.advance(5 * MS)
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 1000


def test_inhp_on_another_di_has_no_effect() -> None:
    # "DI.INHP 僅在 DI 8 支援此功能" (L3550)
    d = make(**{"P2.014": 0x0145})  # DI5 = INHP
    d.set_di(5, True)
    d.advance(5 * MS)
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 1000


def test_p2065_bit11_blocks_only_pulses_towards_the_active_limit() -> None:
    # bit 11 = 1: at the positive limit no forward pulse, reverse pulses accepted (L9926-9930)
    d = make(**{"P2.065": 0x0800, "P2.014": 0x0123})  # DI5 = PL, a contact (L15190)
    d.set_di(5, True)
    d.advance(5 * MS)
    run(d, 10_000, 500)
    assert d.pulse.accepted == 0
    run(d, 10_000, 500, direction=-1)
    assert d.pulse.accepted == -500


def test_cclr_level_keeps_the_error_cleared_so_pulses_do_not_move() -> None:
    # P2.050 = 1: level; while CCLR is on the accumulated error is 0 (L9749-9753)
    d = make(**{"P2.050": 1})  # DI2 = CCLR (factory P2.011 = 0x0104)
    d.set_di(2, True)
    d.advance(5 * MS)
    run(d, 10_000, 1000)
    assert abs(d.axis.position) < 50
    d.set_di(2, False)
    d.advance(5 * MS)
    run(d, 10_000, 1000, **{})
    assert d.axis.position == pytest.approx(1000 * 16777216 / 100000, abs=2)


def test_cclr_edge_drops_the_error_accumulated_so_far() -> None:
    # P2.050 = 0: rising edge clears the error once (L9751)
    d = make(**{"P1.055": 60})  # the motor may run 60 rpm: 1 rev/s
    d.pulse.segment(200_000, 1, 200_000)  # asks for 2 rev/s for 1 s
    d.advance(500 * MS)
    lag = d.pulse.error()
    assert lag > COUNTS_PER_REV / 4
    d.set_di(2, True)
    d.advance(5 * MS)
    assert abs(d.pulse.error()) < lag / 10
    d.advance(2 * S)
    assert d.axis.position < 2 * COUNTS_PER_REV - lag / 2  # what was cleared never moves


# -- smoothing, AL009, TPOS --------------------------------------------------------------------


def test_p1068_moving_filter_spreads_a_step_over_its_window() -> None:
    # P1.068 = 20 ms: a command step becomes a 20 ms ramp (moving average, L8832)
    d = make(**{"P1.068": 20, "P1.044": 16777216, "P1.045": 1000})
    d.pulse.segment(1_000_000, 1, 100)  # 100 pulses in 0.1 ms: a step of 0.1 rev
    d.advance(11 * MS)
    mid = d.axis.demand
    d.advance(30 * MS)
    assert 0.3 * COUNTS_PER_REV / 10 < mid < 0.7 * COUNTS_PER_REV / 10
    assert d.axis.demand == pytest.approx(COUNTS_PER_REV / 10, abs=2)


def test_p1008_low_pass_has_its_time_constant() -> None:
    # P1.008 unit 10 ms (L7921-7925): 10 -> 100 ms; after one time constant 63 %
    d = make(**{"P1.008": 10, "P1.068": 0, "P1.044": 16777216, "P1.045": 1000})
    d.pulse.segment(1_000_000, 1, 100)
    d.advance(101 * MS)
    assert d.axis.demand == pytest.approx(0.632 * COUNTS_PER_REV / 10, rel=0.03)


def test_al009_when_pulses_outrun_the_axis_beyond_p2035() -> None:
    d = make(**{"P1.055": 60, "P2.035": COUNTS_PER_REV // 2})
    d.pulse.segment(400_000, 1, 0)  # 4 rev/s demanded, 1 rev/s allowed
    d.advance(2 * S)
    assert "AL009" in d.alarms.active  # L9556


def test_tpos_in_pt_is_the_pulse_error_inside_p1054() -> None:
    d = make(**{"P1.054": 1000, "P1.044": 16777216, "P1.045": 10000})
    d.pulse.segment(50_000, 1, 50_000)
    d.advance(100 * MS)
    assert abs(d.pulse.error()) > 1000 and not d.do(4)  # TPOS on DO4 (factory)
    d.advance(2 * S)
    assert abs(d.pulse.error()) < 1000 and d.do(4)


# -- encoder output ----------------------------------------------------------------------------


def test_oa_ob_give_four_p1046_counts_per_rev_and_oz_one_per_rev() -> None:
    d = make(**{"P1.046": 2500, "P1.044": 16777216, "P1.045": 10000})
    seen: list[tuple[str, dict]] = []
    d.pulse.listeners.append(lambda k, data: seen.append((k, data)))
    run(d, 20_000, 30_000)  # 3 revolutions
    oab = sum(x["direction"] * x["count"] for k, x in seen if k == "OAB")
    assert oab == pytest.approx(3 * 4 * 2500, abs=2)
    assert 3 <= sum(1 for k, _ in seen if k == "OZ") <= 4  # marks at 1, 2, 3 rev (+0 jitter)


def test_al018_when_the_output_frequency_passes_19_8_mhz() -> None:
    # rpm / 60 x P1.046 x 4 > 19.8 MHz -> AL018 (L8569); P2.065 bit 13 turns it off (L9940)
    d = make(**{"P1.046": 200_000, "P1.044": 16777216, "P1.045": 1000})
    d.pulse.segment(30_000, 1, 0)  # 30 rev/s: 30 x 800000 = 24 MHz
    d.advance(S)
    assert "AL018" in d.alarms.active
    d2 = make(**{"P1.046": 200_000, "P1.044": 16777216, "P1.045": 1000, "P2.065": 0x2000})
    d2.pulse.segment(30_000, 1, 0)
    d2.advance(S)
    assert "AL018" not in d2.alarms.active


# -- monitors ---------------------------------------------------------------------------------


def test_monitor_registers_show_the_pt_codes() -> None:
    # P0.009-P0.013 show the code P0.017-P0.021 selects (L7147-7237): 001 in PT = pulses
    # received, 004 the command after the gear (pulse), 006 the pulse frequency in kpps
    # (L15440-15446)
    d = make(**{"P0.017": 1, "P0.018": 4, "P0.019": 6, "P0.020": 3, "P1.045": 10000})
    d.pulse.segment(50_000, 1, 0)
    d.advance(100 * MS)
    received = d.params.read("P0.009")
    assert received == pytest.approx(5000, abs=50)
    assert d.params.read("P0.010") == pytest.approx(received * COUNTS_PER_REV / 10000, rel=0.01)
    assert d.params.read("P0.011") == 50  # kpps
    assert 0 < d.params.read("P0.012") <= d.params.read("P0.010")  # feedback behind


# -- cruise -------------------------------------------------------------------------------------


def _trace(monkeypatch: pytest.MonkeyPatch, cruise: bool) -> tuple[list[float], int]:
    from hil.model import pulse_train
    monkeypatch.setattr(pulse_train, "CRUISE_NS", 200 * MS if cruise else 0)
    d = make(**{"P2.017": 0x0045, "P1.045": 10000})  # DI8 = INHP, b contact (closed: off)
    out = []
    cruising = 0
    d.pulse.segment(37_000, 1, 30_000)
    for k in range(900):
        if k == 300:
            d.set_di(8, False)  # INHP on for 200 ms (b contact opened)
        if k == 500:
            d.set_di(8, True)
        if k == 600:
            d.pulse.segment(11_000, -1, 0)
        d.advance(MS)
        out.append(d.axis.position)
        cruising += bool(d.pulse._cruise_end)
    out.append(d.snapshot()["pt_count"])  # live: a cruise takes its pulses at its end
    return out, cruising


def test_cruise_follows_the_per_step_path_within_a_pulse(monkeypatch) -> None:
    exact, none = _trace(monkeypatch, cruise=False)
    fast, cruising = _trace(monkeypatch, cruise=True)
    assert none == 0 and cruising > 500  # the fast run did cruise, most of the time
    assert fast[-1] == exact[-1]  # the same pulses counted
    per_pulse = COUNTS_PER_REV / 10000
    assert max(abs(a - b) for a, b in zip(fast[:-1], exact[:-1], strict=True)) < per_pulse


def test_p1001_mode_change_acts_after_a_power_cycle() -> None:
    # servo off, set P1.001, power cycle (L3495-3497; P1.001 "●", L7749)
    d = make()
    d.set_di(1, False)
    d.advance(10 * MS)
    d.params.write("P1.001", 0x0001)  # PR
    run(d, 10_000, 100)
    assert d.pulse.lost_off == 100  # servo off: nothing taken
    d.set_di(1, True)
    d.advance(10 * MS)
    run(d, 10_000, 100)
    assert d.pulse.accepted == 100  # still PT until the power cycle
    d.power_cycle()
    d.advance(10 * MS)
    assert d.difunc.control_mode() == "PR"
    run(d, 10_000, 100)
    assert d.pulse.accepted == 0 and d.pulse.lost_off == 100  # PR takes no pulses


# -- PT-PR, line reconciliation ----------------------------------------------------------------


def test_pt_pr_selects_the_command_source() -> None:
    # P1.001 = 0x0D: DI.PT-PR off -> PT, on -> PR (L15200)
    d = make(**{"P1.001": 0x000D, "P2.014": 0x012B})
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 1000
    d.set_di(5, True)
    d.advance(5 * MS)
    assert d.difunc.control_mode() == "PR"
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 1000 and d.pulse.lost_off == 1000


def test_a_late_segment_is_reconciled_with_the_masters_total() -> None:
    # a network delivered the stop 7 pulses late: the drive counted 7 too many
    d = make()
    d.pulse.segment(10_000, 1, 0, total=0)
    d.advance(100 * MS + MS // 10 * 7)  # 1007 pulses counted
    d.pulse.segment(0, 1, 0, total=1000)  # the master had output 1000
    assert d.pulse.accepted == 1000 and d.pulse.line_total == 1000


def test_malformed_segments_are_refused() -> None:
    d = make()
    for args in ((-1.0, 1, 0), (float("nan"), 1, 0), (1.0, 0, 0), (1.0, 1, -5)):
        with pytest.raises(ValueError):
            d.pulse.segment(*args)
    with pytest.raises(ValueError):
        d.pulse.segment(1.0, 1, 0, form="zigzag")
    assert d.pulse.accepted == 0


# -- found by a review against the manual (wave 3, session 9) ----------------------------------
GEAR_10K = {"P1.044": 16777216, "P1.045": 10000}  # 10 000 pulses a revolution


@pytest.mark.parametrize("when", ["servo_cycle", "train_before_son", "pt_pr_to_pt"])
def test_a_train_already_running_drives_the_motor_once_servo_on_in_pt(when: str) -> None:
    # Servo on in PT: the pulses received drive the motor (L3503, L3510) whether the train
    # began before, during or after the servo came on or PT was selected (PT-PR, L15200).
    d = make(**GEAR_10K, **({"P1.001": 0x000D, "P2.014": 0x012B} if when == "pt_pr_to_pt"
                            else {}))
    if when == "servo_cycle":
        d.pulse.segment(10_000, 1, 0)  # 1 rev/s
        d.advance(200 * MS)
        d.set_di(1, False)
    elif when == "train_before_son":
        d.set_di(1, False)
        d.advance(20 * MS)
        d.pulse.segment(10_000, 1, 0)
    else:
        d.set_di(5, True)  # PR
        d.advance(5 * MS)
        d.pulse.segment(10_000, 1, 0)
    d.advance(100 * MS)
    accepted, start = d.pulse.accepted, d.axis.position
    if when == "pt_pr_to_pt":
        d.set_di(5, False)
    else:
        d.set_di(1, True)
    d.advance(20 * MS)
    assert d.servo_on and d.difunc.control_mode() == "PT"
    d.pulse.stop()
    took = d.pulse.accepted - accepted
    assert took >= 150  # 10 kpps for about 20 ms
    d.advance(500 * MS)
    moved = d.axis.position - start
    assert moved == pytest.approx(took * COUNTS_PER_REV / 10_000, abs=COUNTS_PER_REV / 10_000)
    assert abs(d.pulse.error()) < COUNTS_PER_REV / 10_000 and d.do(4)  # TPOS (L8692)


def test_the_command_follows_a_coasting_motor_while_servo_off() -> None:
    d = make(**GEAR_10K)
    d.pulse.segment(10_000, 1, 0)
    d.advance(200 * MS)
    d.set_di(1, False)  # the motor coasts on after the servo goes off
    for _ in range(5):
        d.advance(20 * MS)
        assert d.snapshot()["pt_error"] == 0


def test_pl_with_p2065_bit11_off_takes_the_pulses_but_the_motor_does_not_run_into_it() -> None:
    # PL forbids running forward in every mode (L15186-15191); with P2.065 bit 11 = 0 the
    # pulses still enter the drive (L9928), so the error grows; reverse pulses run it back.
    d = make(**GEAR_10K, **{"P2.065": 0, "P2.014": 0x0123})  # DI5 = PL, a contact
    d.pulse.segment(10_000, 1, 0)
    d.advance(100 * MS)
    d.set_di(5, True)
    d.advance(100 * MS)  # the P5.003 ramp stop ends
    at_limit, accepted = d.axis.position, d.pulse.accepted
    d.advance(300 * MS)
    assert d.axis.position == pytest.approx(at_limit, abs=1)
    assert d.pulse.accepted - accepted >= 2900 and d.pulse.lost_inhibit == 0
    assert d.pulse.error() > 2900 * COUNTS_PER_REV / 10_000 and not d.do(4)
    assert "AL015" in d.alarms.active
    d.pulse.segment(10_000, -1, 0)  # reverse: once the command is behind the motor again,
    d.advance(500 * MS)  # the motor runs back, away from the limit
    assert d.axis.velocity < 0 and d.axis.position < at_limit - 500 * COUNTS_PER_REV / 10_000


def test_pulses_are_refused_while_al06a_with_p2069_y_0() -> None:
    # P2.069.Y = 0: with AL060 or AL06A active, no pulse command is accepted (L10027-10029)
    d = Drive(inputs={8: True}, params=BENCH | {"P2.069": 0x0001})  # absolute, no origin
    d.set_di(1, True)
    d.advance(20 * MS)
    assert "AL06A" in d.alarms.active and d.servo_on  # a warning (L19795)
    run(d, 10_000, 1000)
    assert d.pulse.accepted == 0 and d.pulse.lost_alarm == 1000 and d.axis.position == 0


def test_p5018_and_monitor_049_count_the_cn1_pulses_in_any_state() -> None:
    # P5.018: the pulse command count (L11298-11305); monitor 049: CN1 pulse count (L15483)
    d = make(**{"P0.017": 49})
    run(d, 10_000, 1234)
    assert d.params.read("P5.018") == 1234 and d.params.read("P0.009") == 1234
    d.set_di(1, False)
    d.advance(10 * MS)
    run(d, 10_000, 100, direction=-1)  # servo off: not a command, still counted at CN1
    assert d.pulse.accepted == 1234 and d.params.read("P5.018") == 1134
    d.params.write("P5.018", 0)  # a write presets the counter
    run(d, 10_000, 10)
    assert d.params.read("P5.018") == 10 and d.params.read("P0.009") == 10


def test_monitor_006_reads_zero_once_a_counted_segment_has_ended() -> None:
    # monitor 006: the pulse command frequency received now, kpps (L15446)
    d = make(**{"P0.017": 6})
    d.pulse.segment(10_000, 1, 50)
    d.advance(2 * MS)
    assert d.params.read("P0.009") == 10
    d.advance(100 * MS)
    assert d.params.read("P0.009") == 0 and d.snapshot()["pt_freq_kpps"] == 0


@pytest.mark.parametrize("p1097, p1003, per_rev", [(0, 0, 10_000), (7, 0, 2500 / 7),
                                                    (0, 0x10, -10_000)])
def test_oa_ob_counts_per_revolution_with_p1097_and_p1003(p1097: int, p1003: int,
                                                          per_rev: float) -> None:
    # P1.097 = 0: 4 x P1.046 (example 1, L9065-9069); P1.097 = 7, P1.046 = 2500: 2500 per
    # seven turns, no x4 (example 2, L9071-9081); P1.003.Y = 1 reverses the output (L7869)
    d = make(**GEAR_10K, **{"P1.046": 2500, "P1.097": p1097, "P1.003": p1003})
    seen: list[dict] = []
    d.pulse.listeners.append(lambda k, data: seen.append(data) if k == "OAB" else None)
    run(d, 10_000, 10_000)  # one revolution
    one = sum(x["direction"] * x["count"] for x in seen)
    assert one == int(per_rev)
    run(d, 10_000, 60_000)  # six more
    assert sum(x["direction"] * x["count"] for x in seen) == round(7 * per_rev)


def test_oa_ob_output_nothing_net_for_a_motor_back_where_it_started() -> None:
    d = make(**GEAR_10K, **{"P1.046": 2500, "P1.008": 5})  # a low-pass: the motor overshoots
    seen: list[dict] = []
    d.pulse.listeners.append(lambda k, data: seen.append(data) if k == "OAB" else None)
    for direction in (1, -1, 1, -1):
        run(d, 7_000, 3_333, direction=direction)
    assert sum(x["direction"] * x["count"] for x in seen) == 0


def test_a_p1045_write_checks_every_numerator_gnum_can_select() -> None:
    # 1/4 < Nx/M < 262144 for N1-N4 (L8547); N2-N4 are chosen by GNUM0/GNUM1 (L9850)
    wired = Drive(inputs={8: True}, params=BENCH | {"P2.060": 30_000, "P2.013": 0x0143})
    with pytest.raises(OutOfRange, match="30000/200000"):
        wired.params.write("P1.045", 200_000)  # N2 / M = 0.15
    alone = Drive(inputs={8: True}, params=BENCH | {"P2.060": 30_000})
    alone.params.write("P1.045", 200_000)  # no GNUM input: Nx is P1.044 (L9850)


@pytest.mark.parametrize("p2009", [0, 2, 10])
def test_inhp_on_di8_inhibits_at_the_terminal_edge_whatever_p2009(p2009: int) -> None:
    # "DI.INHP 僅在 DI 8 支援此功能，以確保即時的脈波禁止" (L15244): not through the filter
    d = make(**{"P2.017": 0x0145, "P2.009": p2009})  # DI8 = INHP, a contact
    d.set_di(8, False)
    d.advance(20 * MS)
    d.pulse.segment(1_000_000, 1, 0)  # 1 MHz
    d.advance(10 * MS + 123_456)  # off the 1 ms grid
    sent = d.pulse.seg.pulses_at(d.now)
    d.set_di(8, True)
    d.advance(50 * MS)
    assert d.pulse.accepted == sent
    d.set_di(8, False)
    resumed = d.pulse.seg.pulses_at(d.now)
    d.advance(3 * MS + 500_000)
    d.pulse.stop()
    assert d.pulse.accepted == sent + d.pulse.line_total - resumed


@pytest.mark.parametrize("at_ms", [150, 1000, 1100])
def test_a_cclr_edge_clears_the_error_but_every_pulse_is_counted(at_ms: int) -> None:
    """CCLR clears the accumulated position error (L15088, P2.050 L9742-9753), not the pulses
    received: P5.018 and monitor 049 are the CN1 pulse count (L11298-11305, L15483) and
    monitor 001 the pulses received in PT (L15441). A CCLR edge during a steady train had
    lost 660-1720 pulses from all three (helper-100)."""
    d = make(**{"P1.044": 1, "P1.045": 1, "P2.050": 0})
    d.pulse.segment(10_000, 1, 0)  # continuous, 10 kHz
    d.advance(at_ms * MS)
    d.set_di(2, True)  # CCLR (factory DI2, P2.011 = 0x0104)
    d.advance(10 * MS)
    d.set_di(2, False)
    d.advance(500 * MS)
    line = d.pulse.seg.pulses_at(d.now)
    d.params.write("P0.017", 49)
    mon049 = d.params.get("P0.009")
    d.params.write("P0.017", 1)
    mon001 = d.params.get("P0.009")
    assert d.params.get("P5.018") == mon049 == mon001 == line
