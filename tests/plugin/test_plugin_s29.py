"""The pytest plugin under what a stranger does (found by an outside probe, helper-120):
pytest-timeout on a test waiting in virtual time, and a fixture that fails after the bench
moved."""

from __future__ import annotations

import glob
import shutil
from pathlib import Path

import pytest

from hil.paths import fixture
from hil.record.reader import Recording

pytest_plugins = ["pytester"]

FOREVER = """
import pytest

@pytest.mark.hil
def test_wait_forever(hil_drive):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO3", True, 1e6)   # HOME never comes: a day of bench time
"""


def _result(pytester: pytest.Pytester) -> tuple[dict, list[dict]]:
    [path] = glob.glob(str(pytester.path / "reports" / "pytest" / "*.mcap"))
    rec = Recording.open(path)
    return (rec.metadata().get("hil.result", {}),
            [m for _, _, _, m in rec.messages("/safety")])


def test_a_pytest_timeout_in_virtual_time_leaves_the_bench_safe(pytester) -> None:
    """pytest-timeout's SIGALRM used to land inside the drive's 1 ms tick, which then never
    planned the next: the model stopped, and the safe state after the timeout said "BRKR
    still on after 3000 ms: the brake may be released" (4 runs in 5). Its exception is now
    raised between two clock events, and a tick cut short still plans the next."""
    pytester.makepyfile(test_forever=FOREVER)
    for _ in range(2):  # where the alarm lands varies
        res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--timeout=2")
        res.assert_outcomes(failed=1)
        out = res.stdout.str()
        assert "Timeout" in out and "safe state was not confirmed" not in out
        result, safety = _result(pytester)
        assert result.get("status") == "fail" and "Timeout" in result.get("reason", "")
        assert result.get("safe_state_ok") == "true"
        assert safety[-1]["action"] == "safe_state_reached"


SETUP = """
import pytest

@pytest.fixture
def broken(hil_drive):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)  # the brake released: the bench moved
    raise RuntimeError("setup boom")

@pytest.mark.hil
def test_setup_error(broken):
    pass
"""


def test_a_fixture_failing_after_the_bench_moved_is_recorded_with_its_cause(pytester) -> None:
    """It said "the test did not run", and "setup boom" was nowhere in the recording; the
    safe state records why the bench went safe, as a teardown error's does."""
    pytester.makepyfile(test_setup=SETUP)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    res.assert_outcomes(errors=1)
    result, safety = _result(pytester)
    assert result.get("status") == "error"
    assert result.get("reason") == "setup failed: RuntimeError: setup boom"
    assert safety and all("setup boom" in m["reason"] for m in safety)
    assert safety[-1]["action"] == "safe_state_reached"


UNMARKED = """
def test_uses_the_drive(hil_drive):
    assert hil_drive is not None

def test_plain():
    pass
"""


def test_a_test_using_the_bench_is_a_hil_test_without_the_marker(pytester) -> None:
    """`-m hil` selected only tests marked by hand: one using `hil_drive` unmarked was left
    out of `pytest -m hil` and opened the bench under `-m "not hil"`."""
    pytester.makepyfile(test_unmarked=UNMARKED)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-m", "hil")
    res.assert_outcomes(passed=1, deselected=1)
    assert [p.name for p in (pytester.path / "reports").rglob("*.mcap")] == [
        "test_unmarked.py_test_uses_the_drive.mcap"]
    shutil.rmtree(pytester.path / "reports")
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-m", "not hil")
    res.assert_outcomes(passed=1, deselected=1)
    assert not list(pytester.path.rglob("*.mcap"))  # the bench was never opened


FAILS = """
import pytest

@pytest.mark.hil
def test_boom(hil_drive):
    hil_drive.set_function("SON", True)
    raise RuntimeError("boom")
"""


