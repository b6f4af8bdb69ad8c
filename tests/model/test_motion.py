"""Axis and mechanics: profiles, stops, e-gear, following error (injected time only)."""

from __future__ import annotations

import pytest

from hil.model.mechanics import COUNTS_PER_REV, Mechanics
from hil.model.motion import (
    Axis,
    accel_from_ms,
    counts_to_puu,
    puu_per_s_to_rpm,
    puu_to_counts,
    ramp_time_ms,
    rpm_to_counts_per_s,
    rpm_to_puu_per_s,
)
from hil.units import MS

CPR = COUNTS_PER_REV


def run(axis: Axis, ms: int) -> None:
    for _ in range(ms):
        axis.step(MS)


def run_until_still(axis: Axis, limit_ms: int = 20_000) -> int:
    for t in range(limit_ms):
        axis.step(MS)
        if not axis.moving:
            return t + 1
    raise AssertionError("axis still moving")


def powered(mech: Mechanics | None = None) -> Axis:
    axis = Axis(mech)
    axis.set_power(True)
    return axis


# ---- conversions ---------------------------------------------------------------------


def test_egear_puu_counts_round_trip():
    # PUU = counts × P1.045 / P1.044 (L16408); factory gear 16777216 / 100000 (L6879-6880)
    assert counts_to_puu(CPR, 16777216, 100000) == 100000
    assert puu_to_counts(100000, 16777216, 100000) == CPR
    # CANopen reload value 1/1 (L10744-10745): PUU = counts
    assert counts_to_puu(12345, 1, 1) == 12345
    assert puu_to_counts(counts_to_puu(987654, 3, 7), 3, 7) == pytest.approx(987654)


def test_speed_conversions():
    assert rpm_to_counts_per_s(60) == CPR
    # 100000 PUU/rev: 500000 PUU/s = 5 rev/s = 300 rpm
    assert puu_per_s_to_rpm(500000, 16777216, 100000) == pytest.approx(300.0)
    assert rpm_to_puu_per_s(300.0, 16777216, 100000) == pytest.approx(500000)


def test_ramp_time_is_constant_slope_l4164():
    # "50 ms: 3000 rpm takes 50 ms, 1500 rpm takes 25 ms" (L4164)
    assert ramp_time_ms(3000, 50) == 50
    assert ramp_time_ms(1500, 50) == 25
    assert accel_from_ms(50) == pytest.approx(rpm_to_counts_per_s(3000) / 0.050)


# ---- mechanics -----------------------------------------------------------------------


def test_mechanics_switches_and_index():
    m = Mechanics(nl_rev=-10, pl_rev=10, home_lo_rev=-0.25, home_hi_rev=0.25, index_angle=0.5)
    assert m.limit_states(0) == (False, False)
    assert m.limit_states(-10 * CPR) == (True, False)
    assert m.limit_states(11 * CPR) == (False, True)
    assert m.home_sensor(0.2 * CPR) and not m.home_sensor(0.3 * CPR)
    assert m.index_crossed(0, 2 * CPR) == [0.5 * CPR, 1.5 * CPR]
    assert m.index_crossed(2 * CPR, 0) == [1.5 * CPR, 0.5 * CPR]
    # half-open: a pulse exactly at the start is not reported again
    assert m.index_crossed(0.5 * CPR, 0.6 * CPR) == []
    assert m.index_crossed(0.4 * CPR, 0.5 * CPR) == [0.5 * CPR]


def test_mechanics_rejects_bad_values():
    with pytest.raises(ValueError, match="nl_rev"):
        Mechanics(nl_rev=5, pl_rev=1)
    with pytest.raises(ValueError, match="unknown field"):
        Mechanics.from_dict({"inertia": 1})


# ---- profiles ------------------------------------------------------------------------


def test_pp_trapezoid_reaches_target_and_settles():
    axis = powered()
    axis.move_to(2 * CPR, 300, 200, 200)  # 300 rpm, 200 ms per 3000 rpm
    t = run_until_still(axis)
    assert axis.position == 2 * CPR
    assert axis.at_target and axis.following_error == 0
    # 2 rev at 5 rev/s with 20 ms ramps: ~420 ms, plus settling of the position loop
    assert 400 <= t <= 600


@pytest.mark.parametrize("dist", [1.0, 0.997, 0.5987, 0.05, -0.7331])
@pytest.mark.parametrize(("rpm", "dec_ms"), [(300, 200), (3000, 50), (1234, 777)])
def test_pp_demand_lands_on_the_target_never_past_it(dist, rpm, dec_ms):
    """The profile (Cmd_O) ends on its target (Cmd_E) without passing it: a position command
    past its target would trip a software limit set at the target (AL283/AL285 judge the
    command, L20107, L20113)."""
    axis = powered()
    target = round(dist * CPR)
    axis.move_to(target, rpm, 200, dec_ms)
    sign = 1 if target > 0 else -1
    for _ in range(20_000):
        axis.step(MS)
        assert axis.demand * sign <= target * sign
        if axis.demand == target and axis.demand_velocity == 0.0:
            break
    assert axis.demand == target and axis.demand_velocity == 0.0


def test_pp_peak_speed_and_acceleration_slope():
    axis = powered()
    axis.move_to(10 * CPR, 3000, 100, 100)
    run(axis, 50)  # 100 ms per 3000 rpm: 1500 rpm after 50 ms (L4164 slope)
    assert axis.demand_rpm == pytest.approx(1500, abs=1e-6)
    run(axis, 100)
    assert axis.demand_rpm == pytest.approx(3000)


