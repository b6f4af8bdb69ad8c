"""Rules docs/timing.md states, each written from the document and judged on small synthetic
recordings: window limits met exactly by an observation's range, `held` over a value that
changes while true, parameters first recorded by a plain change, `forbid` of an event tied to
another. (An outside review, helper-19 in wave 3 session 12, found each of them broken.)"""

from __future__ import annotations

import pytest

from hil.timing.checker import check, context
from hil.timing.source import MemorySource
from hil.timing.spec import loads_spec

MS = 1_000_000
BIND = {"drive": "drive1", "dio": "drive1"}
STATE = "/drive/drive1/state"
PARAMS = "/drive/drive1/params"


def dio(line: str) -> str:
    return f"/dio/drive1/{line}"


def levels(*pts: tuple[float, bool]) -> list[tuple[int, dict]]:
    return [(round(t * MS), {"level": v}) for t, v in pts]


WINDOW = """\
id: edges
title: DO3 follows DI3
source: "test"
resolution: {"/dio/*/DO*": RES, default: 0}
signals:
  A: {line: DI3}
  Y: {line: DO3}
events:
  a: {rise: A}
  y: {rise: Y, after: a}
constraints:
  - name: w
    from: a
    to: y
    window: {min: LO, max: HI}
"""


@pytest.mark.parametrize(("d", "res", "lo", "hi", "status"), [
    # "a change observed at t with resolution r happened in [t - r, t]" and "pass when that
    # whole range is inside the window": [0.2, 0.3] inside [0.2, 10]
    (0.3, 0.1, 0.2, 10, "pass"),
    # [1.0, 2.2] touches the upper limit 1 and goes past it: neither wholly in nor out
    (2.2, 1.2, 0, 1, "inconclusive"),
    (22, 12, 0, 10, "inconclusive"),  # the same geometry, scaled
    (2.3, 1.2, 0, 1, "fail"),  # [1.1, 2.3]: wholly outside
    (0.7, 0.7, 0, 1, "pass"),  # [0.0, 0.7]: touches the lower limit from inside
])
def test_an_observation_range_that_meets_a_limit_exactly(d, res, lo, hi, status):
    spec = WINDOW.replace("RES", str(res)).replace("LO", str(lo)).replace("HI", str(hi))
    src = MemorySource({dio("DI3"): levels((0, False), (1, True)),
                        dio("DO3"): levels((0, False), (1 + d, True), (100, False))})
    [v] = check(loads_spec(spec), src, binding=BIND)
    assert v.status == status, v.message


LOAD = """\
id: load
title: AL501 1 ms after STO_A held lost 1 s
source: "test"
signals:
  A: {line: STO_A}
  lost: {not: A}
  lost_h: {signal: lost, held: 1000}
events:
  a1s: {rise: lost_h}
  al: {raised: AL501, after: a1s, within: 1000}
constraints:
  - name: AL501 within 1 ms
    from: a1s
    to: al
    window: {min: 0, max: 1}
"""


@pytest.mark.parametrize(("late", "status"), [(1.2, "inconclusive"), (1.3, "fail")])
def test_a_failure_whose_excess_equals_the_input_delay_is_inconclusive(late, status):
    """"A failure whose excess over the limit fits within these delays of the edges involved
    is inconclusive": STO_A reached the drive 1.2 ms after the harness stamped it; AL501
    came 1 + `late` ms after the held signal rose."""
    lag = 1.2
    al = 100 + 1000 + 1 + late
    src = MemorySource({
        dio("STO_A"): levels((0, True), (100, False), (3000, False)),
        "/drive/drive1/inputs": [(round((100 + lag) * MS), {
            "line": "STO_A", "level": False, "sent_ns": 100 * MS,
            "applied_ns": round((100 + lag) * MS), "delay_ns": round(lag * MS)})],
        STATE: [(0, {"alarms": []}), (round(al * MS), {"alarms": ["AL501"]}),
                (3000 * MS, {"alarms": ["AL501"]})]})
    [v] = check(loads_spec(LOAD), src, binding=BIND)
    assert v.status == status, v.message


HELD = """\
id: held
title: an alarm code present for 10 ms
source: "test"
signals:
  code: {topic: "/drive/{drive}/state", field: statusword, held: 10}
  raw: {topic: "/drive/{drive}/state", field: statusword}
  code2: {signal: raw, held: 10}
events:
  a: {rise: code}
constraints:
  - {name: held somewhere, from: a, to: a, window: {min: 0, max: 0}}
"""


