"""The PLC's pulse positioning program (seed 001, FATEK FUN140/FUN141), rule by rule from the
seed, against the virtual drive on its own pulse line in virtual time (hil.clock)."""

from __future__ import annotations

import contextlib
import math
from collections.abc import Iterator

import pytest

from hil import clock
from hil.drivers.plc_pulse import (
    AxisParams,
    Drv,
    PlcError,
    Program,
    PulseMaster,
    Step,
    plan_profile,
)
from hil.model.mechanics import COUNTS_PER_REV, Mechanics
from hil.model.options import ModelOptions
from hil.transport.pulse import open_pulse
from hil.units import MS, S
from hil.virtual.stack import DriveSpec, VirtualDriveStack

GEAR = {"P1.044": 16777216, "P1.045": 10000, "P2.041": 0x0108}  # 10000 pulses / rev
PER_REV = 10000
_n = 0


class Rig:
    """A virtual drive with a pulse line, a PLC on the other end, a recording of the line."""

    def __init__(self, stack: VirtualDriveStack, plc: PulseMaster, port) -> None:
        self.stack, self.plc, self.port = stack, plc, port
        self.segs: list[tuple[int, dict]] = []
        self.levels: list[tuple[int, str, bool]] = []  # what crossed the line (the tap)

    @property
    def drive(self):
        return self.stack.drive

    def rev(self) -> float:
        return self.drive.axis.position / COUNTS_PER_REV


class _Tap:
    def __init__(self, rig_segs: list, levels: list) -> None:
        self.segs = rig_segs
        self.levels = levels

    def pulse(self, name, kind, body, t, source_t):
        if kind == "seg":
            self.segs.append((t, dict(body)))

    def dio(self, name, line, level, t, source_t):
        self.levels.append((t, line, level))


@contextlib.contextmanager
def rig(params: AxisParams, mech: Mechanics | None = None, **drive: int) -> Iterator[Rig]:
    global _n
    _n += 1
    line = f"virtual:plc-test-{_n}"
    with clock.use(clock.VirtualClock()):
        stack = VirtualDriveStack(DriveSpec(
            name="d", pulse=line, params=GEAR | drive, inputs={8: True},
            mechanics=mech or Mechanics(), options=ModelOptions())).start()
        segs: list = []
        levels: list = []
        port = open_pulse(line, role="master", tap=_Tap(segs, levels), name="d")
        try:
            stack.host.call(stack.drive.set_di, 1, True)  # SON
            clock.sleep(0.05)
            plc = PulseMaster(port, params)
            r = Rig(stack, plc, port)
            r.segs, r.levels = segs, levels
            yield r
        finally:
            port.close()
            stack.stop()


def prog(*steps: Step) -> Program:
    return Program(list(steps))


FAST = dict(max_speed=100_000, start_speed=500, accel_ms=100)


# -- FUN141 / FUN140 refusals (001:34, 74) ------------------------------------------------------


@pytest.mark.parametrize("kw, code", [
    ({"pulses_per_rev": 0}, 2), ({"creep_speed": 70000}, 7), ({"accel_ms": 30001}, 9),
    ({"max_speed": 250_000}, 37), ({"max_speed": 500_000, "hardware": "differential",
                                     "output": "A/B"}, 37),
    ({"start_speed": 300_000}, 38),
    # P17: 18 by the seed's "parameter N + 1" rule (15 is P14's, 001:34)
    ({"zero_count": 256}, 18),
    # P9-1 is 0 or 1 (001:58); DRV ABS with 0 is one of two readings (001:10 / 001:38)
    ({"home_direction": -1}, 10), ({"home_direction": 2}, 10), ({"abs_zero": "x"}, 33),
    ({"clr": "Y8", "clr_ms": 20.0}, 53),
    # P7 is parameter 7: error 8 (39 is the travel compensation of P10/P11, 001:34)
    ({"backlash": 32768}, 8),
    # DOG and CLR are host points X0~X15 / Y0~Y23 (001:58-60): errors 51 / 53
    ({"dog": "X16"}, 51), ({"dog": "Q7"}, 51), ({"clr": "Y24"}, 53),
    # look-alike digits an outside test found accepted (a superscript 2 crashed `int`, a
    # fullwidth 0 passed the check and was never seen at run time)
    ({"dog": "X\u00b2"}, 51), ({"dog": "X\uff10"}, 51), ({"clr": "Y\u00b2"}, 53),
    # the stroke limit is an input X0~X125 (P15-1, 001:58); PG0 is the drive's OZ (P15-2)
    ({"limit": "banana"}, 51), ({"limit": "X999"}, 51), ({"limit": "X126"}, 51),
    ({"pg0": "foo"}, 52),
    # P9-0 is a bit (error 10, P9's); the output logic normal ON / OFF (001:28)
    ({"run_direction": 7}, 10), ({"logic": 5}, 1),
    # P16 goes into DR4088, 32 bits (001:122; "parameter number + 1")
    ({"origin": 2**31}, 17), ({"origin": -2**31 - 1}, 17),
    # NaN or inf CLR pulses passed `<= 20` and failed at run time
    ({"clr": "Y8", "clr_ms": float("nan")}, 53), ({"clr": "Y8", "clr_ms": float("inf")}, 53),
])
def test_fun141_refuses_with_its_error_code(kw, code):
    with pytest.raises(PlcError) as e:
        AxisParams(**kw).check()
    assert e.value.code == code


