"""IP set-point smoothing, written from the manual: the IP section recommends P1.036 (S-curve)
and P1.068 (position command moving filter) to smooth the position deltas of the set-points
(A3 L17236-17238). P1.068 is a moving average in ms, default 4 (L8826-8840); P1.036 the
S-curve smoothing time in ms, default 0 = off (L8358-8365). Option `ip_smoothing`."""

from __future__ import annotations

import pytest

from hil.model.drive import Drive
from hil.model.options import ModelOptions
from hil.units import MS

BENCH = {"P2.041": 0x0108}  # EMGS on DI8 (b contact) closed
STEP_PUU = 1200  # one set-point jump; a multiple of every window below


def ip_drive(options: ModelOptions | None = None, **params: int) -> Drive:
    d = Drive(options=options, inputs={8: True}, params=BENCH | params)
    d.write_object(0x6060, 0, 7)  # IP (L17211)
    for cw in (0x06, 0x07, 0x0F):  # L17223-17226
        d.write_object(0x6040, 0, cw)
    d.advance(5 * MS)
    return d


def demand_after_step(d: Drive, steps: int) -> list[float]:
    """One set-point STEP_PUU away (60C2h default: 1 ms), then the same set-point held: the
    position demand (PUU, model origin) at the end of each 1 ms."""
    gear = d.axis.cpr / 100_000  # counts per PUU at the default E-gear (16777216/100000)
    base = d.axis.demand
    out = []
    for _k in range(steps):
        d.write_object(0x60C1, 1, STEP_PUU)  # the controller sends a set-point every cycle
        d.advance(MS)
        out.append((d.axis.demand - base) / gear)
    return out


def test_default_p1068_is_a_4_ms_moving_average_of_the_set_points() -> None:
    d = ip_drive()
    assert d.params.get("P1.068") == 4 and d.params.get("P1.036") == 0  # defaults
    got = demand_after_step(d, 6)
    # the interpolated command reaches the set-point within 1 ms; its 4 ms mean ramps
    assert got == pytest.approx([300, 600, 900, 1200, 1200, 1200], abs=1e-6)


def test_p1068_zero_follows_the_interpolation_directly() -> None:
    d = ip_drive(**{"P1.068": 0})
    assert demand_after_step(d, 3) == pytest.approx([1200, 1200, 1200], abs=1e-6)


def test_p1036_adds_an_s_curve_after_the_moving_filter() -> None:
    d = ip_drive(**{"P1.068": 4, "P1.036": 6})
    got = demand_after_step(d, 12)
    # 4 ms mean of a step is a ramp; a 6 ms mean of that ramp is an S: slow, fast, slow
    ramp = [300, 600, 900, 1200] + [1200] * 8
    window = [0.0] * 6
    want = []
    for x in ramp:
        window = [*window[1:], x]
        want.append(sum(window) / 6)
    assert got == pytest.approx(want, abs=1e-6)
    steps = [b - a for a, b in zip([0.0, *got], got, strict=False)]
    assert steps[0] < steps[3] and steps[-4] < steps[3]  # S-shaped: slow, fast, slow
    assert got[-1] == pytest.approx(1200, abs=1e-6)


