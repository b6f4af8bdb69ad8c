"""The CAPTURE / COMPARE timing specs pass on the faithful drive, at several speeds and in both
directions, and fail on each deviation knob (A3 §7.2.2-7.2.3: 5 µs L5150, L5188; pulse width
P5.059.CBA L11770)."""

from __future__ import annotations

import pytest

from hil.model.options import ModelOptions
from hil.paths import fixture
from hil.timing.checker import check
from hil.timing.source import RecordingSource
from hil.timing.spec import load_spec
from hil.units import MS
from tests.timing.test_specs_on_model import assert_all_pass, assert_fails, run

PARAMS = {"P2.020": 0x0116, "P2.021": 0x0000}  # DO3 CAP_OK (L15323); DO4 free for COMPARE


def options(**dev) -> ModelOptions:
    return ModelOptions(state_publish_ms=1, extra={"capture": dev})


def pv(tap, rpm: float) -> None:
    tap.write_object(0x6060, 0, 3)
    for cw in (6, 7, 15):
        tap.write_object(0x6040, 0, cw)
    tap.write_object(0x60FF, 0, round(rpm * 10))
    tap.advance(500 * MS)


def capture_scenario(tap) -> None:
    pv(tap, 300)
    p = tap.drive.params
    for _ in range(3):
        p.write("P5.038", 1)
        p.write("P5.039", 0x0131)  # CN2, NC, start (L11500-11531)
        tap.advance(7 * MS + 123_000)
        tap.set_di(7, False)  # the mark: DI7 opens
        tap.advance(3 * MS)
        tap.set_di(7, True)
        tap.advance(10 * MS)


def capture_scenario_no(tap) -> None:
    """As `capture_scenario` with P5.039.Z = 0 (NO, L11538): the closing edge latches, 3 ms
    after the opening. The spec had judged the opening edge alone (helper-97)."""
    pv(tap, 300)
    p = tap.drive.params
    for _ in range(3):
        p.write("P5.038", 1)
        p.write("P5.039", 0x0031)
        tap.advance(7 * MS + 123_000)
        tap.set_di(7, False)
        tap.advance(3 * MS)
        tap.set_di(7, True)
        tap.advance(10 * MS)


def test_capture_latency_on_the_no_edge(tmp_path) -> None:
    path = run(tmp_path, capture_scenario_no, options(), **PARAMS)
    vs = verdicts(path, "capture_latency")
    assert len([v for v in vs if v.status == "pass"]) == 3, [
        (v.constraint, v.status, v.message) for v in vs]
    assert_all_pass(vs)
    late = run(tmp_path / "late", capture_scenario_no, options(dev_capture_delay_us=50),
               **PARAMS)
    assert_fails(verdicts(late, "capture_latency"), "CAP_OK rises 5 µs after the DI7 edge (NO")


def compare_scenario(rpm: float, width: int = 10):
    def scenario(tap) -> None:
        pv(tap, rpm)
        d = tap.drive
        d.params.write("P5.039", 0x0030)  # capture axis = CN2 (Fb_PUU), stopped
        v = d.compare.velocity()  # PUU/s
        target = round(d.compare.position() + v * 0.05)  # 50 ms ahead
        d.pr.array[50] = target
        d.params.write("P5.056", 50)
        d.params.write("P5.058", 1)
        d.params.write("P5.059", width << 16 | 0x0001)  # capture axis, NO, start
        tap.advance(50 * MS + (width + 100) * MS)
        scenario.target = target
    return scenario


def verdicts(path, spec_id: str, **constants) -> list:
    spec = load_spec(fixture("timing", f"{spec_id}.yaml"))
    return check(spec, RecordingSource(path), constants=constants or None)


def test_capture_latency_faithful(tmp_path) -> None:
    path = run(tmp_path, capture_scenario, options(), **PARAMS)
    vs = verdicts(path, "capture_latency")
    assert len([v for v in vs if v.status == "pass"]) == 3
    assert_all_pass(vs)


def test_capture_latency_is_not_judged_where_it_does_not_apply(tmp_path) -> None:
    """DO3 is not CAP_OK (P2.020 = 0x0109), or an edge after the count ran out (P5.039 bit0
    cleared at the last point, L5155): no capture to time, so `skipped`, never a failure
    (`hil check` with every shipped spec on a plan wired otherwise)."""
    path = run(tmp_path, capture_scenario, options(), **{**PARAMS, "P2.020": 0x0109})
    vs = verdicts(path, "capture_latency")
    assert vs and {v.status for v in vs} == {"skipped"}, [(v.status, v.message) for v in vs]

    def extra_edge(tap) -> None:
        capture_scenario(tap)
        tap.set_di(7, False)  # the count ran out: bit0 is 0, this edge captures nothing
        tap.advance(3 * MS)
        tap.set_di(7, True)
        tap.advance(10 * MS)

    path = run(tmp_path / "x", extra_edge, options(), **PARAMS)
    vs, no = nc_and_no(verdicts(path, "capture_latency"))
    assert [v.status for v in vs] == ["pass", "pass", "pass", "skipped"], \
        [(v.status, v.message) for v in vs]
    assert {v.status for v in no} == {"skipped"}  # Z = 1: the closing edges capture nothing