def test_fun140_refusals():
    p = AxisParams(dog="X0")
    cases = [
        (prog(Step(spd=1000, drive=Drv("ADR", "+", 10, chained=True)),
              Step(spd=1000, drive=Drv("ABS", "", 10))), 41),
        (prog(Step(spd=1000, drive=Drv("ADR", "+", 10, chained=True)),
              Step(spd=1000, drive="MD0")), 42),
        (prog(*[Step(spd=1000, drive=Drv("ADR", "+", 1, chained=True)) for _ in range(8)],
              Step(spd=1000, drive=Drv("ADR", "+", 1))), 34),  # at most 8 DRVC (001:40)
        (prog(Step(wait_time=0.1)) if False else prog(*[Step(wait_time=0.01)] * 251), 36),
        (prog(Step(spd=1000, drive="MD2")), 52),
        (prog(Step(spd=1000, drive="MD4")), 50),
        (prog(Step(drive=Drv("ADR", "+", 10))), 30),
        # the chain's direction is the first DRVC's + or - (001:40); blank is refused
        (prog(Step(spd=1000, drive=Drv("ADR", "", 10, chained=True)),
              Step(spd=1000, drive=Drv("ADR", "+", 10))), 43),
        # a stroke that is no whole number of pulses: 0.4 Ps was taken as stroke 0 ("until
        # the transition") and ran for 60 s (33: stroke value error, 001:34)
        (prog(Step(spd=1000, drive=Drv("ADR", "+", 0.4))), 33),
        (prog(Step(spd=1000, drive=Drv("ADR", "+", 1.5))), 33),
        # a direction and a negative stroke contradict each other
        (prog(Step(spd=1000, drive=Drv("ADR", "+", -500))), 33),
    ]
    for program, code in cases:
        with pytest.raises(PlcError) as e:
            program.check(p)
        assert e.value.code == code, (program, e.value)
    prog(*[Step(spd=1000, drive=Drv("ADR", "+", 1, chained=True)) for _ in range(7)],
         Step(spd=1000, drive=Drv("ADR", "+", 1))).check(p)  # 7 DRVC + the DRV: allowed
    prog(Step(spd=1000, drive=Drv("ADR", "", -500))).check(p)  # the sign gives the direction
    mech = AxisParams(dog="X0", unit=2, decimals=2)  # mm with 2 decimals, 2000 Ps per 2000 um
    prog(Step(spd=1000, drive=Drv("ADR", "+", 0.5, "Ut"))).check(mech)  # 500 Ps
    with pytest.raises(PlcError) as e:  # 0.0001 mm is less than a pulse here
        prog(Step(spd=1000, drive=Drv("ADR", "+", 0.0001, "Ut"))).check(mech)
    assert e.value.code == 33


# -- profile ---------------------------------------------------------------------------------


def test_profile_adds_up_exactly_and_cruises_at_spd():
    acc = (100_000 - 500) / 0.1  # P8 = 100 ms from P5 to P4 (001:56)
    slices = plan_profile([(30_000, 50_000.0)], 500.0, acc, acc)
    assert sum(n for _, n in slices) == 30_000
    speeds = [n * 1e9 / d for d, n in slices]
    assert max(speeds) == pytest.approx(50_000, rel=1e-6)
    cruise = [(d, n) for d, n in slices if n * 1e9 / d == pytest.approx(50_000, rel=1e-6)]
    assert len(cruise) == 1  # a constant speed stays one segment
    # a short stroke is a triangle: it never reaches SPD
    tri = plan_profile([(200, 50_000.0)], 500.0, acc, acc)
    assert sum(n for _, n in tri) == 200
    assert max(n * 1e9 / d for d, n in tri) < 50_000


def test_accel_time_zero_jumps_to_spd():
    slices = plan_profile([(5000, 10_000.0)], 500.0, float("inf"), float("inf"))
    assert slices == [(500 * MS, 5000)]


# -- runs against the virtual drive -------------------------------------------------------------


def test_drv_abs_and_adr_move_the_motor_through_the_gear():
    with rig(AxisParams(**FAST)) as r:
        st = r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 30_000)),
                            Step(spd=20_000, drive=Drv("ADR", "-", 10_000), wait_time=0.2),
                            Step(end=True)))
        assert st.position == 20_000 and st.remaining == 0 and st.done
        assert r.rev() == pytest.approx(2.0, abs=2 / PER_REV)
        assert st.feedback == pytest.approx(4 * 2500 * 2, abs=3)  # OA/OB, P1.046 = 2500


def test_abs_is_relative_to_the_position_register():
    with rig(AxisParams(**FAST)) as r:
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ABS", "", 5000)),
                       Step(spd=20_000, drive=Drv("ABS", "", 2000), wait_time=0.2)))
        assert r.plc.status.position == 2000
        assert r.rev() == pytest.approx(0.2, abs=2 / PER_REV)


