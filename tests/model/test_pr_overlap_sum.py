"""PR OVLP as the manual draws it (§7.1.6 "重疊命令", figure 7.1.6.11, L5051-5057): when the
overlapping position command enters its deceleration, the next motion command's
*acceleration* overlaps it: the next command runs its own profile from rest and the two
add. L5055 gives the smooth case, Spd1 / 3000 × Dec = Spd2 / 3000 × Acc (the two ramps take
the same time); the total travel is the two strokes (seed 000:692-709).

The numbers below are worked out from those lines, not read off the model: ACC/DEC are
"ms from 0 to 3000 rpm" (L11330), so a ramp at speed v takes v / 3000 × T ms (L4164)."""

from __future__ import annotations

import itertools

from hil.model.drive import Drive
from hil.model.motion import Axis, rpm_to_counts_per_s
from hil.model.options import ModelOptions
from hil.units import MS
from tests.model.test_pr import BENCH, put, puu, times

PUU_PER_REV = 100_000  # P1.044 / P1.045 factory values: 16777216 / 100000 (L16408)


def make(**pr_options) -> Drive:
    d = Drive(options=ModelOptions(extra={"pr": pr_options}), inputs={8: True},
              params=BENCH | {"P2.016": 0, "P2.036": 0}, sensors={})
    d.set_di(1, True)
    d.advance(400 * MS)
    assert d.servo_on
    return d


