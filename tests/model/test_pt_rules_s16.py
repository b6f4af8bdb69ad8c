"""PT mode rules written fresh from the manual by an outside review (wave 3, session 16,
helper-60); each test failed before its fix. The drive runs on its injected clock."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.errors import ModelError
from hil.units import MS, S

BENCH = {"P2.041": 0x0108}
G1 = 16777216 / 100000  # command counts per pulse at P1.044 / P1.045 = 1 / 100000 x 2^24


def _pt(**params) -> Drive:
    d = Drive(inputs={8: True}, params=BENCH | params)
    d.set_di(1, True)  # SON
    d.advance(10 * MS)
    assert d.servo_on, d.alarms.active
    return d


@pytest.mark.parametrize("cruise", [True, False])
@pytest.mark.parametrize("how", ["gnum", "write"])
def test_a_gear_change_acts_on_the_pulses_after_it(monkeypatch, cruise, how):
    """GNUM0 selects P2.060 (L9843-9850) and P2.060 may be written with the servo on (no
    ▲): pulses received before the change keep the numerator they came at. A constant train
    is handed to the axis as one "cruise" of up to 200 ms; it had rescaled every pulse since
    the cruise began (1940 instead of about 1480 gear-1 pulses)."""
    if not cruise:
        from hil.model import pulse_train

        monkeypatch.setattr(pulse_train.PulseTrain, "_maybe_cruise", lambda self, pt: None)
    d = _pt(**{"P2.014": 0x0143, "P1.045": 100000, "P2.060": 2 * 16777216})  # DI5 = GNUM0
    if how == "write":
        d.set_di(5, True)  # P2.060 (x2) in force
        d.advance(10 * MS)
    d.pulse.segment(10_000, 1, 1000)  # 1000 pulses at 10 kHz: 100 ms
    d.advance(int(50.5 * MS))
    if how == "write":
        d.params.write("P2.060", 4 * 16777216)
    else:
        d.set_di(5, True)  # GNUM0 on after the 2 ms P2.009 filter
    d.advance(1 * S)
    got = d.pulse.command / G1
    # 505 pulses at the old numerator, 495 at the new one (GNUM0 acts 2 ms later: 525/475)
    want = 505 * 2 + 495 * 4 if how == "write" else 525 * 1 + 475 * 2
    assert abs(got - want) <= 20, (got, want)


def test_al008_is_a_condition_an_over_rate_train_raises_it_again_after_a_reset():
    """AL008 "脈波命令之輸入頻率超過硬體介面容許值" (L19535-19538): after ARST with the 5 MHz
    train still on the line the servo had come back on and the pulses dropped silently."""
    d = _pt(**{"P1.000": 0x0002})
    d.pulse.segment(5_000_000, 1, 0)
    d.advance(5 * MS)
    assert "AL008" in d.alarms.active
    d.alarms.reset("di")
    d.advance(50 * MS)
    assert "AL008" in d.alarms.active and not d.servo_on
    d.pulse.stop()
    d.advance(5 * MS)
    d.alarms.reset("di")
    d.advance(10 * MS)
    assert not d.alarms.active and d.servo_on


def test_al008_when_the_mode_gains_its_pt_side_with_the_train_running():
    """PT-PR (P1.001 = 0x0D): a 5 MHz train started on the PR side raises AL008 once PT is
    selected; its pulses had been dropped without an alarm."""
    d = Drive(inputs={8: True}, params=BENCH | {"P1.000": 0x0002, "P1.001": 0x0D,
                                                "P2.014": 0x012B})  # DI5 = PT-PR
    d.set_di(1, True)
    d.set_di(5, True)
    d.advance(10 * MS)
    assert d.difunc.control_mode() == "PR"
    d.pulse.segment(5_000_000, 1, 0)
    d.advance(5 * MS)
    assert "AL008" not in d.alarms.active
    d.set_di(5, False)
    d.advance(20 * MS)
    assert d.difunc.control_mode() == "PT" and "AL008" in d.alarms.active


def test_monitor_006_is_the_frequency_on_the_line_in_any_servo_state():
    """Monitor 006, "驅動器接收到脈波命令的頻率" (L15446): with the servo off it had kept the
    last frequency accepted (100 kpps) while the line ran at 50 kHz."""
    d = _pt(**{"P0.017": 6, "P1.045": 10000, "P1.000": 0x0002})
    d.pulse.segment(100_000, 1, 0)
    d.advance(100 * MS)
    assert d.params.read("P0.009") == 100
    d.set_di(1, False)
    d.advance(50 * MS)
    d.pulse.segment(50_000, 1, 0)
    d.advance(100 * MS)
    assert d.params.read("P0.009") == 50
    d.pulse.stop()
    d.advance(10 * MS)
    assert d.params.read("P0.009") == 0


def test_monitor_001_in_pt_counts_pulses_from_power_up():
    """Monitor 001 in PT, "代表驅動器接收的脈波命令數" (L15441): before the first pulse it had
    shown the position command in PUU (a jog's 82677), not 0."""
    d = _pt(**{"P2.014": 0x0137, "P4.005": 100, "P0.017": 1})  # DI5 = JOGU
    d.set_di(5, True)
    d.advance(500 * MS)
    d.set_di(5, False)
    d.advance(300 * MS)
    assert d.axis.position != 0
    assert d.params.read("P0.009") == 0
    d.pulse.segment(10_000, 1, 1000)
    d.advance(400 * MS)
    assert d.params.read("P0.009") == 1000


def test_p2_060_is_judged_on_its_write_though_no_gnum_input_selects_it_yet():
    """Our addition (`pt_gear_check`): a P2.060 write is judged even while no GNUM input can
    select it, since a later DI mapping (P2.014 = GNUM0) would put it in use at once with
    nothing left to judge it (an outside review of session 16 found that gap when the write
    was let through)."""
    d = _pt()
    with pytest.raises(ModelError, match="1/4 < Nx/M"):
        d.params.write("P2.060", 1000)


def test_pulses_that_come_during_a_jog_are_dropped_not_run_afterwards():
    """docs/manual-choices.md (JOGU / JOGD): while JOG holds the axis the mode's commands
    are dropped, not queued. 5000 pulses during a jog had been run after it, undoing the
    jog's travel."""
    d = _pt(**{"P2.014": 0x0137, "P4.005": 10, "P1.045": 10000})
    d.set_di(5, True)
    d.advance(20 * MS)
    d.pulse.segment(10_000, 1, 5000)
    d.advance(600 * MS)
    d.set_di(5, False)
    at_end = d.axis.position
    d.advance(1 * S)
    assert d.pulse.accepted == 0 and d.pulse.lost_held == 5000
    assert abs(d.axis.position - at_end) < 0.05 * abs(at_end)  # the jog's stop, no more


@pytest.mark.parametrize("value", [0x0003, 0x000F, 0x0202, 0x0F02, 0x2042])
def test_p1_000_refuses_reserved_digits(value):
    """P1.000 0x0000 ~ 0x11F2: X 0-2, Z 0-1, UY filter with U 0-1 (L7662-L7674). X = 3 had
    been accepted and every pulse then lost without a word."""
    d = Drive(inputs={8: True})
    with pytest.raises(ModelError, match=r"P1\.000: (digit|0x2042 outside)"):
        d.params.write("P1.000", value)
    d.params.write("P1.000", 0x11F2)