def test_goto_loops_and_act_runs_for_its_time():
    with rig(AxisParams(**FAST)) as r:
        t0 = clock.monotonic_ns()
        # ACT 0.3 s of a continuous run (stroke 0, 001:38), then stop
        r.plc.run(prog(Step(spd=10_000, drive=Drv("ADR", "+", 0), act=0.3), Step(end=True)))
        took = clock.monotonic_ns() - t0
        assert 0.3 * S <= took < 0.3 * S + 5 * MS
        assert r.plc.status.position == pytest.approx(3000 - 30, abs=60)  # ramp from P5


def test_ext_abandons_the_remaining_pulses_and_keeps_them_in_dr4072():
    # EXT on the cam X0 (DOG at -0.5..0.5 rev): from +3 rev towards -2 rev (001:42-44)
    with rig(AxisParams(**FAST)) as r:
        r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 30_000), wait_time=0.1)))
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ADR", "-", 50_000), ext="X0", goto=3),
                       Step(spd=20_000, drive=Drv("ADR", "-", 1)),
                       Step(end=True)))
        st = r.plc.status
        assert 24_000 < 30_000 - st.position < 25_200  # stopped at the cam's edge (+0.5 rev)
        assert st.remaining == 50_000 - (30_000 - st.position)  # DR4072 (001:44)
        clock.sleep(0.3)
        assert r.rev() == pytest.approx(st.position / PER_REV, abs=2 / PER_REV)


def test_backlash_is_output_on_a_reversal_and_not_counted():
    # P7 added on reversal (001:56)
    with rig(AxisParams(**FAST, backlash=100)) as r:
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ADR", "+", 5000)),
                       Step(spd=20_000, drive=Drv("ADR", "-", 2000), wait_time=0.2)))
        assert r.plc.status.position == 3000
        assert r.plc.total == 5000 - 2000 - 100
        assert r.rev() == pytest.approx(0.29, abs=2 / PER_REV)


def _home(r: Rig, mode: str) -> None:
    r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 30_000), wait_time=0.1)))
    r.plc.run(prog(Step(spd=20_000, drive=mode)))


HOME = dict(FAST, creep_speed=2000, dog="X0", limit="X1", pg0="OZ", clr="Y8", origin=100)


def test_md0_zero_at_dog_off_at_creep_speed():
    with rig(AxisParams(**HOME)) as r:
        _home(r, "MD0")
        assert r.plc.status.position == 100 and r.plc.status.homed
        assert r.rev() == pytest.approx(-0.5, abs=10 / PER_REV)  # DOG's far edge
        before_stop = [s for _, s in r.segs if s["freq"] > 0][-1]
        assert before_stop["freq"] == pytest.approx(2000)  # creep P6 through DOG


def test_md1_stops_waits_half_a_second_and_reverses_at_creep():
    with rig(AxisParams(**HOME)) as r:
        _home(r, "MD1")
        moving = [(t, s) for t, s in r.segs if s["freq"] > 0]
        rev = next(i for i, (_, s) in enumerate(moving) if s["direction"] == 1 and i > 0
                   and moving[i - 1][1]["direction"] == -1)
        stop_t = next(t for t, s in r.segs if t > moving[rev - 1][0] and s["freq"] == 0)
        assert moving[rev][0] - stop_t >= 500 * MS  # "wait 0.5 s" (001:112)
        assert moving[rev][1]["freq"] == pytest.approx(2000)  # reverse at P6
        assert r.rev() == pytest.approx(0.5, abs=10 / PER_REV)  # DOG's near edge


@pytest.mark.parametrize("edge, zero_count, at_rev", [("leading", 1, 0.0), ("trailing", 1, -1.0),
                                                      ("leading", 2, -1.0)])
def test_md2_counts_pg0_from_the_dog_edge(edge, zero_count, at_rev):
    with rig(AxisParams(**HOME | {"pg0_edge": edge, "zero_count": zero_count})) as r:
        _home(r, "MD2")
        assert r.rev() == pytest.approx(at_rev, abs=10 / PER_REV)


def test_clr_pulse_is_longer_than_20_ms_and_clears_the_drive_error():
    with rig(AxisParams(**HOME)) as r:
        _home(r, "MD0")
        clr = [(t, lv) for t, line, lv in r.levels if line == "Y8"]
        assert [lv for _, lv in clr] == [False, True, False]  # idle off, then the pulse
        assert clr[2][0] - clr[1][0] > 20 * MS  # 001:124
        assert abs(r.drive.pulse.error()) < COUNTS_PER_REV / PER_REV  # CCLR on DI2 (L9749)