def test_hil_report_of_a_pytest_recording_names_the_reason_bench_and_drive(pytester) -> None:
    """The JUnit said `<failure message="fail">`, the page "bench ?" and "dut ?", and the
    time 0: a pytest recording has no steps to name, and its bench is only in `hil.bench`."""
    from hil.cli import main as hil

    pytester.makepyfile(test_fails=FAILS)
    pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider").assert_outcomes(failed=1)
    [rec] = glob.glob(str(pytester.path / "reports" / "pytest" / "*.mcap"))
    out = pytester.path / "r"
    assert hil(["report", rec, "-o", str(out / "r.html"), "--junit", str(out / "j.xml")]) == 0
    junit = (out / "j.xml").read_text(encoding="utf-8")
    assert 'message="test failed: RuntimeError: boom"' in junit
    assert '<property name="bench" value="virtual" />' in junit
    assert 'time="0.000000"' not in junit
    page = (out / "r.html").read_text(encoding="utf-8")
    assert "<td>virtual</td>" in page.replace(" ", "") or ">virtual<" in page
    assert "drive1 fw 100" in page  # hil.dut, as a plan's (P0.000, L7070)


def _readme_example() -> str:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / "README.md").read_text(encoding="utf-8")
    block = next(b.split("```", 1)[0] for b in text.split("```python\n")[1:]
                 if "def test_brake_release" in b)
    return block  # as written: its imports included


def test_the_readme_brake_example_judges_the_brake_and_fails_an_early_one(pytester) -> None:
    """The README's example checked at the BRKR edge, where "BRKR rises P1.042 after
    servo on" cannot be judged yet (its event is servo on for P1.042 + 1 ms): a brake
    released 40 ms early passed. It now waits past the window. (Early here: the check is
    told P1.042 = 120 ms while the drive releases at its 80.)"""
    example = _readme_example()
    pytester.makepyfile(test_readme=example)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    res.assert_outcomes(passed=1)
    [rec] = glob.glob(str(pytester.path / "reports" / "pytest" / "*.mcap"))
    names = [m["constraint"] for _, _, _, m in Recording.open(rec).messages(
        "/timing/verdicts") if m.get("status") == "pass"]
    assert "BRKR rises P1.042 after servo on" in names
    early = example.replace('hil_check("servo_on_brake")',
                            'hil_check("servo_on_brake", params={"P1.042": 120})')
    assert early != example
    pytester.makepyfile(test_readme=early)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    res.assert_outcomes(failed=1)
    assert "BRKR rises P1.042 after servo on: FAIL" in res.stdout.str()


def test_hil_check_of_an_unknown_spec_lists_the_shipped_ones(pytester) -> None:
    """It said "cannot read: No such file or directory" of a path under fixtures/."""
    pytester.makepyfile(test_unknown="""
import pytest

def test_x(hil_drive, hil_check):
    with pytest.raises(ValueError, match=r"no_such_spec.*shipped: .*servo_on_brake"):
        hil_check("no_such_spec")
""")
    pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider").assert_outcomes(passed=1)


def _doc_block(doc: str, lang: str, marker: str) -> str:
    from pathlib import Path

    text = (Path(__file__).resolve().parents[2] / doc).read_text(encoding="utf-8")
    return next(b.split("```", 1)[0] for b in text.split(f"```{lang}\n")[1:] if marker in b)


def test_the_readme_plan_excerpt_judges_the_brake_rule(tmp_path) -> None:
    """The excerpt checked at the BRKR edge, so "BRKR rises P1.042 after servo on" was
    skipped ("no servo on for P1.042 in the recording"): 2 verdicts, the brake's not one."""
    from hil.bench.bench import load_bench
    from hil.plan.plan import loads_plan
    from hil.plan.runner import run_plans

    text = _doc_block("README.md", "yaml", "# plans/servo_on_off_brake.yaml (excerpt)")
    plan = loads_plan(text, str(tmp_path / "excerpt.yaml"))
    [res] = run_plans([plan], load_bench(None), tmp_path / "out", quiet=True)
    assert res.passed
    judged = [v["constraint"] for s in res.steps for v in s.verdicts if v["status"] == "pass"]
    assert "BRKR rises P1.042 after servo on" in judged, judged


