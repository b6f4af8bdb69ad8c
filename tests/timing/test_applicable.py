"""`hil check` with every shipped spec judges a spec only where its scenario can be: its DI/DO
functions on lines the drive maps to them (P2.010-P2.022, P2.036-P2.041, L15243) and its
`requires:` parameters held at some time. Unknown (not recorded) counts as applicable."""

from __future__ import annotations

import json

import pytest

from hil.cli import main as hil
from hil.record import topics
from hil.record.recorder import Recorder
from hil.timing import MemorySource
from hil.timing.applicable import mapping_param, not_applicable
from hil.timing.spec import SpecError, loads_spec

MS = 1_000_000
SPEC = """
id: brake
title: a DO function on DO6
source: "-"
bind: {BRKR: DO6}
signals:
  SON: {function: SON}
  BRKR: {function: BRKR}
events:
  son_in: {rise: SON}
  brkr: {rise: BRKR, after: son_in, within: 1000}
constraints:
  - {name: BRKR after SON, from: son_in, to: brkr, window: {max: 200}}
"""
PARAMS = topics.drive_params("drive1")


def _src(*records: dict) -> MemorySource:
    return MemorySource({PARAMS: [(k * MS, {"values": r}) for k, r in enumerate(records)]})


def test_mapping_params_of_lines():
    assert mapping_param("DI1") == ("P2.010", mapping_param("DI1")[1])
    assert mapping_param("DI9")[0] == "P2.036" and mapping_param("DO6")[0] == "P2.041"
    assert mapping_param("DO5")[0] == "P2.022"
    assert mapping_param("STO_A") is None and mapping_param("DO7") is None


def test_a_function_the_drive_never_maps_there_is_not_applicable():
    spec = loads_spec(SPEC)
    why = not_applicable(spec, _src({"P2.010": 0x0101, "P2.041": 0x0105}), {})
    assert why == "DO6 is not BRKR on this drive (P2.041 = 0x0105; BRKR is 0x08)"
    # mapped at some time (a plan that remaps DO6 midway): applicable
    assert not_applicable(spec, _src({"P2.041": 0x0105}, {"P2.041": 0x0108}), {}) is None
    assert not_applicable(spec, _src({"P2.010": 0x0101}), {}) is None  # DO6 not recorded
    assert not_applicable(spec, MemorySource({}), {}) is None  # a real bench: nothing known
    # the binding decides the line: BRKR on DO4, which is 0x0108 here
    assert not_applicable(spec, _src({"P2.021": 0x0108, "P2.041": 0x0105}),
                          {"BRKR": "DO4"}) is None


def test_a_line_that_changed_only_while_it_was_another_function_is_not_applicable():
    """The factory mapping is recorded before a plan's own (plc_inhp_cclr: DI8 = INHP, not
    EMGS): `hil check` with every shipped spec judged `emgs` on DI8's INHP edges and failed a
    passing plan. The mapping in force when the line changed decides."""
    spec = loads_spec(SPEC)
    di1 = topics.dio("drive1", "DI1")

    def src(changes_ms: list[int]) -> MemorySource:
        return MemorySource({
            PARAMS: [(0, {"values": {"P2.010": 0x0101}}), (5 * MS, {"values": {"P2.010": 0x0145}})],
            di1: [(0, {"level": False})] + [(t * MS, {"level": bool(i % 2 == 0)})
                                            for i, t in enumerate(changes_ms)],
        })

    why = not_applicable(spec, src([10, 20]), {})
    assert why == ("DI1 never changed while it was SON (P2.010 = 0x0101, 0x0145; SON is 0x01)")
    assert not_applicable(spec, src([3, 10]), {}) is None  # one change while it was SON


def test_requires_must_hold_at_some_time():
    spec = loads_spec(SPEC + 'requires: "bit(P5.059, 0) == 1"\n')
    assert "never held" in not_applicable(spec, _src({"P5.059": 0x0030}), {})
    assert not_applicable(spec, _src({"P5.059": 0x0030}, {"P5.059": 0x0031}), {}) is None
    assert not_applicable(spec, _src({"P1.001": 0}), {}) is None  # P5.059 not recorded
    with pytest.raises(SpecError, match=r"requires: unknown name 'tol'"):
        loads_spec(SPEC + 'requires: "tol > 1"\n')


def test_hil_check_every_spec_skips_what_does_not_apply_but_judges_an_asked_spec(
        tmp_path, capsys):
    """A recording whose DO6 is TPOS with a SON edge and no BRKR: every shipped spec says
    the brake spec does not apply, and nothing fails; asked for by name, it is judged."""
    path = tmp_path / "run.mcap"
    rec = Recorder(path)
    t0 = 1_700_000_000_000_000_000
    params = {"P2.010": 0x0101, "P2.041": 0x0105, "P1.042": 0, "P1.043": 0, "P2.009": 2}
    rec.drive_params("drive1", params, snapshot=True, t=t0)
    rec.dio("drive1", "DI1", False, t0, None)
    rec.dio("drive1", "DO6", False, t0, None)
    rec.dio("drive1", "DI1", True, t0 + 100 * MS, None)
    rec.drive_state("drive1", {"servo_on": False, "alarms": []}, t=t0)
    rec.close()
    code = hil(["check", str(path), "--json"])
    vs = json.loads(capsys.readouterr().out)
    brake = [v for v in vs if v["spec"] == "servo_on_brake"]
    assert brake and all(v["status"] == "skipped" and "DO6 is not BRKR" in v["message"]
                         for v in brake), brake
    assert not [v for v in vs if v["status"] == "fail"], [v for v in vs if v["status"] == "fail"]
    assert code != 1  # no failure (a partial synthetic recording leaves some inconclusive)
    assert hil(["check", str(path), "--spec", "servo_on_brake", "--json"]) != 0
    asked = json.loads(capsys.readouterr().out)  # judged: the wiring is the user's to fix
    assert [v for v in asked if v["status"] != "skipped"]
    assert not [v for v in asked if "DO6 is not BRKR" in v["message"]]
