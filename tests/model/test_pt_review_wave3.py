"""PT mode against the A3 manual, from an outside review (helper-38): written from the manual's
lines, each checked failing on the model before its fix."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.units import MS, S

PT = {"P2.041": 0x0108}  # P1.001 = 0: PT; DI8 INHP off (inputs={8: True})
ABS = {"P2.069": 1, "P2.011": 0x11D, "P2.012": 0x11F, "P2.021": 0x10D, "P2.013": 0,
       "P2.019": 0, "P2.020": 0}


def _pt(**params) -> Drive:
    d = Drive(inputs={8: True}, params=PT | params)
    d.set_di(1, True)
    d.advance(10 * MS)
    assert d.servo_on
    return d


def test_a_segment_slower_than_a_pulse_in_1000_s_is_refused_not_a_crash():
    """No minimum frequency in the manual; 1e-300 Hz overflowed the segment's end inside the
    model's step. It is refused (a pulse face answers by dropping it); the drive runs on."""
    d = _pt()
    with pytest.raises(ValueError, match="freq"):
        d.pulse.segment(1e-300, 1, 5)
    d.advance(50 * MS)
    d.pulse.segment(1e-3, 1, 1)  # the slowest allowed: one pulse in 1000 s
    d.advance(50 * MS)
    d.pulse.segment(10_000, 1, 100)
    d.advance(100 * MS)
    d.params.write("P0.017", 1)  # monitor 001: the pulse commands received
    assert d.params.get("P0.009") == 100


def test_pulses_reconciled_by_total_move_the_motor_while_it_is_at_rest():
    """Monitor 001 is the pulse commands the drive received (L15441): the motor follows what
    it counts. A lost 5000-pulse segment reconciled by the next one's `total` while the axis
    rested was counted but not moved (half a turn short)."""
    d = _pt(**{"P1.045": 10000})  # 10000 pulses a turn: Nx/M = 16777216/10000
    d.pulse.segment(10_000, 1, 5000, total=5000)  # 5000 went missing on the way
    d.advance(1 * S)
    d.params.write("P0.017", 1)  # monitor 001: pulse command count
    assert d.params.get("P0.009") == 10000
    assert d.axis.position == pytest.approx(2**24, abs=2)  # one whole turn, not half


@pytest.mark.parametrize("params", [{"P1.044": 2**24, "P1.045": 1},  # 16777216: too big
                                    {"P1.044": 1, "P1.045": 8}])  # 1/8: too small
def test_al045_at_power_up_for_an_out_of_range_e_gear_cleared_by_a_power_cycle(params):
    """AL045 (L19699-19703): a ratio outside 1/4 ~ 262144 shows at power-up, in any mode; the
    servo stays off; it clears by a power cycle once the ratio is right, not by a reset."""
    d = Drive(inputs={8: True}, params={"P1.001": 1} | params)  # PR mode: no write check
    assert "AL045" in d.alarms.active
    d.set_di(1, True)
    d.advance(10 * MS)
    assert not d.servo_on
    d.alarms.reset("di")
    assert "AL045" in d.alarms.active  # a reset does not clear it
    d.power_cycle()
    assert "AL045" in d.alarms.active  # still wrong
    d.params.write("P1.044", 16777216)
    d.params.write("P1.045", 100000)
    d.alarms.reset("di")
    assert "AL045" in d.alarms.active  # right now, but only a power cycle clears it
    d.power_cycle()
    assert "AL045" not in d.alarms.active


def test_al045_also_for_a_ratio_written_in_another_mode_then_pt():
    d = Drive(inputs={8: True}, params=PT | {"P1.001": 1})
    d.params.write("P1.045", 1)  # PR: the PT write check does not apply
    d.params.write("P1.001", 0)
    d.power_cycle()
    assert "AL045" in d.alarms.active
    d.set_di(1, True)
    d.advance(10 * MS)
    assert not d.servo_on  # no pulse turns the motor a whole turn


def test_cw_positive_keeps_the_absolute_puu_with_the_command():
    """"馬達的正旋轉方向是由 P1.001.Z 定義" (L16413): with Z = CW positive a positive command
    turns the motor CW, the encoder's turns count down (L16404) and PUU = -1 x pulse x M/N +
    P6.001 (L16410) goes up with 6064h and monitor 000. It went the other way."""
    for z in (0, 1):
        d = Drive(inputs={8: True}, params=PT | ABS | {"P1.001": z << 8, "P1.045": 10000})
        d.params.write("P2.008", 271)
        d.params.write("P2.071", 1)  # the absolute origin here
        d.set_di(1, True)
        d.advance(10 * MS)
        d.pulse.segment(10_000, 1, 10_000)  # one turn of forward pulses
        d.advance(1300 * MS)
        assert d.absolute.puu == pytest.approx(d.read_object(0x6064), abs=1), z
        assert d.absolute.puu == pytest.approx(10_000, abs=1), z
        # one turn of the motor: +16777216 counts CCW, -16777216 CW (L16404-16406)
        assert d.absolute.mem.pulse_value == pytest.approx((-1 if z else 1) * 2**24, abs=4)


def test_pp_bit13_is_still_set_when_a_master_reads_after_al009():
    """L18338: bit 13 in PP is the following error; L18452: past 6065h the drive raises AL009
    and goes off, so 60F4h falls to 0 in the same step. A master polling 6041h every ms never
    saw bit 13 (an outside review); it is kept with the alarm until a fault reset."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x0B})  # CANopen mode
    d.advance(10 * MS)
    d.write_object(0x6060, 0, 1)
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
        d.advance(5 * MS)
    d.write_object(0x6065, 0, 1000)  # a 1000 PUU window
    d.write_object(0x607A, 0, 167772160)
    d.write_object(0x6081, 0, 503316480)
    d.write_object(0x6083, 0, 10)
    d.write_object(0x6040, 0, 0x1F)
    seen = []
    for _ in range(20):
        d.advance(MS)
        seen.append(d.read_object(0x6041, 0))
    assert "AL009" in d.alarms.active
    assert seen[-1] & 0x2000 and seen[-1] & 0x000F == 0x0008  # FAULT, bit 13 set
    d.write_object(0x6040, 0, 0x80)  # fault reset
    d.advance(5 * MS)
    assert not d.read_object(0x6041, 0) & 0x2000
