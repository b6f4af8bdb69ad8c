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


def test_a_spec_is_parsed_when_it_is_first_asked_for(monkeypatch, tmp_path):
    """A run of one plan reads the specs it checks, not every file (about 0.2 s a process);
    listing the registry reads them all, and the answers are those of a whole pass."""
    import hil.timing.registry as reg

    read: list[str] = []
    real = reg.load_spec_cached
    monkeypatch.setattr(reg, "load_spec_cached", lambda p: read.append(p.stem) or real(p))
    (tmp_path / "broken.yaml").write_text("id: broken\ntitle: t\nsignals: [\n")
    specs = load_specs([tmp_path])
    assert specs["emgs"].id == "emgs" and "servo_on_brake" in specs
    assert read == ["emgs", "servo_on_brake"]
    assert "nope" not in specs and read == ["emgs", "servo_on_brake"]
    assert "broken" not in specs  # its id line names it; it does not load
    assert specs.broken.keys() == {"broken"} and len(specs) == len(load_specs())
    assert specs.why_missing("broken").startswith("timing spec 'broken' does not load")


def test_a_file_the_id_line_does_not_describe_is_read_as_a_whole_pass(tmp_path):
    """A quoted id is read; a file without one `id:` line, or a later broken file with an
    earlier spec's id, gives what one eager pass over every file gives."""
    text = fixture("timing", "emgs.yaml").read_text()
    assert "\nid: emgs\n" in text
    (tmp_path / "a_quoted.yaml").write_text(text.replace("\nid: emgs\n", '\nid: "q1"\n'))
    (tmp_path / "b_flow.yaml").write_text("{" + text.replace("\nid: emgs\n", "\n")
                                          .split("\n", 1)[0] + "}\n")  # no id line at all
    (tmp_path / "c_emgs_broken.yaml").write_text("id: emgs\nsignals: [\n")
    specs = load_specs([tmp_path])
    assert specs["q1"].id == "q1"
    assert specs["emgs"].id == "emgs"  # the shipped one: the later file does not load
    assert set(specs.broken) == {"b_flow", "c_emgs_broken"}
