"""Hostile values in every field of every shipped plan's steps (issue 23 item 2).

A seeded, generated corpus: each case takes a shipped plan, puts one hostile value (a
non-ASCII digit, a 400-digit duration, NaN, an empty list, a huge integer, ...) into one field
of one step, and runs `hil run --check`'s validation (`loads_plan` + `check_plan` against the
built-in virtual bench). Every case is either accepted or refused with `file:line: field`;
none may escape as another exception. Then one test per class the issue names, each refused.
"""

from __future__ import annotations

import copy
import random
from pathlib import Path

import pytest
import yaml
from test_hostile_yaml import _paths as _leaves  # every key and index path of a tree

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.paths import plans_dir
from hil.plan.plan import loads_plan
from hil.plan.runner import check_plan, timing_specs

HOSTILE = ["²", "٣", "", "9" * 400, "9" * 400 + "ms", "9" * 20 + ".5s", ".nan", "nan",
           float("nan"), float("inf"), -1, 2**40, -(2**70), "abc", [], {}, None, True, "1e400",
           "0x", "DI99", 0, 1e-9, "1ns", 256, 0x10000, "0x1017", "x" * 5000, "DI²",
           {"a": [1, {"b": None}]}, [[[]]], "P9.999", "AL999", "\u202e", "0000"]


@pytest.fixture(scope="module")
def world():
    return load_bench(None), timing_specs()


def _set(obj, path, value):
    for p in path[:-1]:
        obj = obj[p]
    obj[path[-1]] = value


def _corpus(seed: int, n: int, values: list = HOSTILE, folder: Path | None = None):
    """`n` draws: (plan file name, the plan with one step field set to one of `values`,
    (step index, field path, value)); a step with no field is skipped. `folder`: where the
    plans are (default: the shipped single-drive plans)."""
    rng = random.Random(seed)
    plans = sorted(Path(folder or plans_dir()).glob("*.yaml"))
    raw = {p: yaml.safe_load(p.read_text(encoding="utf-8")) for p in plans}
    for _ in range(n):
        p = rng.choice(plans)
        data = copy.deepcopy(raw[p])
        i = rng.randrange(len(data["steps"]))
        paths = list(_leaves(data["steps"][i]))
        if not paths:
            continue
        where = rng.choice(paths)
        value = rng.choice(values)
        _set(data["steps"][i], where, value)
        yield p.name, yaml.safe_dump(data, allow_unicode=True), (i, where, value)


@pytest.mark.parametrize("seed", range(4))
def test_no_hostile_step_value_escapes_as_a_traceback(world, seed: int) -> None:
    bench, specs = world
    refused = 0
    for name, text, case in _corpus(seed, 300):
        try:
            check_plan(loads_plan(text, name), bench, specs)
        except PlanFileError as e:
            refused += 1
            assert str(e).startswith(f"{name}:"), (case, e)
            assert len(str(e)) < 600, (case, str(e)[:200])  # the value is shortened
        except Exception as e:
            pytest.fail(f"{name} step {case[0]} {case[1]} = {case[2]!r:.40}: "
                        f"{type(e).__name__}: {e}")
    assert refused > 150  # the corpus is hostile: most cases must be refused


PLAN = """name: p
steps:
  - {step}
"""