def nc_and_no(vs: list) -> tuple[list, list]:
    """The verdicts of the NC-edge rule and of the NO-edge rule (P5.039.Z, L11536-11540)."""
    no = [v for v in vs if "(NO trigger)" in v.constraint]
    return [v for v in vs if v not in no], no


def test_a_three_point_capture_times_cap_ok_from_its_last_edge(tmp_path) -> None:
    """L5156: each captured point decrements P5.038 and CAP_OK comes On only when it reaches
    0, so the first two edges of a 3-point capture raise no CAP_OK (the spec had failed
    them; an outside audit, helper-64); the last edge is timed."""
    def three_point(tap) -> None:
        pv(tap, 300)
        tap.drive.params.write("P5.038", 3)
        tap.drive.params.write("P5.039", 0x0131)  # CN2, NC, start
        for _ in range(3):
            tap.advance(7 * MS + 123_000)
            tap.set_di(7, False)
            tap.advance(3 * MS)
            tap.set_di(7, True)
            tap.advance(10 * MS)

    vs, _no = nc_and_no(verdicts(run(tmp_path, three_point, options(), **PARAMS),
                                 "capture_latency"))
    assert [v.status for v in vs] == ["skipped", "skipped", "pass"], \
        [(v.status, v.message) for v in vs]


def test_capture_latency_fails_late(tmp_path) -> None:
    path = run(tmp_path, capture_scenario, options(dev_capture_delay_us=50), **PARAMS)
    assert_fails(verdicts(path, "capture_latency"), "CAP_OK rises 5 µs after the DI7 edge")


@pytest.mark.parametrize("rpm", [60, 300, 1000, -60, -300, -1000])
def test_compare_output_faithful(tmp_path, rpm) -> None:
    sc = compare_scenario(rpm)
    path = run(tmp_path, sc, options(), **PARAMS)
    assert_all_pass(verdicts(path, "compare_output", target=sc.target, width=10))


@pytest.mark.parametrize(("knob", "constraint", "rpm"), [
    ({"dev_compare_late": 5000}, "DO4 fires at the table position", 1000),
    ({"dev_compare_late": 5000}, "DO4 fires at the table position", -60),
    ({"dev_compare_width_extra_ms": 2}, "DO4 pulse lasts P5.059.CBA ms", 300),
], ids=["late-up", "late-down", "width"])
def test_compare_output_fails_on_knobs(tmp_path, knob, constraint, rpm) -> None:
    sc = compare_scenario(rpm)
    path = run(tmp_path, sc, options(**knob), **PARAMS)
    assert_fails(verdicts(path, "compare_output", target=sc.target, width=10), constraint)


def table_scenario(tap) -> None:
    pv(tap, 300)
    d = tap.drive
    d.params.write("P5.039", 0x0030)
    here = round(d.compare.position())
    for i in range(3):
        d.pr.array[50 + i] = here + (i + 1) * 10000  # every 20 ms at 500 000 PUU/s
    d.params.write("P5.058", 3)
    d.params.write("P5.059", 5 << 16 | 0x0001)  # 5 ms pulses
    tap.advance(150 * MS)


@pytest.mark.parametrize(("knob", "ok"), [({}, True), ({"dev_compare_width_extra_ms": 2}, False)])
def test_compare_pulse_every_point(tmp_path, knob, ok) -> None:
    path = run(tmp_path, table_scenario, options(**knob), **PARAMS)
    vs = verdicts(path, "compare_pulse", width=5)
    assert len([v for v in vs if v.status != "skipped"]) == 3
    if ok:
        assert_all_pass(vs)
    else:
        assert_fails(vs, "each DO4 pulse lasts P5.059.CBA ms")


def there_and_back(tap) -> None:
    """A cyclic COMPARE of one point (P5.059 bit1, L11742): the axis passes it going up,
    turns and passes it again going down. The point fires each time (L5188)."""
    pv(tap, 300)
    d = tap.drive
    d.params.write("P5.039", 0x0030)
    target = round(d.compare.position() + d.compare.velocity() * 0.05)
    d.pr.array[50] = target
    d.params.write("P5.056", 50)
    d.params.write("P5.058", 1)
    d.params.write("P5.059", 10 << 16 | 0x0003)  # 10 ms pulses, cyclic, start
    tap.advance(150 * MS)
    tap.write_object(0x60FF, 0, -3000)
    tap.advance(600 * MS)
    there_and_back.target = target


@pytest.mark.parametrize(("knob", "ok"), [({}, True), ({"dev_compare_positive_only": True}, False)])
def test_compare_output_judges_every_crossing(tmp_path, knob, ok) -> None:
    """compare_output had judged only the first crossing of a recording (its trigger was an
    `earliest_of`, which has one occurrence): a drive firing upward only passed (helper-97)."""
    path = run(tmp_path, there_and_back, options(**knob), **PARAMS)
    vs = verdicts(path, "compare_output", target=there_and_back.target, width=10)
    judged = [v for v in vs if v.status != "skipped"]
    assert len(judged) == 4, [(v.constraint, v.status, v.message) for v in vs]
    if ok:
        assert_all_pass(vs)
    else:
        assert_fails(vs, "DO4 fires at the table position, moving down")