def test_the_documented_pytest_ini_gives_no_warning(pytester) -> None:
    """pytest's ini values take no inline comment: `hil_plans = plans  # one or more ...`
    made every word a directory, with a PytestConfigWarning each."""
    ini = _doc_block("docs/plans.md", "ini", "hil_plans")
    pytester.makeini(ini)
    pytester.mkdir("plans")
    (pytester.path / "plans" / "p.yaml").write_text(
        "name: p\nsteps:\n  - expect: {do: {SRDY: on}}\n", encoding="utf-8")
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--collect-only",
                                        "-W", "error::pytest.PytestConfigWarning")
    assert res.ret == 0, res.stdout.str() + res.stderr.str()
    assert "is not a directory" not in res.stdout.str() + res.stderr.str()


FUNC_ONLY = """
import pytest

@pytest.mark.hil
@pytest.mark.timeout(2, func_only=True)
def test_wait_forever(hil_drive):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO3", True, 1e6)
"""

LOST = """
import os, signal
import hil.clock

def test_alarm_in_last_wait(hil_drive):
    def pred():  # pytest-timeout's alarm landing as the last wait's condition comes true
        os.kill(os.getpid(), signal.SIGALRM)
        return True
    hil.clock.wait_for(pred, 1.0)
"""

IN_SAFE_STATE = """
import signal
import hil.plan.safety as safety

_go_safe = safety.go_safe

def go_safe(session, reason, rec, *a, **k):  # the timer running out while the bench goes safe
    signal.setitimer(signal.ITIMER_REAL, 0.001)
    return _go_safe(session, reason, rec, *a, **k)

safety.go_safe = go_safe

def test_servo_on(hil_drive):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
"""


@pytest.mark.parametrize(("source", "args"), [
    (FUNC_ONLY, ()),  # its handler is installed after the fixtures
    (LOST, ("--timeout=60",)),  # deferred, then the test ended before it was raised
    (IN_SAFE_STATE, ("--timeout=60",)),  # while shielded: the safe state ran on
], ids=["func_only", "lost", "in_safe_state"])
def test_a_pytest_timeout_is_never_lost_nor_cuts_the_safe_state(pytester, source, args) -> None:
    """helper-123: with `func_only` the alarm cut a host tick (the model stopped, "BRKR still
    on after 3000 ms"); one deferred in the test's last wait was dropped before the safe
    state and the test passed; one during the safe state cut it (no safe_state_reached).
    Each now fails the test as a timeout, after the safe state, which is on the record."""
    pytester.makepyfile(test_t=source)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", *args)
    out = res.stdout.str()
    assert "Timeout" in out and "safe state was not confirmed" not in out, out
    outcomes = res.parseoutcomes()
    assert res.ret == 1 and ("failed" in outcomes or "errors" in outcomes), outcomes
    result, safety = _result(pytester)
    assert result.get("status") == "fail" and "Timeout" in result.get("reason", ""), result
    assert result.get("safe_state_ok") == "true"
    assert safety[-1]["action"] == "safe_state_reached"


def test_a_plan_cut_by_pytest_timeout_is_recorded_aborted(pytester) -> None:
    """pytest's Failed is neither a KeyboardInterrupt nor an Exception: a plan it cut was
    recorded `pass`, "end of plan" (helper-123)."""
    (pytester.path / "long.yaml").write_text(
        "name: long\nsteps:\n  - di: {SON: on}\n  - wait: 40000s\n", encoding="utf-8")
    pytester.makepyfile(test_np="""
def test_plan(hil_run_plan):
    assert hil_run_plan("long.yaml").passed
""")
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--timeout=2")
    res.assert_outcomes(failed=1)
    result, safety = _result(pytester)
    assert result.get("status") == "aborted", result
    assert result.get("reason", "").startswith("stopped: Failed: Timeout"), result
    assert safety[-1]["action"] == "safe_state_reached"
    assert all("Timeout" in m["reason"] for m in safety)


