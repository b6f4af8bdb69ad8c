"""Homing and the position counters against the manual, written from it (an outside review
found these departures): torque homing, DEC1 / DEC2, the 32-bit counters' overflow."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS, S

PR_HOMING = {"P1.001": 1, "P2.037": 0x0127}  # PR mode; DI10 = SHOM (0x27, L15197)


@pytest.mark.parametrize("p1087", [50, 70, 150, 250])
def test_torque_homing_finishes_whatever_the_torque_level(p1087):
    """P5.004 X = 9: push into the stop; once the torque reaches P1.087 for P1.088 ms the
    origin is there (L4368, L4392); the torque available is P1.087 + 10 % (L4383), P1.087
    1-300 % (L4374). A level above what the search speed alone needs must still be reached."""
    d = Drive(mechanics=Mechanics(hard_stop_pos_rev=2.0), sensors={"ORGP": (9, "no")},
              inputs={6: True, 7: True, 8: True},
              params=PR_HOMING | {"P5.004": 0x029, "P1.087": p1087, "P1.088": 100})
    d.set_di(1, True)
    d.advance(100 * MS)
    d.set_di(10, True)
    peak = 0.0
    for _ in range(3000):
        d.advance(MS)
        peak = max(peak, abs(d.axis.torque) / 10)
        if d.homing.homed and not d.homing.active:
            break
    assert d.homing.homed and d.do(3), (d.homing.phase, peak)  # HOME on (L15290)
    assert p1087 <= peak <= p1087 + 10 + 0.5


def _decel_ms(p6000: int) -> float:
    """X = 0 homing (forward to PL) at P5.005 = 120 rpm: ms from leaving the search to 0 rpm,
    with P5.026 = 6000 ms and P5.027 = 1500 ms per 3000 rpm (entries 6 and 7, L11323)."""
    d = Drive(inputs={8: True}, params=PR_HOMING | {
        "P5.004": 0x100, "P5.005": 1200, "P5.006": 300, "P6.000": p6000,
        "P5.026": 6000, "P5.027": 1500})
    d.set_di(1, True)
    d.advance(100 * MS)
    d.set_di(10, True)
    while d.homing.phase in ("", "search"):
        d.advance(MS)
    t0 = d.now
    while d.axis.velocity_rpm > 0:
        d.advance(MS)
    return (d.now - t0) / MS


def test_the_first_stage_ends_with_dec1_not_dec2():
    """P6.000 U = DEC1, "the first homing deceleration"; A = DEC2, the second (L4267-4269,
    L12627-12630): the slowdown out of the high-speed search follows U alone. 120 rpm at
    6000 ms per 3000 rpm is 240 ms; at 1500 ms, 60 ms."""
    assert _decel_ms(0x00076000) == pytest.approx(240, abs=3)  # U = 6 (P5.026), A = 7
    assert _decel_ms(0x00067000) == pytest.approx(60, abs=3)  # U = 7 (P5.027), A = 6


def _overflowed() -> Drive:
    """CiA 402 homing (method 35: here) with 607Ch near the top of the 32-bit range, then PV
    forward: the PUU counters pass 2^31 - 1. DO4 = OVF (0x12, L15310)."""
    d = Drive(inputs={8: True}, params={"P1.001": 0x0C, "P2.021": 0x0112})
    for i, s, v in ((0x6060, 0, 6), (0x6098, 0, 35), (0x607C, 0, 2147483000)):
        d.write_object(i, s, v)
    for cw in (0x06, 0x07, 0x0F, 0x1F):
        d.write_object(0x6040, 0, cw)
    d.advance(200 * MS)
    assert d.homing.homed and d.do(3) and not d.do(4)  # HOME on (DO3), OVF off
    d.write_object(0x6060, 0, 3)
    d.write_object(0x60FF, 0, 1000)
    d.write_object(0x6040, 0, 0x0F)
    d.advance(S)
    return d


def test_the_counters_wrap_and_their_overflow_turns_home_off_and_ovf_on():
    """HOME is on "until the position counter (command or feedback) overflows, then off"
    (L15290); OVF is "position command / feedback overflow" (L15310). The counters are 32
    bits: past 2^31 - 1 they read negative."""
    d = _overflowed()
    assert d.read_object(0x6064, 0) < 0 and d.read_object(0x6062, 0) < 0
    assert not d.do(3) and not d.params.get("P0.046") & 0x100  # HOME off, P0.046 bit 8 too
    assert d.do(4)  # OVF


def test_a_positioning_command_after_the_overflow_gives_al235_and_homing_clears_it():
    """A positioning command after the counter overflowed gives AL235 (L20083-20087); the
    clear is homing again (L20091). The PP set-point is not run (no acknowledgement)."""
    d = _overflowed()
    d.write_object(0x60FF, 0, 0)
    d.advance(200 * MS)
    d.write_object(0x6060, 0, 1)  # PP
    d.write_object(0x607A, 0, 1000)
    d.write_object(0x6081, 0, 10000)
    before = d.axis.position
    d.write_object(0x6040, 0, 0x0F)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(100 * MS)
    assert "AL235" in d.alarms.active
    assert not d.read_object(0x6041, 0) & 0x1000  # set-point not acknowledged
    assert d.axis.position == before
    d.write_object(0x6060, 0, 6)  # home again: the coordinate means something again
    d.write_object(0x607C, 0, 0)
    d.write_object(0x6040, 0, 0x0F)
    d.write_object(0x6040, 0, 0x1F)
    d.advance(200 * MS)
    assert "AL235" not in d.alarms.active and d.do(3) and not d.do(4)


def test_idxd_comes_on_when_homing_completes():
    """DO IDXD (0x0E): "the index coordinate is defined once homing completes" (L15298); off
    after a power-up until then. DO4 = IDXD, PR homing X = 8 (here)."""
    d = Drive(inputs={8: True}, params=PR_HOMING | {"P5.004": 0x008, "P2.021": 0x010E})
    d.set_di(1, True)
    d.advance(100 * MS)
    assert not d.do(4)
    d.set_di(10, True)
    d.advance(500 * MS)
    assert d.homing.homed and d.do(3) and d.do(4)
    d.power_cycle()
    assert not d.do(4)