def test_a_p1068_write_takes_effect_on_the_next_set_points() -> None:
    d = ip_drive(**{"P1.068": 0})
    d.params.write("P1.068", 2)
    d.write_object(0x6040, 0, 0x06)  # leave and re-enter IP: the filter starts anew
    for cw in (0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
    d.advance(5 * MS)
    assert demand_after_step(d, 3) == pytest.approx([600, 1200, 1200], abs=1e-6)


def test_option_off_leaves_ip_set_points_unfiltered() -> None:
    d = ip_drive(ModelOptions(ip_smoothing="off"))
    assert demand_after_step(d, 2) == pytest.approx([1200, 1200], abs=1e-6)


def test_target_reached_waits_for_the_filtered_command() -> None:
    d = ip_drive(**{"P1.068": 20})
    d.write_object(0x60C1, 1, STEP_PUU)
    d.advance(MS)
    assert not d.read_object(0x6041, 0) & 0x0400  # the 20 ms mean is still ramping
    d.advance(200 * MS)
    assert d.read_object(0x6041, 0) & 0x0400  # bit 10 in IP (L18469, L18486)
    assert not d.axis.moving


def test_ip_following_error_past_6065h_raises_al009() -> None:
    # following error window 6065h (L18438-18452) applies in IP mode as in PP (the model's
    # following_error_exceeded covers PP, IP and HM): set-points that run away from a motor
    # held back by P1.055 (L4034) make 60F4h grow past it, and AL009 follows (L19539-19542)
    d = ip_drive(**{"P1.055": 60, "P1.068": 0})
    d.write_object(0x6065, 0, 20000)
    target, fe = 0, []
    for _ in range(200):
        target += 500  # 500 PUU a ms = 300 rpm at the default gear: 5x the cap
        d.write_object(0x60C1, 1, target)
        d.advance(MS)
        if d.alarms.active:
            break
        fe.append(abs(d.read_object(0x60F4, 0)))
    assert "AL009" in d.alarms.active and not d.servo_on
    assert fe[-1] <= 20000 < fe[-1] + 500 * 1.2  # tripped as 60F4h passed 6065h


def test_the_same_set_point_every_cycle_lets_the_axis_settle() -> None:
    # a controller at rest sends its last set-point every cycle: the filtered command settles
    # and the axis stops moving (and may then stop stepping)
    settled = []
    for p1068 in (4, 0):  # with the filter as without it
        d = ip_drive(**{"P1.068": p1068})
        demand_after_step(d, 4)
        steps = 0
        while d.axis.moving and steps < 300:
            d.write_object(0x60C1, 1, STEP_PUU)
            d.advance(MS)
            steps += 1
        assert not d.axis.moving and d.axis.at_target
        settled.append(steps)
    assert abs(settled[0] - settled[1]) <= 5  # the motor's own settling, not the filter's


@pytest.mark.parametrize("period_ms", [1, 2])
def test_ip_set_points_never_run_into_an_active_limit(period_ms: int) -> None:
    # PL forbids running forward in every mode (L15191, statusword bit 14 L18316): a master
    # that re-enables (0x0F) at the limit and streams forward set-points does not move the
    # motor; set-points behind it run it back (a review against the manual, session 9)
    d = Drive(inputs={6: True, 7: True, 8: True}, params={"P2.041": 0x0108, "P1.068": 0},
              sensors={})  # DI6/DI7 = NL/PL, b contacts (factory), no cams
    d.write_object(0x6060, 0, 7)
    d.write_object(0x60C2, 1, period_ms)
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
    d.advance(50 * MS)
    d.set_di(7, False)  # PL
    d.advance(10 * MS)
    assert "AL015" in d.alarms.active and d.read_object(0x6041, 0) & 0x4000
    d.write_object(0x6040, 0, 0x0F)
    start = sp = d.read_object(0x6064, 0)
    for _ in range(100 // period_ms):
        sp += 100 * period_ms
        d.write_object(0x60C1, 1, sp)
        d.advance(period_ms * MS)
    assert d.read_object(0x6064, 0) == start
    for _ in range(20):
        sp = start - 1000
        d.write_object(0x60C1, 1, sp)
        d.advance(period_ms * MS)
    assert d.read_object(0x6064, 0) < start - 500


def test_6062h_is_the_interpolator_output_and_60fch_the_filtered_demand() -> None:
    """6062h "內部插值器所計算出來的插值命令。此命令接著會經過內部濾波器" (L18410-18412): before
    the filters; 60FCh after them (L19207-19209); 60F4h = 6062h - 6064h (L19193). Both had
    read the filtered demand (helper-115)."""
    d = ip_drive()  # P1.068 = 4 ms
    base_6062 = d.read_object(0x6062, 0)
    d.write_object(0x60C1, 1, STEP_PUU)
    d.advance(MS)
    gear = d.axis.cpr / 100_000
    assert d.read_object(0x6062, 0) - base_6062 == STEP_PUU  # interpolated in one period
    filtered = (d.axis.demand - d.axis.origin) / gear
    assert abs(filtered - base_6062 - 300) < 1  # the 4 ms mean: a quarter of the step
    assert d.read_object(0x60F4, 0) == d.read_object(0x6062, 0) - d.read_object(0x6064, 0)


def test_al009_judges_60f4h_with_the_filters_lag() -> None:
    """AL009 when |60F4h| > 6065h (L18452): with a 20 ms P1.068 the interpolator runs ahead
    of the filtered demand, and 60F4h (6062h - 6064h) with it (helper-116: 60F4h read past
    6065h with no alarm)."""
    d = ip_drive(**{"P1.068": 20})
    d.write_object(0x6065, 0, 3000)
    base = d.read_object(0x6064, 0)
    for k in range(12):
        d.write_object(0x60C1, 1, base + 600 * (k + 1))
        d.advance(MS)
        if "AL009" in d.alarms.active:
            break
    assert "AL009" in d.alarms.active