def test_a_recorder_only_test_has_a_result_and_specs_are_found_as_named(pytester,
                                                                        monkeypatch) -> None:
    """A test of `hil_recorder` alone had no `hil.result` (its JUnit said "unknown", time
    0); `hil_check("servo_on_brake.yaml")`, the shipped file's own name, was unknown, and a
    spec path relative to the rootdir failed from a subfolder (helper-123)."""
    (pytester.path / "specs").mkdir()
    (pytester.path / "specs" / "mine.yaml").write_text(
        (Path(fixture("timing", "servo_on_brake.yaml"))).read_text(encoding="utf-8"),
        encoding="utf-8")
    sub = pytester.mkpydir("sub")
    (sub / "test_r.py").write_text("""
def test_rec_only(hil_recorder):
    hil_recorder.log("info", "hello", name="t")

def test_specs(hil_drive, hil_check):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    hil_check("servo_on_brake.yaml")
    hil_check("specs/mine.yaml")
""", encoding="utf-8")
    pytester.makeini("[pytest]\n")
    monkeypatch.chdir(sub)  # pytest run from a subfolder of the rootdir
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    res.assert_outcomes(passed=2)
    [rec] = glob.glob(str(pytester.path / "reports" / "pytest" / "*rec_only.mcap"))
    result = Recording.open(rec).metadata().get("hil.result", {})
    assert result.get("status") == "pass" and float(result.get("duration_ms")) > 0


def test_a_step_cut_by_pytest_timeout_ran_and_its_plan_is_in_the_junit(pytester) -> None:
    """The step pytest-timeout cut was recorded "skipped, not run" (Ctrl-C records "error,
    interrupted while it ran"), and the JUnit named no recording for the cut plan."""
    (pytester.path / "long.yaml").write_text(
        "name: long\nsteps:\n  - di: {SON: on}\n  - wait: 40000s\n", encoding="utf-8")
    pytester.makepyfile(test_np="""
def test_plan(hil_run_plan):
    assert hil_run_plan("long.yaml").passed
""")
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--timeout=2",
                                        "--junitxml=j.xml")
    res.assert_outcomes(failed=1)
    [rec] = glob.glob(str(pytester.path / "reports" / "pytest" / "*.mcap"))
    ends = [m for _, _, _, m in Recording.open(rec).messages("/plan/steps")
            if m.get("event") == "end"]
    wait = next(m for m in ends if m["index"] == 1)
    assert wait["status"] == "error" and "while it ran" in wait["message"], wait
    junit = (pytester.path / "j.xml").read_text(encoding="utf-8")
    assert '<property name="recording"' in junit and Path(rec).name in junit


def test_a_recorder_only_test_that_judges_nothing_is_nothing_to_judge(pytester, tmp_path,
                                                                       capsys) -> None:
    """A whole recording with no channel (a skipped test of `hil_recorder` alone) was judged
    with every spec's defaults: 186 skipped and 20 inconclusive, exit 3."""
    from hil.cli import main as hil

    pytester.makepyfile(test_skip="""
import pytest

def test_skipped(hil_recorder):
    pytest.skip("not today")
""")
    pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider").assert_outcomes(skipped=1)
    [rec] = glob.glob(str(pytester.path / "reports" / "pytest" / "*.mcap"))
    capsys.readouterr()
    assert hil(["check", rec, "--json"]) == 4
    out = capsys.readouterr()
    assert out.out.strip() == "[]" and "holds no channel: nothing to judge" in out.err


def test_hil_check_of_a_missing_spec_path_is_an_error(pytester) -> None:
    """`hil_check("spec/servo_on_brake.yaml")`, a folder that does not exist, was judged
    with the shipped spec of that name."""
    pytester.makepyfile(test_p="""
import pytest

def test_x(hil_drive, hil_check):
    with pytest.raises(ValueError, match="no such file"):
        hil_check("spec/servo_on_brake.yaml")
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    hil_check("servo_on_brake.yml")  # the shipped one, by a name with the other suffix
""")
    pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider").assert_outcomes(passed=1)


