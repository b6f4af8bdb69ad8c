"""Step kinds and plan features for the homing and absolute-encoder plans: per-step timing
`bind:` / `constants:` / `since:`, the plan's own DI/DO mapping (params P2.010-P2.041), plan
model `options:`, the sensor lines taken from the ground truth, `abs_read` / `abs_origin`."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import SimpleNamespace

import pytest
import yaml

from hil.bench.bench import load_bench
from hil.paths import fixture
from hil.plan.context import StepFailed
from hil.plan.kinds import absolute
from hil.plan.plan import bind_line, check_plan, loads_plan, mapping_of, plan_spec
from hil.plan.runner import timing_specs
from hil.plan.steps import describe
from hil.timing.checker import occurrences_since
from hil.virtual.truth import SensorTap, bench_with_options

HOMING = """
name: h
params: {P2.036: 0x0124, P2.037: 0x0127, P2.011: 0x011D, P2.019: 0}
options: {state_publish_ms: 1}
steps:
  - name: go
    home: {method: 3, speeds: [1200, 300]}
  - check_timing: {spec: homing_canopen, since: go, bind: {REF: ORGP},
                   constants: {v1: 120, d0: 1}}
  - check_timing: {spec: homing_canopen, since: last_check, bind: {REF: NL}}
"""


def test_check_timing_takes_bind_constants_and_since():
    plan = loads_plan(HOMING)
    a = plan.steps[1].args
    assert a.bind == {"REF": "ORGP"} and a.constants == {"v1": 120, "d0": 1}
    assert a.since == "go" and plan.steps[2].args.since == "last_check"
    assert describe(plan.steps[1]) == "check_timing homing_canopen (REF=ORGP)"
    assert plan.options == {"state_publish_ms": 1}
    check_plan(plan, load_bench(), timing_specs())  # spec constants and binds known


def test_plan_params_map_functions_onto_lines():
    # P2.036 = 0x0124: DI9 ORGP a-contact; P2.011 = 0x011D: DI2 ABSE (CCLR leaves);
    # P2.019 = 0: DO2 no function (ZSPD leaves) - L9238-9256, L9323-9339
    assert mapping_of("P2.036", 0x0124)[1].function == "ORGP"
    assert mapping_of("P2.019", 0) == ("DO2", None)
    assert mapping_of("P1.042", 5) is None
    with pytest.raises(ValueError, match=r"no function of table 8\.2"):
        mapping_of("P2.021", 0x01FE)
    plan = loads_plan(HOMING)
    spec = plan_spec(plan, load_bench().drives["drive1"])
    assert spec.di["ORGP"].line == "DI9" and spec.di["SHOM"].line == "DI10"
    assert spec.di["ABSE"].line == "DI2" and "CCLR" not in spec.di
    assert "ZSPD" not in spec.do and spec.do["HOME"].line == "DO3"
    assert bind_line("ORGP", spec) == "DI9" and bind_line("NL", spec) == "DI6:b"
    assert bind_line("DI7:b", spec) == "DI7:b"
    assert spec.binding()["SHOM"] == "DI10"


def test_mapped_functions_satisfy_di_steps():
    plan = loads_plan("name: p\nparams: {P2.037: 0x0127}\nsteps:\n  - di: {SHOM: on}\n")
    check_plan(plan, load_bench(), timing_specs())


@dataclass
class V:
    occurrence: int
    t_ns: int | None
    from_ns: int | None = None


def test_since_keeps_occurrences_that_began_after():
    vs = [V(0, 100), V(0, 150), V(1, 300), V(1, 250), V(2, None)]
    assert [v.occurrence for v in occurrences_since(vs, 200)] == [1, 1, 2]
    assert occurrences_since(vs, None) == vs


class Rec:
    def __init__(self) -> None:
        self.calls: list[tuple] = []

    def drive_state(self, drive, state, **kw):
        self.calls.append(("state", drive))

    def dio(self, name, line, level, t, source_t=None):
        self.calls.append(("dio", name, line, level, source_t))

    def other(self):
        return "forwarded"


def test_sensor_tap_records_sensor_lines_from_the_ground_truth():
    rec = Rec()
    tap = SensorTap(rec)
    di = [False] * 10
    di[5] = di[6] = True  # NL, PL closed (b-contacts), cam off
    tap.drive_state("drive1", {"di": list(di)}, source_t=10)
    di[8], di[0] = True, True  # ORGP cam reached; DI1 (a harness line) is not copied
    tap.drive_state("drive1", {"di": list(di)}, source_t=20)
    tap.drive_state("drive1", {"di": list(di)}, source_t=30)
    dio = [c for c in rec.calls if c[0] == "dio"]
    assert dio == [("dio", "drive1", "DI6", True, 10), ("dio", "drive1", "DI7", True, 10),
                   ("dio", "drive1", "DI9", False, 10), ("dio", "drive1", "DI9", True, 20)]
    assert tap.other() == "forwarded"


def test_plan_options_reach_the_virtual_drives(tmp_path: Path):
    import contextlib

    plan = loads_plan(HOMING)
    with contextlib.ExitStack() as stack:
        b = bench_with_options(load_bench(), plan.options, stack)
        assert b.drives["drive1"].options["state_publish_ms"] == 1
        zenoh = load_bench(fixture("benches", "virtual-zenoh.yaml"))
        z = bench_with_options(zenoh, plan.options, stack)
        # `hil drive --bench` reads the file: the copy carries the options
        data = yaml.safe_load(Path(z.path).read_text())
        assert data["drives"]["drive1"]["options"]["state_publish_ms"] == 1
        assert load_bench(z.path).drives["drive1"].options["state_publish_ms"] == 1
    assert not Path(z.path).exists()


def _abs_step(text: str):
    return loads_plan("name: p\nsteps:\n" + text).steps


def test_abs_read_compares_with_expect_and_stored_readings(monkeypatch):

    readings = iter([(0, 0, 250000), (0, 0, 250001), (0, 0, 250003)])

    class Reader:
        retries = 2

        def read(self):
            st, tu, pos = next(readings)
            return SimpleNamespace(status=st, turns=tu, position=pos, attempts=1,
                                   violations=())

    monkeypatch.setattr(absolute, "abs_reader", lambda d: Reader())
    ctx = SimpleNamespace(store={}, rec=SimpleNamespace(log=lambda *a, **k: None))
    d = SimpleNamespace(name="drive1")
    steps = _abs_step("  - abs_read: {expect: {status: 0, position: 250000}, store: a}\n"
                      "  - abs_read: {same_as: a, tolerance: 1}\n"
                      "  - abs_read: {same_as: a, tolerance: 1}\n")
    assert "position 250000" in steps[0].action.run(ctx, steps[0], d).text
    assert ctx.store["a"] == {"status": 0, "turns": 0, "position": 250000}
    assert "position 250001" in steps[1].action.run(ctx, steps[1], d).text  # within one PUU
    with pytest.raises(StepFailed, match=r"position 250003, expected 250000 ± 1 \(as a\)"):
        steps[2].action.run(ctx, steps[2], d)


def test_abs_steps_need_abse_and_absc_wired():
    abs_params = "params: {P2.011: 0x011D, P2.012: 0x011F, P2.013: 0}\n"
    plan = loads_plan("name: p\n" + abs_params + "steps:\n  - abs_origin: {}\n"
                      "  - abs_read: {expect: {turns: 0}}\n")
    check_plan(plan, load_bench(), timing_specs())
    assert describe(plan.steps[0]) == "absolute origin (ABSE + ABSC)"
    assert describe(plan.steps[1]) == "absolute read (DI/DO): turns=0"
