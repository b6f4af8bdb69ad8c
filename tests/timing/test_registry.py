"""The spec registry: specs by id and the files that failed to load (issue 17 item 3)."""

from __future__ import annotations

import shutil

import pytest

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.paths import fixture
from hil.plan.plan import check_plan, loads_plan
from hil.timing.registry import load_specs


def test_shipped_specs_all_load():
    specs = load_specs()
    assert "servo_on_brake" in specs and specs.broken == {}
    assert specs["servo_on_brake"].id == "servo_on_brake"


def test_a_broken_file_is_reported_and_only_plans_naming_it_are_refused(tmp_path):
    (tmp_path / "my_spec.yaml").write_text("id: my_spec\ntitle: t\nsignals: [\n")
    shutil.copy(fixture("timing", "emgs.yaml"), tmp_path / "emgs_copy.yaml")
    specs = load_specs([tmp_path])
    assert set(specs.broken) == {"my_spec"} and "my_spec.yaml" in specs.broken["my_spec"]
    bench = load_bench()
    check_plan(loads_plan("name: p\nsteps:\n  - check_timing: emgs\n"), bench, specs)
    with pytest.raises(PlanFileError, match=r"timing spec 'my_spec' does not load: .*my_spec"):
        check_plan(loads_plan("name: p\nsteps:\n  - check_timing: my_spec\n"), bench, specs)
    with pytest.raises(PlanFileError, match=r"no timing spec 'nope'; known: .*emgs"):
        check_plan(loads_plan("name: p\nsteps:\n  - check_timing: nope\n"), bench, specs)