def test_start_on_dog_runs_to_the_stroke_limit_and_back_through_dog():
    # 001:118: on or in front of DOG -> homing speed to the stroke limit -> reverse until DOG
    # goes 1 -> 0 -> the selected mode. Limit switch close by: NL at -2 rev.
    mech = Mechanics(nl_rev=-2.0, hard_stop_neg_rev=-3.0)
    with rig(AxisParams(**HOME), mech=mech) as r:
        assert r.plc.dog()  # the axis starts at 0 rev, on the cam
        r.plc.run(prog(Step(spd=20_000, drive="MD0")))
        dirs = [s["direction"] for _, s in r.segs if s["freq"] > 0]
        assert dirs[0] == -1 and 1 in dirs  # towards the limit, then back
        assert r.plc.status.homed
        assert r.rev() == pytest.approx(-0.5, abs=10 / PER_REV)


def test_drvz_without_a_zero_point_times_out_and_stops():
    mech = Mechanics(home_lo_rev=50.0, home_hi_rev=51.0)  # no cam on the way
    with rig(AxisParams(**HOME | {"limit": ""}), mech=mech) as r:
        with pytest.raises(TimeoutError, match="DRVZ MD0"):
            r.plc.run(prog(Step(spd=20_000, drive="MD0")), timeout_s=0.5)
        assert r.segs[-1][1]["freq"] == 0  # the pulses stopped
        # no homing runs and none completed: a later CLR-line rise is no homing's (plc_clr
        # judged every later Y8 rise after a failed DRVZ, helper-99)
        assert r.plc.status.drvz == "" and not r.plc.status.homed


# -- found by a review against seed 001 (wave 3, session 9) --------------------------------------


def test_p9_0_reversed_counts_down_for_forward_pulses_and_abs_still_arrives():
    # P9-0 = 1: forward pulses count down, reverse pulses count up (001:56); ABS is from the
    # position register (001:38), so the move still ends at its target
    with rig(AxisParams(**FAST, run_direction=1)) as r:
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ABS", "", 5000), wait_time=0.1)))
        assert r.plc.status.position == 5000
        assert {s["direction"] for _, s in r.segs if s["freq"] > 0} == {-1}  # reverse pulses
        assert r.rev() == pytest.approx(-0.5, abs=2 / PER_REV)
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ABS", "", 5000), wait_time=0.1)))
        assert r.plc.status.position == 5000  # already there
        r.plc.run(prog(Step(spd=20_000, drive=Drv("ADR", "+", 1000), wait_time=0.1)))
        assert r.plc.status.position == 6000


@pytest.mark.parametrize("mode", ["MD0", "MD2"])
def test_md0_md2_drop_to_the_creep_speed_at_dog_at_once(mode):
    # "碰到近點 DOG ... 立即降為原點復歸速度" (001:122; MD0 001:110, MD2 001:114): with the
    # default P8 = 5000 ms the zero point is still taken at P6, not on a slope
    mech = Mechanics(home_lo_rev=-0.25, home_hi_rev=0.25)  # a DOG half a revolution wide
    with rig(AxisParams(**HOME | {"accel_ms": 5000}), mech=mech) as r:
        _home(r, mode)
        assert r.plc.status.homed
        moving = [s for _, s in r.segs if s["freq"] > 0]
        assert moving[-1]["freq"] == pytest.approx(2000)
        assert r.rev() == pytest.approx(-0.25 if mode == "MD0" else 0.0, abs=10 / PER_REV)


def test_md1_after_a_stop_past_dog_comes_back_through_it():
    # MD1 (001:112): stop with P8, wait 0.5 s, reverse at P6, the zero where DOG turns off.
    # A long P8 stop can run past a narrow DOG: the reverse run comes back into DOG first,
    # and the zero is DOG's near edge, as after a stop inside it
    mech = Mechanics(home_lo_rev=-0.25, home_hi_rev=0.25)
    with rig(AxisParams(**HOME | {"accel_ms": 5000}), mech=mech) as r:
        r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 30_000), wait_time=0.1)))
        r.plc.run(prog(Step(spd=20_000, drive="MD1")), timeout_s=30)
        assert r.plc.status.homed
        assert r.rev() == pytest.approx(0.25, abs=10 / PER_REV)  # DOG's near edge


def test_a_stroke_0_move_that_never_meets_its_transition_is_not_a_finished_program():
    # stroke 0: run until the transition (001:38); WAIT acts once the pulses are done (001:42),
    # which never happens: the program has not ended when the time runs out
    with rig(AxisParams(**FAST)) as r, pytest.raises(TimeoutError):
        r.plc.run(prog(Step(spd=10_000, drive=Drv("ADR", "+", 0), ext="X5"), Step(end=True)),
                  timeout_s=1.0)


@pytest.mark.parametrize("unit, decimals, stroke, pulses", [
    (2, 2, 100, 2000),  # 1.00 mm of a 5000 µm/rev screw at 10000 Ps/rev
    (2, 0, 100, 200_000),  # 100 mm
    (0, 3, 2500, 5000),  # 2.500 mm
    (1, 2, 100, 100),  # the motor unit: pulses
])
def test_mechanical_units_use_p3_decimals_and_p2_in_um(unit, decimals, stroke, pulses):
    # P0: 0 mechanical (mm and cm/min), 1 motor, 2 compound (mm and Ps/s); P2 (B) µm/rev,
    # P1 (A) Ps/rev, P3 decimals (001:54-56)
    p = AxisParams(unit=unit, pulses_per_rev=10_000, travel_per_rev=5000, decimals=decimals)
    assert p.pulses(stroke, "Ut") == pulses