def test_held_counts_from_when_the_value_became_true_not_from_its_last_change():
    """`held: D`: "true only once the value has been true for D ms". A code that goes 3, 4,
    5, 6 (true all along) from 5 ms has been true for 10 ms at 15 ms."""
    src = MemorySource({STATE: [(round(t * MS), {"statusword": v}) for t, v in
                                [(0, 0), (5, 3), (8, 4), (12, 5), (20, 6), (40, 0)]]})
    ctx = context(loads_spec(HELD), src, binding=BIND)
    for name in ("code", "code2"):
        tr = ctx.trace(name)
        assert list(zip(tr.times, tr.values, strict=True)) == [
            (0, False), (15 * MS, True), (40 * MS, False)], name


def test_held_is_not_true_when_the_value_drops_before_d():
    src = MemorySource({STATE: [(round(t * MS), {"statusword": v}) for t, v in
                                [(0, 0), (5, 3), (9, 4), (14, 0), (30, 0)]]})
    tr = context(loads_spec(HELD), src, binding=BIND).trace("code")
    assert list(zip(tr.times, tr.values, strict=True)) == [(0, False)]


BRAKE = """\
id: brake
title: DO6 P1.042 after DI3
source: "test"
signals:
  A: {line: DI3}
  Y: {line: DO6}
events:
  a: {rise: A}
  y: {rise: Y, after: a}
constraints:
  - name: y after P1.042
    from: a
    to: y
    window: {min: "P1.042 - 1", max: "P1.042 + 1"}
"""


@pytest.mark.parametrize(("record", "status"), [
    # "a first value from a plain change (a write, a model ParamChanged) does not" cover the
    # times before it: P1.042 at the reference time (10 ms) is unknown
    ({"values": {"P1.042": 50}}, "inconclusive"),
    # "A parameter's first value from a snapshot or a read also covers the times before it"
    ({"snapshot": True, "values": {"P1.042": 50}}, "pass"),
    ({"source": "read", "values": {"P1.042": 50}}, "pass"),
])
def test_a_parameter_first_written_after_the_reference_time_is_not_in_force_there(
        record, status):
    src = MemorySource({dio("DI3"): levels((0, False), (10, True), (200, False)),
                        dio("DO6"): levels((0, False), (60, True), (200, False)),
                        PARAMS: [(150 * MS, record)]})
    [v] = check(loads_spec(BRAKE), src, binding=BIND)
    assert v.status == status, v.message
    if status == "inconclusive":
        assert "P1.042 is neither recorded nor given" in v.message


FORBID = """\
id: forbid
title: no DO3 rise tied to another event
source: "test"
signals:
  A: {line: DI3}
  C: {line: DI4}
  Y: {line: DO3}
events:
  a: {rise: A}
  c: {rise: C, after: a}
  y_after_c: {rise: Y, after: c}
  y_within: {rise: Y, after: a, within: 3}
constraints:
  - name: no Y after C
    from: a
    forbid: y_after_c
    window: {min: 0, max: 100}
  - name: no Y within 3 ms of A
    from: a
    forbid: y_within
    window: {min: 0, max: 100}
"""


@pytest.mark.parametrize(("y_at", "want"), [(20, ["pass", "pass"]), (60, ["fail", "pass"]),
                                            (2, ["pass", "fail"])])
def test_forbid_of_an_event_tied_to_another_is_that_event_not_every_edge(y_at, want):
    """`forbid`: "no occurrence of this event" in the window. `{rise: Y, after: c}` is the
    first Y rise after C (at 50 ms); a Y rise at 20 ms is not it."""
    src = MemorySource({dio("DI3"): levels((0, False), (1, True), (300, False)),
                        dio("DI4"): levels((0, False), (50, True), (300, False)),
                        dio("DO3"): levels((0, False), (y_at, True), (y_at + 5, False))})
    got = [v.status for v in check(loads_spec(FORBID), src, binding=BIND)]
    assert got == want


BEFORE = """\
id: before
title: the last time Y became true before A
source: "test"
signals:
  A: {line: DI3}
  Y: {line: DO3}
events:
  a: {rise: A}
  y_true: {first_true: Y, before: a}
constraints:
  - name: Y true before A
    from: y_true
    to: a
    window: {min: 0, max: 100}
"""