def test_following_error_is_small_but_real():
    axis = powered()
    axis.move_to(5 * CPR, 3000, 200, 200)
    worst = 0.0
    for _ in range(3000):
        axis.step(MS)
        worst = max(worst, abs(axis.following_error))
    assert 0.001 * CPR < worst < 0.1 * CPR  # lags, but far inside 6065h = 3840000 (L18438)
    assert axis.following_error == 0  # settled


def test_change_set_immediately_retargets_while_moving():
    axis = powered()
    axis.move_to(10 * CPR, 3000, 200, 200)
    run(axis, 100)
    assert axis.demand_velocity > 0
    axis.move_to(-1 * CPR, 3000, 200, 200)  # reverse: decelerates, comes back
    run(axis, 5)
    assert axis.demand_velocity > 0  # still braking, no jump
    run_until_still(axis)
    assert axis.position == -1 * CPR


def test_profile_velocity_and_ramp_stop_p5003_example():
    axis = powered()
    axis.run_velocity(3000, 50, 50)
    run(axis, 50)
    assert axis.demand_rpm == 3000  # 0 -> 3000 rpm in 50 ms
    run(axis, 50)
    assert axis.velocity_rpm == pytest.approx(3000, abs=1)
    axis.ramp_stop(50)  # "T ms per 3000 rpm" (L11330, L4164)
    run(axis, 25)
    assert axis.demand_rpm == pytest.approx(1500)
    run(axis, 25)
    assert axis.demand_rpm == 0 and axis.mode == "hold"
    run_until_still(axis)
    assert axis.velocity == 0


def test_ramp_stop_from_1500_rpm_takes_half_the_time():
    axis = powered()
    axis.run_velocity(1500, 50, 50)
    run(axis, 200)
    axis.ramp_stop(50)
    run(axis, 24)
    assert axis.demand_rpm > 0
    run(axis, 1)
    assert axis.demand_rpm == 0  # 1500 rpm at 50 ms/3000 rpm: 25 ms (L4164)


def test_profile_torque_slope_and_speed_limit():
    axis = powered()
    axis.run_torque(1000, 200)  # 100 % in 200 ms (6087h, L18803-18817)
    run(axis, 100)
    assert axis.torque_demand == pytest.approx(500)
    run(axis, 100)
    assert axis.at_target
    run(axis, 200)  # (not longer: at 3000 rpm the default hard stop is < 1 s away)
    assert axis.velocity_rpm == pytest.approx(axis.max_speed_rpm)  # P1.055 caps the speed
    run(axis, 1000)
    assert axis.position == 48 * CPR and axis.velocity == 0  # pressed into the hard stop


def test_torque_limit_makes_the_axis_lag():
    axis = powered()
    axis.set_torque_limits(100, 100)  # 10 % of rated
    axis.move_to(10 * CPR, 3000, 10, 10)
    run(axis, 100)
    assert abs(axis.torque) <= 100 + 1e-9
    assert axis.following_error > 0.5 * CPR


def test_interpolate_linear_segment():
    axis = powered()
    axis.interpolate_to(CPR / 100, 2 * MS)
    axis.step(MS)
    assert axis.demand == pytest.approx(CPR / 200)
    axis.step(MS)
    assert axis.demand == CPR / 100 and axis.at_target


# ---- power stage, stops, brake, gravity --------------------------------------------------


def spinning(stop_mode: int, rpm: float = 3000) -> Axis:
    axis = powered()
    axis.run_velocity(rpm, 10, 10)
    run(axis, 100)
    axis.stop_mode = stop_mode
    axis.set_power(False)
    return axis


def test_coast_is_slower_than_dynamic_brake():
    coast, db = spinning(1), spinning(0)
    run(coast, 30)
    run(db, 30)
    assert 0 < db.velocity_rpm < coast.velocity_rpm
    assert run_until_still(db) < run_until_still(coast)


def test_stop_mode_2_brakes_then_coasts_below_p1038():
    a = spinning(2)
    run(a, 2000)
    assert a.velocity_rpm < a.zero_speed_rpm  # DB until below P1.038 (L8327)
    run_until_still(a)
    assert a.velocity == 0


def test_power_off_keeps_no_command():
    axis = powered()
    axis.move_to(5 * CPR, 3000, 200, 200)
    axis.set_power(False)
    assert axis.mode == "hold"


def test_gravity_falls_unless_clamped_or_powered():
    m = Mechanics(gravity_torque=0.5)
    free = Axis(m)
    run(free, 20)
    assert free.velocity < 0 and free.moving
    clamped = Axis(m)
    clamped.brake_clamped = True
    run(clamped, 20)
    assert clamped.position == 0 and not clamped.moving
    held = Axis(m)
    held.set_power(True)
    run(held, 50)
    assert abs(held.position) < 1 and held.torque == pytest.approx(0.5 / 1.27 * 1000, rel=0.01)


def test_hard_stop_stops_a_falling_axis():
    m = Mechanics(gravity_torque=0.5, hard_stop_neg_rev=-0.5)
    axis = Axis(m)
    run_until_still(axis)
    assert axis.position == -0.5 * CPR and axis.velocity == 0


def test_user_origin():
    axis = powered()
    axis.move_to(CPR, 600, 100, 100)
    run_until_still(axis)
    axis.set_user_position(0)
    assert axis.user_position == 0 and axis.position == CPR


def test_bad_axis_arguments():
    with pytest.raises(ValueError, match="feedforward"):
        Axis(feedforward=2)
    with pytest.raises(ValueError, match="period"):
        Axis().interpolate_to(0, 0)