def test_mechanical_speeds_are_cm_per_minute():
    # f = V x 1000 x A / (6 x B) (001:54-56): 100 cm/min of a 5 mm/rev screw is 3.33 rev/s
    p = AxisParams(unit=0, pulses_per_rev=10_000, travel_per_rev=5000, max_speed=100,
                   start_speed=1, creep_speed=6)
    assert p.max_speed_pps == pytest.approx(33_333.3, abs=0.1)
    assert p.speed(6) == pytest.approx(2000)
    assert AxisParams(unit=2, max_speed=100).max_speed_pps == 100  # compound: Ps/s


@pytest.mark.parametrize("accel_ms", [50, 1000, 5000])
def test_a_drvc_chain_enters_a_slower_segment_at_its_own_speed(accel_ms):
    # the seed's multi-speed chain (001:40): 20000 at 10 kHz, 60000 at 50 kHz, 5000 at 3 kHz;
    # with the default P8 (5000 ms) too, the last segment runs at its 3 kHz
    p = AxisParams(max_speed=100_000, start_speed=500, accel_ms=accel_ms)
    slices = plan_profile([(20_000, 10_000.0), (60_000, 50_000.0), (5000, 3000.0)],
                          p.start_speed_pps, p.accel, p.decel)
    x, speeds_in_last = 0, []
    for dur, n in slices:
        if x >= 80_000:
            speeds_in_last.append(n * S / dur)
        x += n
    assert x == 85_000
    assert max(speeds_in_last) <= 3000 * 1.05  # entered at 3 kHz (10 ms slices average)
    assert sum(1 for v in speeds_in_last if v == pytest.approx(3000, rel=0.01)) >= 1


def test_md1_stops_with_the_p8_slope_even_when_p12_is_set():
    # "由目前速度以加減速時間設定 (參數 8) 之斜率減速停止" (001:112)
    with rig(AxisParams(**HOME | {"accel_ms": 1000, "decel_ms": 10})) as r:
        _home(r, "MD1")
        moving = [(t, s) for t, s in r.segs if s["freq"] > 0]
        turn = next(i for i, (_, s) in enumerate(moving) if s["direction"] == 1 and i > 0
                    and moving[i - 1][1]["direction"] == -1)
        last = max(i for i, (_, s) in enumerate(moving[:turn])
                   if s["freq"] == pytest.approx(20_000))  # the homing speed, until DOG
        slowing = [t for t, s in r.segs if moving[last][0] < t <= moving[turn - 1][0]]
        stop = next(t for t, s in r.segs if t > moving[turn - 1][0] and s["freq"] == 0)
        # 20 kHz down to P5 (500) on P8's slope (~100 kHz a second): about 0.2 s, not 2 ms
        assert 0.15 * S < stop - slowing[0] < 0.3 * S


# -- register operands (001:38-44) -------------------------------------------------------------


def test_the_seeds_register_example_continues_the_pulses_ext_left_in_dr4072():
    """The seed's own program (001:44): SPD R1000 (DR1000), DRV ADR,+,D100 (DD100), WAIT
    TIME,R500 (0.01 s); then SPD R1002, DRV ADR,-,D102 with EXT X0: cut at the cam, the next
    step runs DRV ADR,-,R4072,Ps, the pulses step 3 did not output (its minus sign is lost in
    the OCR, as every minus of that page). The motor ends where step 3 alone would have."""
    regs = {"R1000": 50_000, "D100": 30_000, "R500": 20, "R1002": 20_000, "D102": 50_000}
    with rig(AxisParams(**FAST)) as r:
        t0 = clock.monotonic_ns()
        st = r.plc.run(prog(Step(spd="R1000", drive=Drv("ADR", "+", "D100"), wait_time="R500"),
                            Step(spd="R1002", drive=Drv("ADR", "-", "D102"), ext="X0"),
                            Step(spd=2000, drive=Drv("ADR", "-", "R4072", "Ps"),
                                 wait_time=0.1),
                            Step(end=True)), registers=regs)
        assert st.position == 30_000 - 50_000 and st.remaining == 0
        assert r.rev() == pytest.approx(-2.0, abs=2 / PER_REV)
        # step 3 ran at 2 kHz: the cut left more than 20 000 pulses, so it took over 10 s
        assert clock.monotonic_ns() - t0 > 10 * S


def test_wait_and_act_times_from_a_register_count_hundredths_of_a_second():
    with rig(AxisParams(**FAST)) as r:
        t0 = clock.monotonic_ns()
        r.plc.run(prog(Step(wait_time="R10"), Step(spd=10_000, drive=Drv("ADR", "+", 0),
                                                   act="D7"), Step(end=True)),
                  registers={"R10": 50, "D7": 30})
        took = clock.monotonic_ns() - t0
        assert 0.8 * S <= took < 0.8 * S + 5 * MS  # 0.5 s, then ACT 0.3 s
        assert r.plc.status.position == pytest.approx(3000 - 30, abs=60)


