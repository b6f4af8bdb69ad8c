"""Accepted plans with hostile values, executed (wave 3, session 9): `hil run --check`
validates every field (test_hostile_steps.py), but a value the check lets through must also
run without an unexpected exception. Each case takes a shipped single-drive plan, puts one
plausible-but-odd value (0, -1, 2**31, a string where a number goes, ...) into one field of
one step; those the check accepts run in virtual time on the built-in bench. A step may pass,
fail or end in error with the harness's own explanation, never with a Python error (a
TypeError, KeyError, ...). An exploratory run of this found plc_program's expected values and
refused writes the route cannot carry raising TypeError / ValueError at run time."""

from __future__ import annotations

import copy
import dataclasses
import random
import re

import pytest
import yaml
from test_hostile_steps import _corpus  # one odd value in one field of one shipped plan

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.paths import fixture, plans_dir
from hil.plan.plan import loads_plan
from hil.plan.runner import check_plan, run_plan, timing_specs
from hil.units import S

pytestmark = pytest.mark.virtual_time

VALUES = [0, 1, -1, 2, 7, 99, 1000, 65535, 65536, 2**31 - 1, -(2**31), 2**31, 0.5, 1e-3,
          "0", "1ms", "0ms", "10s", "1us", "off", "on", True, False, "DI1", "DI8", "X0", "Y0",
          "ABS,,0,Ps", "ADR,-,1,Ps", "ADR,-,R4072,Ps", "R1000", "R4088", "D4000", [], [0],
          {}, "x"]
PYTHON_ERRORS = re.compile(r"^(TypeError|KeyError|AttributeError|IndexError|ZeroDivisionError|"
                           r"OverflowError|UnboundLocalError|NameError|AssertionError|"
                           r"RecursionError|ValueError|RuntimeError): ")


def _short(bench):
    """The bench with 5 s step, motion and homing timeouts (virtual time): a case whose odd
    value makes a step wait (a speed of 7) ends in the harness's timeout error soon, so the
    cost of a draw stays bounded; what is looked for is a Python error, not a verdict."""
    short = {"step": 5 * S, "target_reached": 5 * S, "homing": 5 * S}
    return dataclasses.replace(bench, timeouts={**bench.timeouts, **short})


def _accepted(seed: int, n: int, bench, specs, values: list = VALUES, folder=None):
    found = 0
    for name, text, case in _corpus(seed, 5000, values, folder):
        try:
            plan = loads_plan(text, name)
            check_plan(plan, bench, specs)
        except PlanFileError:
            continue
        yield plan, (name, *case)
        found += 1
        if found == n:
            return


@pytest.mark.parametrize("seed", [11, 13])
def test_accepted_odd_values_run_without_a_python_error(tmp_path, seed: int) -> None:
    bench = _short(dataclasses.replace(load_bench(None), clock="virtual"))
    specs = timing_specs()
    for k, (plan, case) in enumerate(_accepted(seed, 24, bench, specs)):
        r = run_plan(plan, bench, tmp_path / str(k), specs=specs, reports=False)
        bad = [(s.label, s.message) for s in r.steps
               if s.status == "error" and PYTHON_ERRORS.match(s.message or "")]
        assert not bad, (case, bad)


# the axis group's fields (seed 004): COMMAND codes and their Par numbers, axis names, cycles
GROUP_VALUES = [0, 1, -1, 2, 3, 4, 5, 6, 7, 8, 99, 65536, 2**31 - 1, -(2**31), 2**31, 0.5, 1e9,
                -1e9, 1e300, -0.0, "0", "1ms", "0ms", "2ms", "10s", "1us", "off", True, False,
                "axis1", "axis2", "axis9", [], [0], [0, 0], [1, 0], {}, "x", None]


def _reordered(seed: int, n: int, bench, specs, folder):
    """Accepted plans with one step deleted, doubled, swapped with another or moved (a
    group command before the group, a stop twice, a wait on a stopped group, ...)."""
    rng = random.Random(seed)
    plans = sorted(folder.glob("*.yaml"))
    found = 0
    for _ in range(500):
        p = rng.choice(plans)
        data = yaml.safe_load(p.read_text(encoding="utf-8"))
        st = data["steps"]
        op, i, j = rng.choice(("del", "dup", "swap", "move")), *rng.sample(range(len(st)), 2)
        if op == "del":
            del st[i]
        elif op == "dup":
            st.insert(j, copy.deepcopy(st[i]))
        elif op == "swap":
            st[i], st[j] = st[j], st[i]
        else:
            st.insert(j, st.pop(i))
        try:
            plan = loads_plan(yaml.safe_dump(data), p.name)
            check_plan(plan, bench, specs)
        except PlanFileError:
            continue
        yield plan, (p.name, op, i, j)
        found += 1
        if found == n:
            return


def test_accepted_odd_group_plans_run_without_a_python_error(tmp_path) -> None:
    """The shipped axis-group plans on their bench (fixtures/benches/virtual-group.yaml):
    one odd value in one field (COMMAND codes and Par values, gear ratios, ramp types, axes,
    cycles, expectations), or the steps out of their order."""
    bench = _short(load_bench(fixture("benches", "virtual-group.yaml")))
    assert bench.clock == "virtual"
    specs = timing_specs()
    folder = plans_dir() / "group"
    cases = [*_accepted(5, 4, bench, specs, GROUP_VALUES, folder),
             *_reordered(5, 4, bench, specs, folder)]
    assert len(cases) == 8
    for k, (plan, case) in enumerate(cases):
        r = run_plan(plan, bench, tmp_path / str(k), specs=specs, reports=False)
        bad = [(s.label, s.message) for s in r.steps
               if s.status == "error" and PYTHON_ERRORS.match(s.message or "")]
        assert not bad and not PYTHON_ERRORS.match(r.error or ""), (case, bad, r.error)
