"""Brake and STO against section 3.10 and P1.042/P1.043, written from the manual (an outside
review found these departures)."""

from __future__ import annotations

from hil.model.drive import Drive
from hil.units import MS


def mk(**p: int) -> Drive:
    """DO6 = BRKR (P2.041 = 0x0108, L9603): the bench's brake hangs on it."""
    return Drive(inputs={8: True}, params={"P2.041": 0x0108} | p)


def test_no_brake_release_no_do_and_no_torque_while_the_drive_is_off():
    """BRKR on = brake released, only P1.042 after a servo on (L1353, L8499); a drive
    without control power conducts on no DO and holds no torque: a P1.042 release pending
    at the power-off never comes during the off time."""
    d = mk(**{"P1.042": 300})
    d.set_di(1, True)  # SON
    d.advance(100 * MS)
    seen = []
    d.sched.after(250 * MS, lambda: seen.append(
        (d.powered, d.do(6), d.holding_brake.clamped, d.dio.do_levels(), d.axis.power)))
    d.power_cycle(off_for=500 * MS)
    powered, brkr_do, clamped, levels, torque = seen[0]
    assert not powered and not brkr_do and clamped and not torque
    assert levels == [False] * 6


def test_a_negative_p1043_hold_ends_at_the_power_off():
    """A negative P1.043 holds torque |P1.043| after a normal servo off (L8503-8516); a drive
    that loses control power holds nothing."""
    d = mk(**{"P1.043": -1000})
    d.set_di(1, True)
    d.advance(50 * MS)
    d.set_di(1, False)
    d.advance(10 * MS)
    assert d.axis.power  # the hold
    seen = []
    d.sched.after(200 * MS, lambda: seen.append((d.powered, d.axis.power)))
    d.power_cycle(off_for=500 * MS)
    assert seen == [(False, False)]


def test_emgs_during_a_negative_p1043_hold_cuts_the_torque_at_once():
    """For EMGS (and an alarm other than AL022) a negative P1.043 is ignored and acts as 0
    (L8516): EMGS during the hold after a normal servo off ends it at once."""
    d = mk(**{"P1.043": -500})
    d.set_di(1, True)
    d.advance(105 * MS)
    d.set_di(1, False)
    d.advance(50 * MS)
    assert d.axis.power
    d.set_di(8, False)  # EMGS (DI8, b-contact by default)
    d.advance(10 * MS)  # P2.009 filter and the alarm
    assert "AL013" in d.alarms.active and not d.axis.power


def test_one_channel_lost_for_1_s_gives_its_alarm_whatever_the_other_does():
    """AL501: "STO_A lost its enable signal" for 1 s (L2482, L20203). A brief dip of STO_B
    (5 ms, too short for AL500's 10 ms, L2478) does not restart STO_A's second."""
    d = mk()
    d.set_di(1, True)
    d.advance(200 * MS)
    d.set_sto("A", False)
    for _ in range(2):
        d.advance(400 * MS)
        d.set_sto("B", False)
        d.advance(5 * MS)
        d.set_sto("B", True)
    d.advance(200 * MS)  # 1010 ms after A was lost
    assert "AL501" in d.alarms.active and not d.servo_on
    assert "AL500" not in d.alarms.active


def test_both_lost_gives_al500_and_not_al501_as_well():
    """Both lost with a skew: AL500 after 10 ms of both (L2478) takes over; the channel lost
    first gives no AL501 on top while both stay lost."""
    d = mk()
    d.set_di(1, True)
    d.advance(200 * MS)
    d.set_sto("A", False)
    d.advance(50 * MS)
    d.set_sto("B", False)
    d.advance(1500 * MS)
    assert "AL500" in d.alarms.active
    assert "AL501" not in d.alarms.active and "AL502" not in d.alarms.active


def test_no_sto_alarm_is_raised_while_the_drive_is_off():
    """The firmware that counts the 10 ms / 1 s does not run without control power: both
    channels lost 5 ms before a power-off give no AL500 during the off time; at power-up
    they are judged afresh (AL500 10 ms later)."""
    d = mk()
    d.set_di(1, True)
    d.advance(50 * MS)
    d.set_sto("A", False)
    d.set_sto("B", False)
    d.advance(5 * MS)
    seen = []
    d.sched.after(100 * MS, lambda: seen.append(tuple(d.alarms.active)))
    d.power_cycle(off_for=500 * MS)
    assert seen == [()]
    d.advance(20 * MS)
    assert "AL500" in d.alarms.active