REFUSED = [
    # unknown `via:` on every PR / capture step
    ("pr_trigger: {pr: 1, via: ethercat}", "via"),
    ("pr_wait: {pr: 1, via: 7}", "via"),
    ("capture_arm: {via: [modbus]}", "via"),
    ("compare_table: {positions: [1], via: profinet}", "via"),
    ("latch: {tolerance: 5, via: x}", "via"),
    # a PR type outside the table, data over 32 bits
    ("pr_table: {1: {type: 99, data: 1}}", "type"),
    ("pr_table: {1: {type: single, data: 4294967296}}", "data"),
    ("pr_table: {1: {type: single, data: -2147483649}}", "data"),
    # NaN tolerances and windows, latch start / count
    ("latch: {tolerance: .nan}", "tolerance"),
    ("latch: {tolerance: .inf}", "tolerance"),
    ("latch: {tolerance: 5, window: {min: .nan}}", "min"),
    ("latch: {tolerance: 5, start: abc}", "start"),
    ("latch: {tolerance: 5, count: 100000000}", "count"),
    # faults: empty COB-ID, too many data bytes, periods the bus cannot carry
    ("fault: {can: drop, match: {cob_id: []}}", "cob_id"),
    ("fault: {can: duplicate_pdo, cob_id: [], data: '00'}", "cob_id"),
    ("fault: {can: duplicate_pdo, cob_id: 0x201, data: '000102030405060708'}", "data"),
    ("fault: {can: duplicate_pdo, cob_id: 0x201, data: 12}", "data"),
    ("produce: {sync: 1ns}", "sync"),
    ("produce: {heartbeat: 999us}", "heartbeat"),
    # two spellings of one key (an outside fuzz: the last one won unseen), a Par index in
    # other digits, a NaN constant (every constraint reading it judged "cannot judge")
    ("pr_table: {1: {type: single, data: 1}, '01': {type: single, data: 2}}", "named twice"),
    ("group_command: {axis: x, code: 1, par: {3: 1, '03': 2}}", "Par3 is named twice"),
    ("group_command: {axis: x, code: 1, par: {'+3': 1}}", "in digits"),
    ("group_command: {axis: x, code: 1, par: {'٣': 1}}", "in digits"),
    ("check_timing: {spec: servo_on_brake, constants: {tol: .nan}}", "finite"),
    ("check_timing: {spec: servo_on_brake, constants: {tol: -.inf}}", "finite"),
    ("check_timing: {spec: servo_on_brake, constants: {tol: 1" + "0" * 320 + "}}", "finite"),
    # raw SDO objects
    ("sdo: {'0x1017h:300': 20}", "sub-index"),
    ("sdo: {'1016:256': 1}", "sub-index"),
    ("sdo: {'0000': 1}", "0001h"),
    # durations: non-ASCII digits, 400 digits (every duration field shares the parser)
    ("wait: ²ms", "wait"),
    ("wait: " + "9" * 400 + "ms", "chars"),
    ("wait_until: {do: {BRKR: on}, timeout: " + "9" * 400 + "s}", "timeout"),
    ("pr_wait: {pr: 1, timeout: ٣s}", "timeout"),
    ("mark: {line: DI²}", "line"),
    # model options by `inject:`: types, not only names
    ("inject: {options: {motion_step_ms: .nan}}", "motion_step_ms"),
    ("inject: {options: {dev_ignore_speed_rule: maybe}}", "dev_ignore_speed_rule"),
    ("inject: {options: {nmt_stop_action: halt}}", "nmt_stop_action"),
    # a refusal the drive can give: a value the route can carry (SDO 2xxxh: INTEGER16;
    # Modbus: P1.042's 16 bits unsigned); an execution fuzz found these raising ValueError
    ("write: {P1.042: 65535, via: sdo, expect_error: 0x06090031}", "P1.042"),
    ("write: {P1.042: -1, via: modbus, expect_error: 3}", "P1.042"),
    # plc_program's expected status: the kind each field holds (an execution fuzz of
    # accepted plans found these raising TypeError at the end of the program)
    *((f"plc_program: {{program: [{{SPD: 1000, DRV: 'ABS,,1,Ps'}}], expect: {{{k}: {v}}}}}",
       f"expect.{k}") for k, v in (("feedback_tol", "0ms"), ("feedback", "DI8"), ("done", 1),
                                  ("position", 1.5), ("feedback_tol", -1), ("error", 40))),
]


@pytest.mark.parametrize(("step", "named"), REFUSED)
def test_each_class_is_refused_with_file_line_field(world, step: str, named: str) -> None:
    bench, specs = world
    with pytest.raises(PlanFileError) as ei:
        check_plan(loads_plan(PLAN.format(step=step), "p.yaml"), bench, specs)
    msg = str(ei.value)
    assert msg.startswith("p.yaml:3:"), msg
    assert named in msg, msg


def test_an_sdo_key_is_read_as_written(world) -> None:
    """YAML 1.1 reads an unquoted 0x1017 as the integer 4119: the key keeps its text, so the
    object is 1017h, not 4119h."""
    bench, specs = world
    plan = loads_plan(PLAN.format(step="sdo: {0x1017: 20, 1006: 5}"), "p.yaml")
    check_plan(plan, bench, specs)
    assert plan.steps[0].args.values == [(0x1017, 0, 20), (0x1006, 0, 5)]


@pytest.mark.parametrize(("step", "named"), [
    ("fault: {dio: stuck, line: DI99}", "DI1..DI10"),
    ("fault: {can: drop, bus: can7}", "can7"),
])
def test_a_fault_on_a_line_the_bench_does_not_have(world, step: str, named: str) -> None:
    bench, specs = world
    with pytest.raises(PlanFileError, match=named):
        check_plan(loads_plan(PLAN.format(step=step), "p.yaml"), bench, specs)
