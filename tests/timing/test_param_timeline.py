"""Parameters over time (/drive/<d>/params): a snapshot's or a read's first value covers the
times before it, a plain change does not; which parameters a spec reads."""

from __future__ import annotations

import pytest

from hil.timing.checker import check
from hil.timing.registry import load_specs
from hil.timing.source import MemorySource, ParamTimeline
from hil.timing.spec import loads_spec, spec_params

PARAMS = "/drive/drive1/params"
MS = 1_000_000
SPECS = load_specs()


def timeline(*records: tuple[int, dict]) -> ParamTimeline:
    return ParamTimeline.from_source(MemorySource({PARAMS: list(records)}), PARAMS)


def test_a_change_before_the_first_snapshot_does_not_hide_the_snapshot():
    # the subprocess bench: the drive process reports a P5.011 change, then its snapshot
    tl = timeline((0, {"snapshot": False, "values": {"P5.011": 1}}),
                  (5, {"snapshot": True, "values": {"P5.011": 2, "P5.008": 0}}),
                  (9, {"snapshot": False, "values": {"P5.008": 100000}}))
    assert tl.at(0) == {"P5.011": 1, "P5.008": 0}
    assert tl.at(None) == {"P5.011": 1, "P5.008": 0}
    assert tl.at(9) == {"P5.011": 2, "P5.008": 100000}


def test_a_read_covers_the_times_before_it_a_write_does_not():
    read = timeline((0, {"values": {"P1.043": 5}}),
                    (50, {"snapshot": False, "source": "read", "values": {"P1.042": 150}}))
    assert read.at(20) == {"P1.043": 5, "P1.042": 150}
    write = timeline((0, {"values": {"P1.043": 5}}), (50, {"values": {"P1.042": 150}}))
    assert write.at(20) == {"P1.043": 5}
    assert write.at(50) == {"P1.043": 5, "P1.042": 150}


def test_a_read_after_a_recorded_change_does_not_reach_back_past_it():
    tl = timeline((0, {"values": {"P1.043": 5}}), (10, {"values": {"P1.042": 100}}),
                  (50, {"source": "read", "values": {"P1.042": 100}}))
    assert "P1.042" not in tl.at(5)
    assert tl.names() == {"P1.043", "P1.042"}


BEYOND = """\
id: beyond
title: the feedback passes P5.008 10 ms after the start
source: "P5.008 L11191"
signals:
  pos: {topic: "/drive/{drive}/state", field: position_puu}
  beyond: {signal: pos, above: P5.008}
  go: {topic: "/drive/{drive}/state", field: servo_on}
events:
  start: {rise: go}
  past: {first_true: beyond, after: start}
constraints:
  - name: past P5.008 after 10 ms
    from: start
    to: past
    window: {min: 10, max: 10}
"""


def test_a_threshold_on_a_parameter_is_judged_after_an_early_change():
    """`above: P5.008` is evaluated at every parameter change, the first one included: with
    the subprocess bench's snapshot after an early change, P5.008 was "neither recorded nor
    given" there."""
    state = [(0, {"position_puu": 0, "servo_on": False}),
             (MS, {"position_puu": 0, "servo_on": True}),
             (11 * MS, {"position_puu": 200000, "servo_on": True})]
    src = MemorySource({PARAMS: [(0, {"values": {"P5.011": 1}}),
                                 (MS, {"snapshot": True, "values": {"P5.008": 100000}})],
                        "/drive/drive1/state": state})
    [v] = check(loads_spec(BEYOND), src, binding={"drive": "drive1"})
    assert v.status == "pass", v.message


def test_spec_params_lists_the_parameters_of_windows_thresholds_and_constants():
    assert spec_params(SPECS["servo_on_brake"]) == {"P1.042", "P2.009"}
    assert spec_params(SPECS["servo_off_brake"]) == {"P1.038", "P1.043"}
    assert spec_params(SPECS["pr_soft_limit"]) == {"P2.009", "P5.008"}
    assert spec_params(SPECS["sto"]) == set()


def test_a_threshold_that_changes_mid_recording_applies_from_each_change_on():
    """`above: P5.008` where P5.008 is written three times while the position sits still and
    moves: each sample is compared with the value in force at its own time (a sample at a
    change time takes the new value), in time order or not (L11191)."""
    from hil.timing.checker import context

    writes = [(0, 300000), (5 * MS, 100000), (8 * MS, 250000), (12 * MS, 50000)]
    pos = {t * MS: p for t, p in [(0, 0), (2, 200000), (4, 200000), (5, 200000), (6, 200000),
                                  (8, 200000), (9, 260000), (11, 260000), (12, 60000),
                                  (13, 40000)]}
    in_force = ParamTimeline.from_source(
        MemorySource({PARAMS: [(t, {"values": {"P5.008": v}}) for t, v in writes]}), PARAMS)
    want = [(t, p > in_force.at(t)["P5.008"]) for t, p in sorted(pos.items())]
    # the change points the samples give, one per change of the value
    want = [pt for i, pt in enumerate(want) if i == 0 or pt[1] != want[i - 1][1]]
    assert want == [(0, False), (5 * MS, True), (8 * MS, False), (9 * MS, True),
                    (13 * MS, False)]
    for order in (sorted(pos.items()), sorted(pos.items(), reverse=True)):
        state = [(t, {"position_puu": p, "servo_on": True}) for t, p in order]
        src = MemorySource({PARAMS: [(t, {"values": {"P5.008": v}}) for t, v in writes],
                            "/drive/drive1/state": state})
        tr = context(loads_spec(BEYOND), src, binding={"drive": "drive1"}).trace("beyond")
        assert list(zip(tr.times, tr.values, strict=True)) == want


