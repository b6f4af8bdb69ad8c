"""Spec loading: every shipped spec loads; malformed specs get `file:line: field: what`."""

from __future__ import annotations

import pytest

from hil.timing.expr import Expr, ExprError
from hil.timing.spec import SpecError, load_spec, loads_spec, shipped_specs

EXPECTED = {"servo_on_brake", "servo_off_brake", "sto", "sto_reset", "sto_glitch", "alarm_reset",
            "emgs", "cia402_transitions"}


def test_every_shipped_spec_loads_and_cites_the_manual():
    paths = shipped_specs()
    assert {p.stem for p in paths} >= EXPECTED
    for p in paths:
        spec = load_spec(p)
        assert spec.id == p.stem
        # the A3 manual's lines (L...), or seed 001's for the PLC's own rules (001:...)
        assert ("L" in spec.source or "001:" in spec.source) and spec.constraints


GOOD = """\
id: demo
title: demo
source: "L1"
signals:
  SON: {function: SON}
  BRKR: {function: BRKR}
events:
  son: {rise: SON}
  brkr: {rise: BRKR, after: son}
constraints:
  - name: delay
    from: son
    to: brkr
    window: {min: "P1.042 - 1", max: "P1.042 + 1"}
"""


def test_good_minimal_spec_loads():
    spec = loads_spec(GOOD, "good.yaml")
    assert spec.constraints[0].window.min.params == ["P1.042"]


# (replace this, with that) in GOOD -> (line, field, words in the message)
BAD = [
    ("id: demo\n", "id: demo\ncolour: red\n", 2, "colour", "unknown key"),
    ("title: demo\n", "", 1, "(top)", "missing field 'title'"),
    ("  SON: {function: SON}", "  SON: {function: SONN}", 5, "signals.SON.function",
     "unknown function 'SONN'"),
    ("  SON: {function: SON}", "  SON: {topic: /dio/x/DI1}", 5, "signals.SON",
     "missing field 'field'"),
    ("  SON: {function: SON}", "  SON: {function: SON, colour: 1}", 5, "signals.SON.colour",
     "unknown key"),
    ("  son: {rise: SON}", "  son: {rise: SONX}", 8, "events.son.rise", "unknown signal 'SONX'"),
    ("  son: {rise: SON}", "  son: {jump: SON}", 8, "events.son", "needs exactly one of"),
    ("after: son}", "after: nobody}", 9, "events.brkr.after", "unknown event 'nobody'"),
    ("    to: brkr", "    to: brake", 13, "constraints[0].to", "unknown event 'brake'"),
    ('{min: "P1.042 - 1"', '{min: "P1.042 - "', 14, "constraints[0].window.min",
     "bad expression"),
    ('{min: "P1.042 - 1"', '{min: "P1.042 - tol"', 14, "constraints[0].window.min",
     "unknown name 'tol'"),
    ('{min: "P1.042 - 1"', '{min: "__import__(1)"', 14, "constraints[0].window.min",
     "only min, max, abs and bit"),
    ('window: {min: "P1.042 - 1", max: "P1.042 + 1"}', "window: {}", 14,
     "constraints[0].window", "needs `min`, `max` or both"),
    ('window: {min: "P1.042 - 1", max: "P1.042 + 1"}', "window: {low: 1}", 14,
     "constraints[0].window.low", "unknown key"),
    ("    window: {min", "    windw: {min", 14, "constraints[0].windw", "unknown key"),
    ("    to: brkr\n", "", 11, "constraints[0]", "missing field 'to'"),
    ("  - name: delay\n", "  - name: delay\n    when: SON and P1.042 >> 2\n", 12,
     "constraints[0].when", "not allowed"),
    ("  SON: {function: SON}", "  SON: {line: DIX}", 5, "signals.SON.line", "is not a line"),
    ("  SON: {function: SON}", "  SON: {alarm: E500}", 5, "signals.SON.alarm",
     "not an alarm code"),
    ("  SON: {function: SON}", "  SON: {function: SON}\n  SON: {function: ARST}", 6,
     "signals.SON", "duplicate key"),
    ("  SON: {function: SON}", "  SON: {function: SON", 6, "(yaml)", ""),
    ("constraints:\n  - name", "constraints: []\nnotes:\n  - name", 10, "constraints",
     "non-empty list"),
    ("  SON: {function: SON}", "  SON: {not: SON}", 5, "signals.SON", "depends on itself"),
    ("  SON: {function: SON}", "  SON: {function: SON}\n  S2: {signal: SON, below: tol}", 6,
     "signals.S2.below", "unknown name 'tol'"),
]


@pytest.mark.parametrize("old,new,line,where,words", BAD, ids=[b[3] + ":" + b[4] for b in BAD])
def test_malformed_spec_is_rejected_precisely(old, new, line, where, words):
    assert old in GOOD
    text = GOOD.replace(old, new, 1)
    with pytest.raises(SpecError) as ei:
        loads_spec(text, "bad.yaml")
    e = ei.value
    assert str(e).startswith(f"bad.yaml:{e.line}: {e.where}: ")
    assert (e.line, e.where) == (line, where), str(e)
    assert words in e.what, str(e)


def test_bad_spec_file_names_file_and_line(tmp_path):
    p = tmp_path / "broken.yaml"
    p.write_text(GOOD.replace("    to: brkr", "    to: 12"), encoding="utf-8")
    with pytest.raises(SpecError, match=r"broken\.yaml:13: constraints\[0\]\.to: unknown event"):
        load_spec(p)
    with pytest.raises(SpecError, match=r"missing\.yaml:0: \(file\): cannot read"):
        load_spec(tmp_path / "missing.yaml")


def test_expressions_resolve_parameters_units_and_functions():
    assert Expr("P1.042 + 1").eval({"P1.042": 150}) == 151
    assert Expr("max(P1.043, 0)").eval({"P1.043": -20}) == 0
    assert Expr("1 s + 500 us").eval({}) == pytest.approx(1000.5)
    assert Expr("P1.038 / 10").eval({"P1.038": 100}) == 10
    assert Expr("not fault and P1.043 >= 0").eval({"fault": False, "P1.043": 0})
    with pytest.raises(ExprError):
        Expr("P1.042.x")
    with pytest.raises(KeyError):
        Expr("P1.042").eval({})
