"""Timing specs as a stranger writes them, from an outside fuzz (helper-41): each case seen
failing (a hang, a traceback, a silent pass) before its fix."""

from __future__ import annotations

import pytest

from hil.terminal import terminal_text
from hil.timing.checker import check
from hil.timing.spec import MAX_CHAIN, SpecError, loads_spec

from .trace import STATE, source

HEAD = """id: m
title: t
source: s
"""
SRC = source({(STATE, "speed_rpm"): [(0, 0.0), (10, 5.0), (20, 500.0), (30, 0.0)],
              (STATE, "homing_phase"): [(0, ""), (10, "search"), (30, "")],
              (STATE, "alarms"): [(0, []), (30, [])]},
             params={"P1.042": 0})


def _spec(body: str):
    return loads_spec(HEAD + body, "m.yaml")


@pytest.mark.timeout(30)
def test_shared_composite_events_are_labelled_without_exponential_text():
    """40 levels of earliest_of/latest_of sharing their parts: each composite's label spelt
    out every level below, 2^40 texts (a hang); nested composites are now named."""
    lines = ["signals:", "  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}",
             "events:", "  start: {rise: v}"]
    depth = 40
    for i in range(depth):
        lines += [f"  e{i}: {{earliest_of: [e{i + 1}, f{i + 1}]}}",
                  f"  f{i}: {{latest_of: [e{i + 1}, f{i + 1}]}}"]
    lines += [f"  e{depth}: {{rise: v}}", f"  f{depth}: {{fall: v}}",
              "constraints:", "  - {name: c, from: start, to: e0, window: {max: 100000}}"]
    [v] = check(_spec("\n".join(lines) + "\n"), SRC)
    assert v.status in ("pass", "fail") and len(v.message) < 300, v.message


@pytest.mark.parametrize("kind", ["constants", "signals", "events"])
def test_a_chain_deeper_than_max_chain_is_refused_at_load(kind):
    n = MAX_CHAIN + 10
    if kind == "constants":
        body = ("constants:\n" + "".join(f"  c{i}: c{i + 1}\n" for i in range(n))
                + f"  c{n}: 1\nsignals:\n  v: {{topic: \"/drive/{{drive}}/state\", field: "
                "speed_rpm, above: c0}\n")
    elif kind == "signals":
        body = ("signals:\n  s0: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
                + "".join(f"  s{i + 1}: {{not: s{i}}}\n" for i in range(n)))
        body = body.replace("s0:", "v:", 1).replace("{not: s0}", "{not: v}")
    else:
        body = ("signals:\n  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
                "events:\n  e0: {rise: v}\n"
                + "".join(f"  e{i + 1}: {{rise: v, after: e{i}}}\n" for i in range(n)))
    body += ("events:\n  start: {rise: v}\n" if kind != "events" else "") + \
        "constraints:\n  - {name: c, from: start, to: start, window: {max: 1}}\n"
    body = body.replace("to: start", "to: e0" if kind == "events" else "to: start")
    body = body.replace("from: start", "from: e0" if kind == "events" else "from: start")
    with pytest.raises(SpecError, match=rf"a chain of more than {MAX_CHAIN} {kind}"):
        _spec(body)


@pytest.mark.parametrize("bad", ["{rise: [v]}", "{rise: {a: 1}}", "{earliest_of: [[start], e]}"])
def test_a_list_or_mapping_where_a_name_belongs_is_a_spec_error(bad):
    with pytest.raises(SpecError, match=r"m\.yaml:\d+: events\.x"):
        _spec("signals:\n  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
              f"events:\n  start: {{rise: v}}\n  e: {{fall: v}}\n  x: {bad}\n"
              "constraints:\n  - {name: c, from: start, to: x, window: {max: 1}}\n")
    with pytest.raises(SpecError, match=r"constraints\[0\]\.present: unknown signal"):
        _spec("signals:\n  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
              "events:\n  start: {rise: v}\n"
              "constraints:\n  - {name: c, present: [v], at: start}\n")