def test_goto_a_register_and_unset_registers_read_0():
    with rig(AxisParams(**FAST)) as r:
        # GOTO R20 = 3 skips step 2; DRV D5 (unset: 0) would be a continuous run, so it
        # must be skipped for the program to end
        st = r.plc.run(prog(Step(spd=10_000, drive=Drv("ADR", "+", 1000), goto="R20"),
                            Step(spd=10_000, drive=Drv("ADR", "+", "D5")),
                            Step(spd=10_000, drive=Drv("ADR", "+", 500)),
                            Step(end=True)), registers={"R20": 3})
        assert st.position == 1500


def test_register_operands_are_refused_as_the_plc_refuses_them():
    p = AxisParams(**FAST)
    # an operand that is no register: SPD error 30, stroke error 32, others 34
    for program, code in [
        (prog(Step(spd="R4000", drive=Drv("ADR", "+", 10))), 30),
        (prog(Step(spd=1000, drive=Drv("ADR", "+", "D4000"))), 32),
        (prog(Step(goto="R9000"), Step(end=True)), 34),
    ]:
        with pytest.raises(PlcError) as e:
            program.check(p)
        assert e.value.code == code
    # values the data registers hold, checked as constants: SPD above P4 (31), a stroke
    # beyond 32 bits in mechanical units (33), a GOTO to no step (34), and an SPD of 0,
    # which the PLC would wait on for ever (001:38)
    mech = AxisParams(**FAST, unit=0, travel_per_rev=1)
    for params, program, regs, code in [
        (p, prog(Step(spd="R1", drive=Drv("ADR", "+", 10))), {"R1": 200_000}, 31),
        (p, prog(Step(spd="R1", drive=Drv("ADR", "+", 10))), {}, 31),
        (mech, prog(Step(spd=1, drive=Drv("ADR", "+", "D1", "Ut"))), {"D1": 2**30}, 33),
        (p, prog(Step(goto="R1"), Step(end=True)), {"R1": 3}, 34),
    ]:
        program.check(params)
        with pytest.raises(PlcError) as e:
            program.check_registers(params, regs)
        assert e.value.code == code, (program, regs, e.value)


def test_a_status_register_read_at_run_time_is_checked_then():
    # SPD from DR4088 (the position register): 0 at the start, so the step waits for a
    # non-zero speed (001:38) and the program's time runs out; R4060 stays 0
    with rig(AxisParams(**FAST)) as r:
        with pytest.raises(TimeoutError, match="SPD R4088 stayed 0"):
            r.plc.run(prog(Step(spd="R4088", drive=Drv("ADR", "+", 10))), timeout_s=0.5)
        # once the position is 300 000, SPD R4088 is above P4 (100 kHz): error 31 in R4060
        r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 300_000))))
        with pytest.raises(PlcError) as e:
            r.plc.run(prog(Step(spd="R4088", drive=Drv("ADR", "+", 10))))
        assert e.value.code == 31 and r.plc.status.error == 31


def test_registers_are_16_bit_words_and_a_32_bit_value_takes_the_next_as_its_high_word():
    # 132072 = 2 << 16 | 1000: R10 holds 1000, R11 holds 2 (001:38: low word, high word)
    from hil.drivers.plc_pulse import read_register, register_words
    w = register_words({"R10": 132072, "R500": 20, "R501": 2, "D102": -3000})
    assert (w["R10"], w["R11"], w["R500"], w["R501"]) == (1000, 2, 20, 2)
    assert read_register("R10", w, None, 32) == 132072
    assert read_register("R11", w, None, 16) == 2
    assert read_register("R500", w, None, 32) == 2 << 16 | 20  # the pair a PLC reads
    assert read_register("D102", w, None, 32) == -3000 and read_register("D103", w, None, 16) \
        == 0xFFFF
    assert read_register("R0500", w, None, 16) == 20  # R0500 is R500
    for bad in ({"D102": -1, "D103": 5}, {"R3839": 70000}, {"R1": "5"}, {"R4088": 1}):
        with pytest.raises(ValueError):
            register_words(bad)
    with rig(AxisParams(**FAST)) as r:  # GOTO R11 reads the high word of R10's value: 2
        st = r.plc.run(prog(Step(goto="R11"), Step(spd=10_000, drive=Drv("ADR", "+", 700)),
                            Step(end=True)), registers={"R10": 132072})
        assert st.position == 700
    # a 32-bit operand needs its high word in the register map: R3839 + R3840 is not
    with pytest.raises(PlcError) as e:
        prog(Step(spd="R3839", drive=Drv("ADR", "+", 10))).check(AxisParams(**FAST))
    assert e.value.code == 30


