"""Step kinds: one class per YAML key, found through a registry that entry points extend
(issue 17 item 4), and the bench policy the classes declare (virtual only, motion)."""

from __future__ import annotations

from dataclasses import replace
from typing import Any

import pytest

import hil.plan.kinds as kinds_mod
from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.plan.context import Outcome
from hil.plan.kinds import BUILTIN, StepKind, kinds
from hil.plan.plan import check_plan, loads_plan
from hil.plan.runner import timing_specs


def test_every_builtin_kind_is_a_named_class_with_its_own_key():
    assert len(BUILTIN) >= 26
    for name, cls in BUILTIN.items():
        assert issubclass(cls, StepKind) and cls.name == name
        assert cls.parse is not StepKind.parse, f"{name} does not parse"
        assert cls.run is not StepKind.run, f"{name} does not run"


def test_parsed_step_holds_an_instance_of_its_kind():
    plan = loads_plan("name: p\nsteps:\n  - write: {P1.042: 150}\n  - wait: 20ms\n"
                      "  - check_timing: brake_servo_off\n")
    kinds_seen = [type(s.action).__name__ for s in plan.steps]
    assert kinds_seen == ["Write", "Wait", "CheckTiming"]
    assert plan.steps[0].label == "write P1.042=150"  # the bench's param_via: no "via -"
    assert loads_plan("name: p\nsteps:\n  - read: {P1.042: null, via: sdo}\n"
                      ).steps[0].label == "read P1.042 via sdo"
    assert plan.steps[1].imposed_ns == 20_000_000
    assert plan.steps[2].action.judge_only and not plan.steps[0].action.judge_only


class _Beep(StepKind):
    name = "beep"

    @classmethod
    def parse(cls, v, obj, line, where) -> dict[str, Any]:
        if not isinstance(obj, int):
            raise v.err(line, where, "beep: a count")
        return {"n": obj}

    def run(self, ctx, step, d) -> Outcome:
        return Outcome("beep" * self.args["n"])

    def describe(self) -> str:
        return f"beep x{self.args['n']}"


class _EP:
    def __init__(self, value: Any, name: str = "beep") -> None:
        self.name, self.value, self._v = name, f"tests:{name}", value

    def load(self) -> Any:
        return self._v


@pytest.fixture
def entry_points(monkeypatch):
    def install(*eps: _EP) -> None:
        monkeypatch.setattr(kinds_mod, "_loaded", None)
        monkeypatch.setattr(kinds_mod, "entry_points", lambda group: list(eps)
                            if group == "hil.steps" else [])
    yield install
    kinds_mod._loaded = None


def test_an_entry_point_adds_a_step_kind(entry_points):
    entry_points(_EP(_Beep))
    assert kinds()["beep"] is _Beep
    plan = loads_plan("name: p\nsteps:\n  - beep: 3\n")
    assert plan.steps[0].label == "beep x3"
    check_plan(plan, load_bench(), timing_specs())
    with pytest.raises(PlanFileError, match=r"<string>:3: steps\[0\]\.beep: beep: a count"):
        loads_plan("name: p\nsteps:\n  - beep: loud\n")


def test_an_entry_point_may_not_replace_a_builtin_kind_or_be_no_kind(entry_points):
    clash = type("Write2", (_Beep,), {"name": "write"})
    entry_points(_EP(clash))
    with pytest.raises(TypeError, match="step kind 'write' exists already"):
        kinds()
    entry_points(_EP(object))
    with pytest.raises(TypeError, match="not a StepKind subclass"):
        kinds()


def test_unknown_kind_lists_the_registered_ones():
    with pytest.raises(PlanFileError, match=r"unknown step kind; known: di, pulse, .*pr_wait"):
        loads_plan("name: p\nsteps:\n  - frobnicate: 1\n")


@pytest.mark.parametrize("step", ["pr_trigger: {pr: 1}", "move: {mode: PV, velocity: 10}",
                                  "home: {method: 3}"])
def test_motion_kinds_are_refused_on_a_bench_without_motion(step):
    bench = replace(load_bench(), motion_allowed=False)
    plan = loads_plan(f"name: p\nsteps:\n  - {step}\n")
    with pytest.raises(PlanFileError, match="motion is not allowed"):
        check_plan(plan, bench, timing_specs())


def test_virtual_only_kinds_are_refused_on_a_real_bench():
    bench = replace(load_bench(), virtual=False)
    plan = loads_plan("name: p\nsteps:\n  - power_cycle: true\n")
    with pytest.raises(PlanFileError, match=r"steps\[0\]\.power_cycle: only on a virtual bench"):
        check_plan(plan, bench, timing_specs())