THROUGH = BEYOND.replace("above: P5.008}", "above: lim}").replace(
    "signals:", "constants:\n  lim: \"P5.008 / 2\"\nsignals:")


def test_a_limit_is_looked_up_again_only_where_a_parameter_it_reads_changed():
    """A threshold through a constant (`lim: P5.008 / 2`) amid writes of parameters it does
    not read (P1.038, P2.009 every millisecond): the trace is the one every write gives, and
    the limit's own change times are the first record and the P5.008 writes only."""
    from hil.timing.checker import context

    writes = [(0, 600000), (5 * MS, 200000), (8 * MS, 500000), (12 * MS, 100000)]
    noise = [(t * MS + 500_000, {"values": {"P1.038": t, "P2.009": 2 * t}}) for t in range(14)]
    records = sorted([(t, {"values": {"P5.008": v}}) for t, v in writes] + noise,
                     key=lambda r: r[0])
    pos = {t * MS: p for t, p in [(0, 0), (2, 200000), (4, 200000), (5, 200000), (6, 200000),
                                  (8, 200000), (9, 260000), (11, 260000), (12, 60000),
                                  (13, 40000)]}
    in_force = ParamTimeline.from_source(MemorySource({PARAMS: records}), PARAMS)
    assert in_force.change_times(["P5.008"]) == [t for t, _v in writes]
    assert in_force.change_times(["P1.038"]) == [0] + [t for t, _r in noise]
    assert len(in_force.change_times()) == len(writes) + len(noise)
    want = [(t, p > in_force.at(t)["P5.008"] / 2) for t, p in sorted(pos.items())]
    want = [pt for i, pt in enumerate(want) if i == 0 or pt[1] != want[i - 1][1]]
    assert want == [(0, False), (5 * MS, True), (8 * MS, False), (9 * MS, True),
                    (13 * MS, False)]
    state = [(t, {"position_puu": p, "servo_on": True}) for t, p in sorted(pos.items())]
    ctx = context(loads_spec(THROUGH), MemorySource({PARAMS: records,
                                                    "/drive/drive1/state": state}),
                  binding={"drive": "drive1"})
    tr = ctx.trace("beyond")
    assert list(zip(tr.times, tr.values, strict=True)) == want
    span = ctx._thresholds(ctx.spec.signals["beyond"].transforms)
    assert span.times == [t for t, _v in writes]
    # a constant given by the check reads no parameter: one value throughout
    given = context(loads_spec(THROUGH), MemorySource({PARAMS: records,
                                                      "/drive/drive1/state": state}),
                    binding={"drive": "drive1"}, constants={"lim": 150000})
    assert given._thresholds(given.spec.signals["beyond"].transforms).constant


RATIO = THROUGH.replace('lim: "P5.008 / 2"', 'lim: "P5.008 / 2"\n  ratio: "1000 / P1.038"')


@pytest.mark.parametrize(("above", "status"), [
    ("lim", "pass"),                           # the limit does not read `ratio`
    ("lim * ratio / 200", "inconclusive"),     # it does: 1000 / 0 once P1.038 = 0
])
def test_a_limit_is_judged_with_the_constants_it_reads_only(above, status):
    """A constant the limit does not read (`ratio`, 1000 / P1.038) failing after the
    constraint's reference time, where P1.038 is written 0: the limit is judged; one that
    reads it cannot judge. (Every limit of the spec had been "cannot judge". A window is
    still evaluated with every constant at its reference time.)"""
    first = 5
    spec = loads_spec(RATIO.replace("above: lim}", f"above: \"{above}\"}}"))
    state = [(0, {"position_puu": 0, "servo_on": False}),
             (MS, {"position_puu": 0, "servo_on": True}),
             (11 * MS, {"position_puu": 200000, "servo_on": True})]
    params = [(0, {"snapshot": True, "values": {"P5.008": 300000, "P1.038": first}}),
              (20 * MS, {"values": {"P1.038": 0}})]
    [v] = check(spec, MemorySource({PARAMS: params, "/drive/drive1/state": state}),
                binding={"drive": "drive1"})
    assert v.status == status, v.message
    if status == "inconclusive":
        assert "division by zero" in v.message
