"""`pytest -m hil` in a user's own project: plan files from the `hil_plans` directory are
collected as tests (issue 18 item 1), with tags as markers, and run under pytest-xdist."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

PASSING = """name: brake_ok
tags: [brake, quick]
steps:
  - di: {SON: on}
  - wait_until: {do: {BRKR: on}, timeout: 2s}
  - di: {SON: off}
"""
FAILING = """name: never_on
tags: [quick]
steps:
  - expect: {do: {BRKR: on}}
"""


def _project(tmp_path: Path) -> Path:
    (tmp_path / "plans").mkdir()
    (tmp_path / "plans" / "brake_ok.yaml").write_text(PASSING)
    (tmp_path / "plans" / "never_on.yaml").write_text(FAILING)
    (tmp_path / "pytest.ini").write_text("[pytest]\nhil_plans = plans\n"
                                         "addopts = -p no:cacheprovider --strict-markers\n")
    return tmp_path


def _pytest(cwd: Path, *args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "pytest", "-q", "--hil-out", str(cwd / "out"),
                           *args], cwd=cwd, capture_output=True, text=True, timeout=300)


def test_plans_are_collected_run_and_explained(tmp_path):
    proj = _project(tmp_path)
    r = _pytest(proj, "-m", "hil")
    assert "1 failed, 1 passed" in r.stdout, r.stdout + r.stderr
    assert "plan never_on: fail" in r.stdout  # the runner's explanation, not a traceback
    assert "expected DO BRKR on, saw BRKR off" in r.stdout
    assert (proj / "out" / "brake_ok.mcap").exists() and (proj / "out" / "never_on.mcap").exists()


def test_tags_are_markers_and_k_selects_by_name(tmp_path):
    proj = _project(tmp_path)
    r = _pytest(proj, "-m", "brake")
    assert "1 passed, 1 deselected" in r.stdout, r.stdout + r.stderr
    r = _pytest(proj, "-k", "never", "--collect-only")
    assert "never_on" in r.stdout and "brake_ok" not in r.stdout


def test_a_malformed_plan_is_a_collection_error_naming_file_and_line(tmp_path):
    proj = _project(tmp_path)
    (proj / "plans" / "broken.yaml").write_text("name: b\nsteps:\n  - frobnicate: 1\n")
    r = _pytest(proj, "--collect-only")
    assert r.returncode != 0
    assert "broken.yaml:3: steps[0].frobnicate: unknown step kind" in r.stdout + r.stderr


def test_xdist_runs_plans_in_parallel_workers(tmp_path):
    proj = _project(tmp_path)
    r = _pytest(proj, "-n", "2", "-m", "hil")
    assert "1 failed, 1 passed" in r.stdout, r.stdout + r.stderr
    assert "[gw" in r.stdout or "2 workers" in r.stdout


def test_same_named_plans_of_two_folders_keep_both_recordings(tmp_path):
    """`hil run`'s naming rule under pytest too: two plan directories a/ and b/ (`hil_plans =
    a b`) with a same.yaml each -> a-same.mcap
    and b-same.mcap, not one over the other."""
    for folder in ("a", "b"):
        (tmp_path / folder).mkdir(parents=True)
        (tmp_path / folder / "same.yaml").write_text(
            FAILING.replace("never_on", f"same_{folder}").replace(
                "expect: {do: {BRKR: on}}", "expect: {do: {BRKR: off}}"))
    (tmp_path / "pytest.ini").write_text("[pytest]\nhil_plans = a b\n"
                                         "addopts = -p no:cacheprovider\n")
    r = _pytest(tmp_path, "-m", "hil")
    assert "2 passed" in r.stdout, r.stdout + r.stderr
    assert sorted(p.name for p in (tmp_path / "out").glob("*.mcap")) == [
        "a-same.mcap", "b-same.mcap"]


def test_a_bad_hil_bench_is_one_clear_error(tmp_path):
    """A malformed or missing bench is one usage error naming the file, not one traceback per
    plan (issue: a bad HIL_BENCH printed 1 600 lines)."""
    proj = _project(tmp_path)
    bad = tmp_path / "bench.yaml"
    bad.write_text("name: b\ndrives: 7\n")
    import os

    for env in ({"HIL_BENCH": str(bad)}, {"HIL_BENCH": str(tmp_path / "none.yaml")}):
        r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-m", "hil"], cwd=proj,
                           capture_output=True, text=True, timeout=120,
                           env={**os.environ, **env})
        out = r.stdout + r.stderr
        assert r.returncode == 4, out  # pytest's usage error
        assert "HIL_BENCH:" in out and env["HIL_BENCH"] in out
        assert "Traceback" not in out and len(out.splitlines()) < 20, out


def test_pytest_and_hil_run_write_one_junit_shape(tmp_path):
    """One testcase per plan from either entry point, the same properties (recording relative
    to the JUnit file, bench, status, a property per step), and the project's junit_family
    left alone (pytest's default xunit2: no `file` attribute on testcases)."""
    import xml.etree.ElementTree as ET

    proj = _project(tmp_path)
    r = _pytest(proj, "-m", "brake", f"--junitxml={proj / 'py.xml'}")
    assert "1 passed" in r.stdout, r.stdout + r.stderr
    [py_case] = ET.parse(proj / "py.xml").getroot().iter("testcase")
    assert py_case.get("file") is None  # xunit2, not forced to xunit1
    run = subprocess.run([sys.executable, "-m", "hil.cli", "run", "-q", "brake_ok",
                          "--plans", str(proj / "plans"), "--out", str(proj / "run")],
                         cwd=proj, capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stdout + run.stderr
    [run_case] = ET.parse(proj / "run" / "junit.xml").getroot().iter("testcase")
    py = {p.get("name"): p.get("value") for p in py_case.iter("property")}
    hr = {p.get("name"): p.get("value") for p in run_case.iter("property")}
    assert list(py) == list(hr)
    assert py["recording"] == "out/brake_ok.mcap" and hr["recording"] == "brake_ok.mcap"
    assert run_case.get("name") == "brake_ok"


def test_a_collected_plans_failure_reads_as_hil_runs_junit(tmp_path) -> None:
    """README: under pytest a plan's testcase carries "the same failure text" as `hil run`'s
    JUnit: step number, status, time, plan file and line, message (an outside review found
    no file:line under pytest)."""
    from hil.report.data import load_run
    from hil.report.junit import failure_text

    proj = tmp_path / "proj"
    (proj / "plans").mkdir(parents=True)
    (proj / "plans" / "never_on.yaml").write_text(
        "name: never_on\nsteps:\n  - expect: {do: {BRKR: on}}\n")
    (proj / "pytest.ini").write_text("[pytest]\nhil_plans = plans\n")
    r = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                        f"--hil-out={proj / 'out'}"], cwd=proj, capture_output=True, text=True,
                       timeout=120)
    first, _all = failure_text(load_run(proj / "out" / "never_on.mcap"))
    assert "(" in first and "never_on.yaml:3)" in first, first
    assert first in r.stdout, r.stdout