RERUN = """
import pytest
N = {"n": 0}

def test_on_the_bench_fails(hil_drive):
    N["n"] += 1
    print("ATTEMPT", N["n"])
    assert False

def test_off_the_bench_fails():
    assert False
"""


def test_a_plugin_test_in_virtual_time_is_never_rerun(pytester, monkeypatch) -> None:
    """Issue 25: virtual-time tests are never rerun; pytest-rerunfailures must not apply to
    them. An outside probe (helper-131) saw a user's `hil_drive` test run three times
    under `--reruns 2`: only hil's own suite held the rule. A test off the bench still is."""
    monkeypatch.delenv("HIL_BENCH", raising=False)
    pytester.makepyfile(test_rerun=RERUN)
    res = pytester.runpytest_subprocess("-q", "-s", "-p", "no:cacheprovider", "--reruns", "2")
    assert res.parseoutcomes() == {"failed": 2, "rerun": 2}
    out = res.stdout.str()
    assert "ATTEMPT 1" in out and "ATTEMPT 2" not in out  # the two reruns: the other test's


HANG_AT_TEARDOWN = """
import time
from hil import clock

def test_leaves_a_hung_event(hil_session):
    def forever():  # a model bug: an event that never returns, due as the test ends
        while True:
            time.sleep(0.001)
    clock.call_later(1e-6, forever)
"""


def test_the_hil_session_safe_state_runs_under_the_watchdog(pytester, monkeypatch) -> None:
    """A review (helper-133): the fixture's safe state had no watchdog, so an event left on
    the clock hung pytest for good (pytest-timeout and SIGTERM held off). It goes safe
    through the runner's one path now: stopped, not confirmed, the test an error."""
    monkeypatch.delenv("HIL_BENCH", raising=False)
    pytester.makeconftest("import hil.plan.context as c\nc.WATCHDOG_GRACE_NS = 500_000_000\n"
                          "c.WATCHDOG_FACTOR = 0\n")
    pytester.makepyfile(test_hang=HANG_AT_TEARDOWN)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", timeout=60)
    res.assert_outcomes(passed=1, errors=1)
    result, safety = _result(pytester)
    assert result.get("safe_state_ok") == "false"
    assert safety[-1]["action"] == "safe_state_not_confirmed"
    assert "wall-clock watchdog" in safety[-1]["detail"]


HANG_IN_BODY = """
import time
from hil import clock

def test_hangs_in_an_event(hil_session):
    def forever():  # a model bug: an event that never returns, while the test waits
        while True:
            time.sleep(0.001)
    clock.call_later(0.001, forever)
    clock.sleep(0.01)
"""


def test_pytest_timeout_cuts_an_event_that_never_ends(pytester, monkeypatch) -> None:
    """A review (helper-134): pytest-timeout's alarm (and Ctrl-C) are held to the end of the
    clock event running, so that no model tick is cut in half; an event that never ended
    held them for ever and pytest hung. After HELD_WAIT_S the event is cut: the test fails
    with the timeout, the safe state is recorded as not confirmed (the clock is hung), and
    the recording is closed."""
    monkeypatch.delenv("HIL_BENCH", raising=False)
    pytester.makeconftest("import hil.clock as c\nc.HELD_WAIT_S = 1.0\n")
    pytester.makepyfile(test_hang=HANG_IN_BODY)
    res = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--timeout=2",
                                        "--timeout-method=signal", timeout=60)
    res.assert_outcomes(failed=1, errors=1)  # the error: its teardown's safe state
    assert "Timeout" in res.stdout.str()
    result, safety = _result(pytester)
    assert result.get("status") == "fail" and "Timeout" in result.get("reason", "")
    assert result.get("safe_state_ok") == "false"
    assert safety[-1]["action"] == "safe_state_not_confirmed"