def test_a_goto_loop_that_takes_no_time_is_refused_not_spun_for_ever():
    # WAIT R500 = 0 then GOTO 1: in virtual time no time passes, so the program's timeout
    # would never come; the PLC would spin for ever. The step fails at once instead.
    with rig(AxisParams(**FAST)) as r:
        for program, regs in ((prog(Step(wait_time="R500", goto="R7")), {"R500": 0, "R7": 1}),
                              (prog(Step(wait_time=0.0, goto=1)), {})):
            t0 = clock.monotonic_ns()
            with pytest.raises(TimeoutError, match="loops without end"):
                r.plc.run(program, timeout_s=2.0, registers=regs)
            assert clock.monotonic_ns() == t0
        # a loop that moves takes time: it ends at the program's timeout as before
        with pytest.raises(TimeoutError, match="program timeout"):
            r.plc.run(prog(Step(spd=5000, drive=Drv("ADR", "+", 100), goto=1)), timeout_s=0.5)


def test_a_wait_longer_than_the_program_time_fails_at_that_time():
    with rig(AxisParams(**FAST)) as r:
        t0 = clock.monotonic_ns()
        with pytest.raises(TimeoutError, match="longer than the program's time"):
            r.plc.run(prog(Step(wait_time="R500"), Step(end=True)), timeout_s=2.0,
                      registers={"R500": -1})  # 65535 x 0.01 s
        assert 1.99 * S <= clock.monotonic_ns() - t0 <= 2.01 * S


def test_the_stroke_limit_may_be_any_input_x0_to_x125():
    # P15-1 b14~b8: 0~125, X0~X125 (001:58); only DOG is a host point X0~X15
    AxisParams(limit="X125").check()
    AxisParams(limit="X20").check()


def test_p9_1_is_the_seeds_0_up_1_down():
    # 001:58: 0 = towards increasing count ("origin on the right"), 1 (default) decreasing
    assert AxisParams().home_direction == 1 and AxisParams().home_sign == -1
    assert AxisParams(home_direction=0).home_sign == 1


def test_md1_decelerates_from_the_speed_it_has_when_dog_comes():
    # MD1: at DOG "由目前速度以加減速時間設定(參數8)之斜率減速停止" (001:112): from the current
    # speed with the P8 slope. With P8 = 5 s and DOG 0.5 rev away the axis is still low on
    # its ramp at DOG: no segment may jump above the speed it had (an outside review saw
    # 14 kHz -> 50 kHz at DOG)
    with rig(AxisParams(**HOME | {"accel_ms": 5000})) as r:
        r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 10_000), wait_time=0.1)))
        n0 = len(r.segs)
        r.plc.run(prog(Step(spd=50_000, drive="MD1")))
        toward = [s["freq"] for _, s in r.segs[n0:] if s["freq"] > 0 and s["direction"] == -1]
        peak = max(toward)
        assert peak < 20_000, peak  # 1.5 rev from DOG at the P8 slope: far below 50 kHz
        assert r.plc.status.homed


@pytest.mark.parametrize("run_direction", [0, 1])
def test_a_start_on_dog_seeks_the_limit_in_the_homing_direction_whatever_p9_0(run_direction):
    # 001:118: first towards the homing direction (P9-1) to the stroke limit. P9-0 = 1
    # reverses the pulses for the count (001:56), so the motor turns the other way for the
    # same P9-1: the limit must then be on that side. An outside review found P9-0 = 1 ran
    # away from the limit (the start-on-DOG path ignored P9-0)
    mech = (Mechanics(nl_rev=-2.0, hard_stop_neg_rev=-3.0) if not run_direction
            else Mechanics(pl_rev=2.0, hard_stop_pos_rev=3.0))
    params = AxisParams(**HOME | {"run_direction": run_direction,
                                  "limit": "X1" if not run_direction else "X2"})
    with rig(params, mech=mech) as r:
        assert r.plc.dog()
        r.plc.run(prog(Step(spd=20_000, drive="MD0")), timeout_s=8)
        first = next(s["direction"] for _, s in r.segs if s["freq"] > 0)
        assert first == (-1 if not run_direction else 1)
        assert r.plc.status.homed
        far_edge = -0.5 if not run_direction else 0.5
        assert r.rev() == pytest.approx(far_edge, abs=10 / PER_REV)


@pytest.mark.parametrize("abs_zero, moves", [("continuous", False), ("position", True)])
def test_drv_abs_0_is_the_configured_reading(abs_zero, moves):
    # 001:38: a stroke of 0 runs on "whether ADR or ABS"; 001:10: "DRV ABS,,0,Ut" goes from
    # 300 mm to 0 mm. Option abs_zero (docs/manual-choices.md)
    with rig(AxisParams(**FAST, abs_zero=abs_zero)) as r:
        r.plc.run(prog(Step(spd=50_000, drive=Drv("ABS", "", 30_000), wait_time=0.1)))
        if moves:  # a move to 0 and its WAIT
            r.plc.run(prog(Step(spd=20_000, drive=Drv("ABS", "", 0), wait_time=0.1)))
            assert r.plc.status.position == 0
        else:  # runs on until its ACT
            r.plc.run(prog(Step(spd=20_000, drive=Drv("ABS", "", 0), act=1.0), Step(end=True)))
        if moves:
            assert r.plc.status.position == 0
            clock.sleep(0.2)
            assert r.rev() == pytest.approx(0.0, abs=2 / PER_REV)
        else:  # ran on, forwards, until ACT
            assert r.plc.status.position > 30_000