@pytest.mark.parametrize(("a_at", "measured"), [(31, 0.0), (40, 9.0), (25, 15.0), (15, 5.0)])
def test_first_true_before_an_event_is_the_last_time_it_became_true(a_at, measured):
    """`before:` "last occurrence at/before it": Y true over [10, 20) and again from 31; the
    instant Y became true last at or before A."""
    src = MemorySource({dio("DI3"): levels((0, False), (a_at, True), (200, False)),
                        dio("DO3"): levels((0, False), (10, True), (20, False), (31, True),
                                           (200, True))})
    [v] = check(loads_spec(BEFORE), src, binding=BIND)
    assert v.status == "pass" and v.measured_ms == measured, v.message


DEBOUNCED = """\
id: debounced
title: edges a 2 ms DI filter passes
source: "test"
signals:
  A: {line: DI3}
events:
  up: {rise: A, held: 2}
  down: {fall: A, held: 2}
constraints:
  - name: u
    for_each: up
    present: A
    at: up
  - name: d
    for_each: down
    absent: A
    at: down
"""


def test_a_held_edge_is_one_a_filter_of_that_length_passes():
    """docs/timing.md: `held: D` on an edge event counts a change once its new value has
    lasted D ms, stamped at the change; a bounce shorter than D is none, nor is the return
    to the value the filter still holds (a 1 ms release inside a press is no release, and
    the press after it no new press). helper-96: servo_on_brake took SON bounces for
    servo-ons and failed a right drive."""
    src = MemorySource({dio("DI3"): levels(
        (0, False), (10, True), (11, False), (12, True), (13, False),  # bounces: nothing
        (20, True),                                                   # a press: 20
        (40, False), (41, True),                                      # a 1 ms release: nothing
        (60, False), (61, True), (62, False), (70, False))})         # a release at 62
    ctx = context(loads_spec(DEBOUNCED), src, binding=BIND)
    assert [o.t for o in ctx.occurrences("up")] == [20 * MS]
    assert [o.t for o in ctx.occurrences("down")] == [62 * MS]
    # a level too near the end to tell is kept: the edge is not called a bounce
    src = MemorySource({dio("DI3"): levels((0, False), (10, True))})
    assert [o.t for o in context(loads_spec(DEBOUNCED), src, binding=BIND)
            .occurrences("up")] == [10 * MS]


def test_held_on_an_edge_needs_an_edge_kind():
    with pytest.raises(Exception, match="held"):
        loads_spec(DEBOUNCED.replace("  up: {rise: A, held: 2}", "  up: {first_true: A, held: 2}"))


def test_emgs_fails_a_drive_that_turns_the_servo_on_while_emgs_is_active():
    """EMGS is a level (L15184) and AL013 holds the servo off (L19338): a drive that comes
    back on with SON still held while EMGS stays active is wrong (helper-96 F6)."""
    from hil.paths import fixture
    from hil.timing.spec import load_spec

    def state(t, on, alarms):
        return (round(t * MS), {"servo_on": on, "torque_enabled": on, "speed_rpm": 0.0,
                                "alarms": alarms})

    src = MemorySource({
        dio("DI8"): levels((0, True), (100, False), (500, True), (600, True)),  # b-contact
        dio("DO6"): levels((0, True), (102, False), (600, False)),
        STATE: [state(0, True, []), state(102, False, ["AL013"]),
                state(300, True, ["AL013"]),  # back on under EMGS
                state(502, True, []), state(600, True, [])],
        PARAMS: [(0, {"P2.009": 2, "P1.043": 0, "P1.038": 100})]})
    verdicts = {v.constraint: v for v in check(load_spec(fixture("timing", "emgs.yaml")), src,
                                                binding=BIND)}
    v = verdicts["servo stays off while EMGS is active"]
    assert v.status == "fail", v.message


def test_a_held_edge_before_its_parameter_is_known_cannot_be_judged():
    """docs/timing.md: a first value from a plain write does not cover the time before it.
    A `held: "P2.009"` edge before P2.009's first record is not taken for a bounce on the
    strength of the later value (it had passed: helper-101); it cannot be judged."""
    from hil.timing.source import ParamTimeline

    spec = loads_spec(DEBOUNCED.replace("held: 2}", 'held: "P2.009"}'))
    src = MemorySource({dio("DI3"): levels((0, False), (100, True), (105, False),
                                           (200, True), (300, False), (2000, False))})
    late = ParamTimeline([(1000 * MS, {"P2.009": 10})])
    statuses = {v.status for v in check(spec, src, params=late, binding=BIND)}
    assert "pass" not in statuses and statuses & {"inconclusive", "skipped"}, statuses