def run_two(d: Drive, pr1: dict, pr2: dict, ms: int = 600) -> tuple[dict[int, float], int]:
    """PR#1 (AUTO, OVLP) -> PR#2 from P5.007; the demand speed (rpm) at every ms after the
    trigger, and the ms PR#2 was issued at."""
    put(d, 1, type_="auto", cmd="INC", ovlp=True, **pr1)
    put(d, 2, type_="single", cmd="INC", **pr2)
    t0 = d.now // MS
    d.params.write("P5.007", 1)
    speed = {}
    for _ in range(ms):
        d.advance(MS)
        speed[d.now // MS - t0] = d.axis.demand_rpm
    return speed, times(d, "motion:2")[0] - t0


def test_the_smooth_case_of_l5055_is_one_straight_ramp_from_spd1_to_spd2() -> None:
    """Spd1 300 rpm, Dec 800 ms (PR#1 decelerates for 300/3000 × 800 = 80 ms); Spd2 600 rpm,
    Acc 400 ms (PR#2 accelerates for 600/3000 × 400 = 80 ms): the equation of L5055 holds,
    so the speed goes from 300 to 600 rpm in one straight ramp of 80 ms (3.75 rpm a ms),
    halfway (450 rpm) 40 ms in. Re-targeting PR#1 at PR#2's acceleration would reach 600 rpm
    after 300/3000 × 400 = 40 ms instead."""
    d = make()
    d.params.write("P5.021", 400)  # ACC #1
    speed, m2 = run_two(d, {"data": 50_000, "spd": 4, "dec": 4},  # P5.064 300 rpm, P5.024
                        {"data": 200_000, "spd": 6, "acc": 1})   # P5.066 600 rpm
    assert abs(speed[m2 + 40] - 450.0) <= 8.0, speed[m2 + 40]
    assert abs(speed[m2 + 20] - 375.0) <= 8.0, speed[m2 + 20]
    assert speed[m2 + 70] < 600.0 - 20.0  # still ramping 70 ms in
    assert abs(speed[m2 + 85] - 600.0) < 0.01  # the ramp is over by 80 ms (+ a tick)
    join = [speed[m2 + k] for k in range(0, 85)]
    assert all(b >= a - 0.01 for a, b in itertools.pairwise(join))  # never slows down
    assert puu(d) == 250_000  # the two strokes (000:692-709)


def test_unequal_ramps_add_up_to_a_bump_above_both_speeds() -> None:
    """Both paths at 300 rpm; PR#1's Dec 800 ms (80 ms at 300 rpm), PR#2's Acc 600 ms (60 ms):
    L5055 does not hold. The sum rises by 3000/600 - 3000/800 = 1.25 rpm a ms while both
    ramps run, to 300 + 1.25 × 60 = 375 rpm when PR#2 reaches its speed, then falls with
    what is left of PR#1's ramp, back to 300 rpm 80 ms in."""
    d = make()
    speed, m2 = run_two(d, {"data": 50_000, "spd": 4, "dec": 4},  # P5.024 = 800
                        {"data": 200_000, "spd": 4, "acc": 3})    # P5.023 = 600
    peak_t = max(range(m2, m2 + 120), key=lambda t: speed[t])
    assert abs(speed[peak_t] - 375.0) <= 8.0, speed[peak_t]
    assert 57 <= peak_t - m2 <= 63, peak_t - m2
    assert abs(speed[m2 + 85] - 300.0) < 0.01
    assert puu(d) == 250_000


def test_equal_ramps_at_equal_speeds_keep_the_speed_and_end_one_ramp_early() -> None:
    """Figure 7.1.6.11(b): 50000 then 30000 PUU at 300 rpm (500000 PUU/s), 20 ms ramps
    (P5.020 = 200 ms: 300/3000 × 200): PR#1 takes 20 + 80 + 20 = 120 ms, PR#2 20 + 40 + 20
    = 80 ms; overlapped, the program ends 120 + 80 - 20 = 180 ms after PR#1 began, the speed
    held at 300 rpm between the two (within the 1 ms tick)."""
    d = make()
    speed, m2 = run_two(d, {"data": 50_000, "spd": 4}, {"data": 30_000, "spd": 4})
    assert all(abs(speed[t] - 300.0) < 0.01 for t in range(m2 - 30, m2 + 40))
    t0 = d.now // MS - 600  # the trigger
    m1 = times(d, "motion:1")[0] - t0
    cmd_ok = [t - t0 for t in times(d, "Cmd_OK:1")]
    assert len(cmd_ok) == 1
    assert abs(cmd_ok[0] - (m1 + 180)) <= 1, (m1, cmd_ok)
    assert puu(d) == 80_000


def test_the_retargeting_model_is_kept_as_a_deviation_and_differs() -> None:
    """`dev_ovlp_retargets` (the model before this fix): PR#1 re-targeted at PR#2's ramps
    reaches 600 rpm in 40 ms, not 80 (the L5055 case of the first test)."""
    d = make(dev_ovlp_retargets=True)
    d.params.write("P5.021", 400)
    speed, m2 = run_two(d, {"data": 50_000, "spd": 4, "dec": 4},
                        {"data": 200_000, "spd": 6, "acc": 1})
    assert abs(speed[m2 + 41] - 600.0) < 0.01
    assert puu(d) == 250_000


def test_three_overlapping_paths_add_and_travel_their_strokes() -> None:
    """PR#1 OVLP -> PR#2 OVLP (a short one) -> PR#3: PR#3 starts when PR#2's own profile
    decelerates, while PR#1's ramp may still run; the axis ends on the sum of the strokes and
    Cmd_OK rises once."""
    d = make()
    put(d, 1, type_="auto", cmd="INC", ovlp=True, data=40_000, spd=4, dec=4)
    put(d, 2, type_="auto", cmd="INC", ovlp=True, data=8_000, spd=4)
    put(d, 3, type_="single", cmd="INC", data=20_000, spd=4)
    d.params.write("P5.007", 1)
    last = d.axis.demand
    worst = 0.0
    for _ in range(800):
        d.advance(MS)
        worst = max(worst, abs(d.axis.demand - last))
        last = d.axis.demand
    assert puu(d) == 68_000
    assert len(times(d, "Cmd_OK:1")) == 1
    # the demand moves at most a ms at the sum of three 300 rpm profiles: no jump
    assert worst <= 3 * rpm_to_counts_per_s(300.0) * 1e-3 + 1.0


def test_a_stop_during_the_overlap_stops_the_sum_without_a_jump() -> None:
    """STP (P5.007 = 1000, L11183) while PR#2 accelerates over PR#1's ramp: the summed demand
    decelerates to rest from where it is, with no step in the demand position."""
    d = make()
    put(d, 1, type_="auto", cmd="INC", ovlp=True, data=50_000, spd=4, dec=4)
    put(d, 2, type_="single", cmd="INC", data=200_000, spd=6)
    d.params.write("P5.007", 1)
    while not times(d, "motion:2"):
        d.advance(MS)
    d.advance(10 * MS)  # both ramps running
    before = d.axis.demand
    v = d.axis.demand_velocity
    d.params.write("P5.007", 1000)
    d.advance(MS)
    assert abs(d.axis.demand - before) <= abs(v) * 1e-3 + 1.0
    d.advance(2000 * MS)
    assert d.axis.demand_velocity == 0.0 and not d.axis.moving
    assert puu(d) < 250_000  # stopped short


def test_axis_overlap_keeps_the_demand_continuous_and_is_at_target_after_both() -> None:
    """The axis API: `move_to(..., overlap=True)` during a move leaves the demand where it is
    (the new profile starts at the old target, the old one's remainder subtracted), and
    `at_target` waits for the sum."""
    ax = Axis()
    ax.set_power(True)
    ax.move_to(50_000_000.0, 300.0, 200.0, 200.0)
    for _ in range(50):
        ax.step(MS)
    d0, v0 = ax.demand, ax.demand_velocity
    ax.move_to(60_000_000.0, 300.0, 200.0, 200.0, overlap=True)
    assert (ax.demand, ax.demand_velocity) == (d0, v0)
    ax.step(MS)
    assert abs(ax.demand - d0) <= abs(v0) * 1e-3 * 1.1
    steps = 0
    while not ax.at_target:
        ax.step(MS)
        steps += 1
        assert steps < 5000
    assert ax.demand == 60_000_000.0
    ax.move_to(1_000_000.0, 300.0, 200.0, 200.0, overlap=True)  # at rest: a plain move
    while ax.moving:
        ax.step(MS)
    assert ax.demand == 1_000_000.0