def test_a_profile_is_planned_no_further_than_its_limit() -> None:
    # a 32-bit stroke at 200 kHz is 3 h of pulses: planned up to the limit only, the slices
    # end short of the total, about the limit long (a ms at a time the whole stroke was
    # 10 million steps and 455 MB before the first pulse)
    total = 2**31 - 1
    slices = plan_profile([(total, 200_000.0)], 500.0, 1e6, 1e6, 10 * MS, limit_ns=5 * S)
    assert 5 * S <= sum(d for d, _ in slices) <= 5 * S + 20 * MS
    assert 0 < sum(n for _, n in slices) < total
    # without a limit a short move is planned whole, as before
    whole = plan_profile([(20_000, 200_000.0)], 500.0, 1e6, 1e6, 10 * MS)
    assert sum(n for _, n in whole) == 20_000


@pytest.mark.parametrize("spd", [1234, 150, 33333])
def test_a_constant_spd_is_one_segment_at_its_own_frequency(spd):
    """SPD is the output frequency (001:38) and a constant speed is one segment
    (docs/pulse.md): the 10 ms slices, each floored to whole pulses, had alternated 1200 and
    1300 Hz for SPD 1234 (±33 % at 150). The pulses still add up exactly."""
    from hil.drivers.plc_pulse import plan_profile

    slices = plan_profile([(2 * spd, float(spd))], v0=141.0, acc=spd / 0.1, dec=spd / 0.1)
    assert sum(n for _, n in slices) == 2 * spd
    longest = max(slices, key=lambda s: s[0])
    assert longest[0] >= 1_500_000_000  # most of the 2 s move
    assert abs(longest[1] / (longest[0] / 1e9) - spd) < 1.0


def test_a_creep_speed_above_max_speed_is_refused():
    """P6, the homing creep speed, converts as every speed does (001:56) and may not pass
    P4 and the output's maximum (001:14; error 37, 001:34): 65535 cm/min at 6 Ps a cm had
    been taken and sent a 65.5 MHz train (helper-100)."""
    with pytest.raises(PlcError) as e:
        AxisParams(unit=0, pulses_per_rev=6, travel_per_rev=1, max_speed=200,
                   creep_speed=65535).check()
    assert e.value.code == 37 and "creep_speed" in str(e.value)
    with pytest.raises(PlcError):
        AxisParams(unit=1, max_speed=10_000, creep_speed=65535).check()
    AxisParams(unit=1, max_speed=10_000, creep_speed=10_000).check()


@pytest.mark.parametrize("extra", [{"goto": 3}, {"wait_time": 1.0}, {"act": 0.5},
                                   {"ext": "X1"}, {"wait_line": "X0"}])
def test_a_drvc_step_with_a_transition_is_refused(extra):
    """A DRVC segment runs straight into the next (001:40: "GOTO NEXT" on each DRVC of the
    example): a GOTO to another step or a WAIT/ACT/EXT on it had been ignored without a
    word (helper-100)."""
    program = prog(Step(spd=10_000, drive=Drv("ADR", "+", 1000, chained=True), **extra),
                   Step(spd=10_000, drive=Drv("ADR", "+", 50_000)),
                   Step(spd=10_000, drive=Drv("ADR", "+", 2000)))
    with pytest.raises(PlcError) as e:
        program.check(AxisParams())
    assert e.value.code == 34 and "DRVC" in str(e.value)


def test_a_move_ending_on_a_slice_boundary_keeps_its_speed_to_the_last_whole_ms():
    """The last 1 ms step of a move is cut short: it is no ms at the constant speed, so the
    stretch before it stays at SPD (1901 Ps at 100 kHz with no slope had become one 20 ms
    segment at 95.05 kHz, helper-101). The pulses and the time are as before."""
    from hil.drivers.plc_pulse import plan_profile

    slices = plan_profile([(1901, 100_000.0)], v0=100_000.0, acc=math.inf, dec=math.inf)
    assert sum(n for _, n in slices) == 1901
    assert slices[0] == (10 * MS, 1000)  # 100 kHz
    assert sum(t for t, _ in slices) == 20 * MS


def test_leading_slices_without_a_whole_pulse_keep_their_time():
    """5 Ps from 1 Hz at 10 Ps/s²: the first slices carry no whole pulse; their time belongs
    to the first segment (it had been dropped: 875 ms of a 1225 ms move, helper-101)."""
    from hil.drivers.plc_pulse import plan_profile

    slices = plan_profile([(5, 100.0)], v0=1.0, acc=10.0, dec=10.0)
    assert sum(n for _, n in slices) == 5
    # a triangle from 1 Hz and back: 5 = 2 (v² - 1) / (2 x 10), v = sqrt(51), 2 (v - 1) / 10 s
    t = 2 * (math.sqrt(51.0) - 1.0) / 10.0
    assert abs(sum(d for d, _ in slices) / S - t) < 0.015