@pytest.mark.parametrize("field, tf", [("homing_phase", "bit: 3"),
                                       ("homing_phase", "mask: 255, equals: 1"),
                                       ("alarms", "above: 1"), ("alarms", "abs: true")])
def test_a_transform_on_a_field_of_another_type_cannot_judge(field, tf):
    """A bit of a text, a comparison of a list: inconclusive with the value, not a traceback."""
    spec = _spec(f"signals:\n  v: {{topic: \"/drive/{{drive}}/state\", field: {field}, {tf}}}\n"
                 "  s: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
                 "events:\n  start: {rise: s}\n"
                 "constraints:\n  - {name: c, present: v, at: start}\n")
    [v] = check(spec, SRC)
    assert v.status == "inconclusive" and "cannot judge: signal v: the recorded value" in \
        v.message, v.message


def test_a_field_a_closed_hil_schema_lacks_is_refused_at_load():
    with pytest.raises(SpecError, match=r"signals\.v\.field: 'nosuchfield': "
                                        r"/drive/\{drive\}/state \(hil\.DriveState\) has no"):
        _spec("signals:\n  v: {topic: \"/drive/{drive}/state\", field: nosuchfield}\n"
              "events:\n  start: {rise: v}\n"
              "constraints:\n  - {name: c, present: v, at: start}\n")


def test_a_duration_or_window_made_impossible_by_a_parameter_cannot_judge():
    base = ("signals:\n  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
            "events:\n  start: {rise: v}\n  stop: {fall: v, after: start, within: %s}\n"
            "constraints:\n  - {name: c, from: start, to: stop, window: {min: %s, max: %s}}\n")
    [v] = check(_spec(base % ("\"P1.042 - 5\"", "0", "100")), SRC)
    assert v.status == "inconclusive" and "a duration cannot be negative" in v.message
    [v] = check(_spec(base % ("1000", "\"20 + P1.042\"", "\"10 + P1.042\"")), SRC)
    assert v.status == "inconclusive" and "window min 20 ms > max 10 ms" in v.message
    [v] = check(_spec(base % ("1000", "0", "100")), SRC)
    assert v.status == "pass"  # the same spec with sane values judges


def test_spec_text_is_made_safe_for_a_terminal():
    assert terminal_text("c\x1b[2J\x1b[H") == "c\\x1b[2J\\x1b[H"
    assert terminal_text("x" * 1000).endswith("... (1000 characters)")


def test_skipped_messages_make_a_passing_check_incomplete(capsys):
    """An outside review: `hil check` could exit 0 after skipping messages it could not read;
    what they said is not in the verdicts, so a pass is incomplete (exit 4)."""
    from types import SimpleNamespace

    from hil.timing.checker import Verdict
    from hil.timing.cli import EXIT_INCOMPLETE, EXIT_PASS, final_code

    v = [Verdict("m", "c", "pass", "ok")]
    src = SimpleNamespace(path="r.mcap", corrupt=False, error=None, truncated=False,
                          bad_messages=0)
    assert final_code(v, src, []) == EXIT_PASS
    src.bad_messages = 2
    assert final_code(v, src, []) == EXIT_INCOMPLETE
    assert "2 message(s) of a wrong shape were skipped" in capsys.readouterr().err


def test_a_parameter_no_drive_has_is_refused_at_load():
    """`P9.999` in a window was judged inconclusive ("neither recorded nor given: --param
    P9.999=...") while `--param P9.999=3` was refused as unknown (helper-103, session 28)."""
    base = ("signals:\n  v: {topic: \"/drive/{drive}/state\", field: speed_rpm, above: 1}\n"
            "events:\n  start: {rise: v}\n  stop: {fall: v, after: start, within: 1000}\n"
            "constraints:\n  - {name: c, from: start, to: stop, window: {min: 0, max: %s}}\n")
    with pytest.raises(SpecError, match=r"m\.yaml:\d+: constraints\[0\]\.window\.max: unknown "
                                        r"parameter 'P9\.999'"):
        _spec(base % "\"P9.999 + 1\"")
    [v] = check(_spec(base % "\"P1.042 + 100\""), SRC)
    assert v.status == "pass"
