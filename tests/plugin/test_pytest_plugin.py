"""The pytest plugin itself, exercised through pytester (a real inner pytest run)."""

from __future__ import annotations

import itertools
import xml.etree.ElementTree as ET

import pytest

pytest_plugins = ["pytester"]

INNER = '''
import pytest
from hil.pytest_plugin import TimingFailure

@pytest.mark.hil
def test_brake_release(hil_drive, hil_recorder, hil_check):
    hil_drive.write_param("P1.042", 80)
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)      # BRKR on DO6 on the virtual bench
    verdicts = hil_check("servo_on_brake", params={"P1.042": 80})
    assert any(v.status == "pass" for v in verdicts)

@pytest.mark.hil
def test_deviation_reads_well(hil_drive, hil_check):
    hil_drive.write_param("P1.042", 80)
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    with pytest.raises(TimingFailure, match=r"BRKR rises P1.042 after servo on: FAIL: .*allowed"):
        hil_check("servo_on_brake", params={"P1.042": 20})   # a wrong expectation fails
'''


def test_fixtures_recording_and_junit_property(pytester: pytest.Pytester, tmp_path) -> None:
    pytester.makepyfile(test_inner=INNER)
    junit = tmp_path / "junit.xml"
    result = pytester.runpytest_subprocess(
        "-m", "hil", "-p", "no:cacheprovider", f"--junitxml={junit}",
        f"--hil-out={tmp_path / 'out'}", "-q",
    )
    result.assert_outcomes(passed=2)
    props = [p.get("value") for p in ET.parse(junit).iter("property")
             if p.get("name") == "recording"]
    assert len(props) == 2
    for path in props:  # relative to the JUnit file, as `hil run` writes it
        assert path.endswith(".mcap") and path.startswith("out/")
    props = [str(tmp_path / p) for p in props]
    from hil.record.reader import Recording

    rec = Recording.open(props[0])
    topics = set(rec.topics())
    assert "/dio/drive1/DO6" in topics and "/drive/drive1/state" in topics
    assert "/safety" in topics  # the bench was driven to its safe state after the test


def test_marker_selects_and_option_is_known(pytester: pytest.Pytester) -> None:
    pytester.makepyfile(test_sel="""
import pytest
@pytest.mark.hil
def test_a(hil_bench):
    assert hil_bench.virtual
def test_b():
    pass
""")
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, deselected=1)
    bad = pytester.runpytest_subprocess("--hil-bench", "/nonexistent.yaml", "-m", "hil", "-q",
                                        "-p", "no:cacheprovider")
    assert bad.ret != 0
    assert "nonexistent.yaml" in bad.stdout.str() + bad.stderr.str()


OUTCOMES = '''
import pytest

@pytest.mark.hil
@pytest.mark.parametrize("p", ["x y", "x_y", "a/b", "a_b"])
def test_q(hil_recorder, p):
    hil_recorder.log("info", p)

@pytest.mark.hil
def test_raises_midway(hil_drive):
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    raise RuntimeError("the fixture went wrong")

@pytest.mark.hil
def test_passes(hil_drive):
    hil_drive.set_function("SON", True)

@pytest.mark.hil
def test_check_nothing(hil_drive, hil_check):
    hil_check("servo_off_brake")          # no servo off happened: nothing to judge

@pytest.mark.hil
def test_run_a_plan(hil_run_plan):
    assert hil_run_plan("servo_on_off_brake").passed
'''


def test_each_test_its_own_recording_and_what_ended_it(pytester: pytest.Pytester,
                                                      tmp_path) -> None:
    """README: `hil_recorder` is "one MCAP per test" (parameters that differ only in what a
    file name cannot hold included); a failed test's recording says it failed and why the
    bench went safe, a passing one says it ended; a `hil_check` that judges nothing fails, as
    a plan's `check_timing` does; a plan run from a test and a plan collected as a test never
    share a recording."""
    pytester.makepyfile(test_outcomes=OUTCOMES)
    plans = pytester.mkdir("plans")
    (plans / "servo_on_off_brake.yaml").write_text(_shipped("servo_on_off_brake").read_text())
    pytester.makeini("[pytest]\nhil_plans = plans\n")
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider",
                                           f"--hil-out={out}")
    result.assert_outcomes(passed=7, failed=2)
    names = sorted(p.name for p in out.glob("*.mcap"))
    assert len([n for n in names if "test_q" in n]) == 4, names
    assert len(names) == len(set(names)) == 4 + 4 + 1, names  # 4 params, 4 tests, 1 plan
    from hil.record.reader import Recording

    def result_of(part: str) -> dict:
        [path] = [p for p in out.glob("*.mcap") if part in p.name]
        meta = Recording.open(path).metadata()
        return dict(meta["hil.result"])

    failed = result_of("test_raises_midway")
    assert failed["status"] == "fail" and "the fixture went wrong" in failed["reason"]
    assert failed["safe_state_ok"] in (True, "True", "true")
    assert result_of("test_passes")["status"] == "pass"
    assert "nothing judged" in result.stdout.str()
    assert any(n.endswith("test_run_a_plan-servo_on_off_brake.mcap") for n in names)


XFAIL = '''
import pytest

@pytest.mark.hil
@pytest.mark.xfail(reason="the brake is slow on this bench")
def test_xfails(hil_drive):
    raise AssertionError("too slow")

@pytest.mark.hil
def test_skips(hil_drive):
    pytest.skip("no brake fitted")

@pytest.mark.hil
@pytest.mark.xfail(reason="flaky wiring")
def test_xpasses(hil_drive):
    pass

@pytest.fixture
def needs_encoder(hil_drive):
    pytest.skip("no encoder cable")

@pytest.mark.hil
def test_fixture_skips(hil_drive, needs_encoder):
    pass

@pytest.mark.hil
def test_imperative_xfail(hil_drive):
    pytest.xfail("known firmware bug")

@pytest.mark.hil
@pytest.mark.xfail(reason="must fail", strict=True)
def test_strict_xpass(hil_drive):
    pass
'''


def test_xfail_skip_and_xpass_say_so_in_the_recording(pytester: pytest.Pytester,
                                                      tmp_path) -> None:
    """`hil.result` of an expected failure, a skip inside the test and an unexpected pass
    names what pytest made of it and why (all three said "end of test")."""
    pytester.makepyfile(test_x=XFAIL)
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider",
                                           f"--hil-out={out}")
    result.assert_outcomes(xfailed=2, skipped=2, xpassed=1, failed=1)
    from hil.record.reader import Recording

    def result_of(part: str) -> dict:
        [path] = [p for p in out.glob("*.mcap") if part in p.name]
        return dict(Recording.open(path).metadata()["hil.result"])

    xf = result_of("test_xfails")
    assert xf["status"] == "skipped", xf
    assert xf["reason"] == "expected failure (xfail): the brake is slow on this bench", xf
    sk = result_of("test_skips")
    assert (sk["status"], sk["reason"]) == ("skipped", "skipped: no brake fitted"), sk
    xp = result_of("test_xpasses")
    assert xp["status"] == "pass" and "expected to fail (xfail): flaky wiring" in xp["reason"]
    fx = result_of("test_fixture_skips")  # a fixture set up after the bench skipped it
    assert (fx["status"], fx["reason"]) == ("skipped", "skipped: no encoder cable"), fx
    ix = result_of("test_imperative_xfail")
    assert ix["reason"] == "expected failure (xfail): known firmware bug", ix
    sx = result_of("test_strict_xpass")
    assert sx["status"] == "fail" and "XPASS(strict)" in sx["reason"] and "must fail" in \
        sx["reason"], sx


def _shipped(name: str):
    from hil.plan.plan import find_plans

    return find_plans([name])[0]


def test_a_bad_hil_out_is_one_usage_error(pytester: pytest.Pytester) -> None:
    """A file where `--hil-out`'s directory belongs: one line, before anything runs."""
    pytester.makepyfile(test_one="import pytest\n@pytest.mark.hil\n"
                                 "def test_a(hil_recorder):\n    pass\n")
    (pytester.path / "afile").write_text("x")
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider",
                                           "--hil-out=afile")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert "--hil-out afile: not a directory" in result.stderr.str()
    assert (pytester.path / "afile").read_text() == "x"


def _one_passing_test(pytester: pytest.Pytester, tmp_path, source: str):
    """Run a one-test file on the built-in bench; the test passes; its recording."""
    from hil.record.reader import Recording

    pytester.makepyfile(test_one=source)
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider",
                                           f"--hil-out={out}")
    result.assert_outcomes(passed=1)
    (path,) = out.glob("*.mcap")
    return Recording.open(path)


CANOPEN_WAITS = '''
import canopen
import pytest
from hil import clock

@pytest.mark.hil
def test_canopen_waits(hil_session, hil_drive):
    node = hil_drive.cia.node
    node.sdo[0x1017].raw = 50  # the drive's heartbeat every 50 ms
    t0 = clock.monotonic()
    assert node.nmt.wait_for_heartbeat(1.0)
    waited = clock.monotonic() - t0
    assert 0 < waited <= 0.06, waited  # the heartbeat itself, in bench time
    t0 = clock.monotonic_ns()
    assert node.tpdo[1].wait_for_reception(0.3) is None  # not subscribed: its timeout
    assert clock.monotonic_ns() - t0 == 300_000_000
    net = hil_session.nets["can0"]
    mine = net.add_node(99, node.object_dictionary)  # a node the test adds itself
    t0 = clock.monotonic_ns()
    with pytest.raises(canopen.nmt.NmtError):
        mine.nmt.wait_for_heartbeat(0.25)  # nobody is node 99
    assert clock.monotonic_ns() - t0 == 250_000_000
    net.sync.start(0.01)  # canopen's SYNC producer: python-can's send_periodic on the bus
    clock.sleep(0.095)
    net.sync.stop()
'''


def test_canopen_waits_and_send_periodic_run_on_the_virtual_clock(pytester: pytest.Pytester,
                                                                   tmp_path) -> None:
    """A stranger's test on the virtual bench using canopen's own API on `hil_drive.cia.node`
    and the session's network: canopen's heartbeat wait and its SYNC producer (python-can's
    `send_periodic`) ran on the wall clock, so no heartbeat came and SYNC came at wall
    instants (docs/clock.md)."""
    rec = _one_passing_test(pytester, tmp_path, CANOPEN_WAITS)
    syncs = [lt for _t, lt, _p, m in rec.messages("/can/can0/raw")
             if m.get("id") == 0x80 and m.get("dir") == "tx"]
    assert len(syncs) == 10  # at 0, 10, ... 90 ms of the 95 ms
    assert {b - a for a, b in itertools.pairwise(syncs)} == {10_000_000}


SESSION_CLOCK = '''
import gc
import pytest
from hil import clock
from hil.plan.runner import VIRTUAL_GC_OLDER

BEFORE = gc.get_threshold()

@pytest.mark.hil
def test_on_the_bench_clock(hil_session, hil_bench):
    virtual = hil_bench.clock == "virtual"
    assert clock.is_virtual() == virtual
    assert gc.get_threshold()[1:] == (VIRTUAL_GC_OLDER if virtual else BEFORE[1:])

def test_after():
    assert gc.get_threshold() == BEFORE and not clock.is_virtual()
'''


@pytest.mark.parametrize("clk", ["virtual", "real"])
def test_hil_session_runs_on_the_clock_a_plan_runs_on(pytester: pytest.Pytester, clk) -> None:
    """`hil_session` sets its bench's clock up as `hil run` does (`bench_clock`): in virtual
    time the older collector generations are collected seldom, as during a plan."""
    pytester.makepyfile(test_sc=SESSION_CLOCK)
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-p", "no:randomly",
                                           f"--hil-clock={clk}")
    result.assert_outcomes(passed=2)


OPEN_AT_CLOSE = '''
import pytest
from hil import clock
from hil.protocol import modbus as mb

@pytest.mark.hil
def test_open_at_close(hil_session, hil_drive):
    # requests nobody answers (node 5, station 5 are not on the bench): the recording writes
    # them as unanswered when it closes, after hil_session has put the wall clock back
    hil_session.nets["can0"].send_message(0x605, bytes([0x40, 0x00, 0x10, 0, 0, 0, 0, 0]))
    hil_drive.modbus.port.write(mb.encode_adu(5, bytes([3, 0, 0, 0, 1]), "rtu"))
    clock.sleep(0.05)
'''


def test_a_pytest_recording_in_virtual_time_keeps_its_clock_to_the_end(
        pytester: pytest.Pytester, tmp_path) -> None:
    """What the recorder stamps at close (open SDO and Modbus transactions) is on the run's
    clock: it had the wall clock's 2026 among 2000's bench times."""
    from hil.clock import VIRTUAL_EPOCH_NS
    from hil.plan.runner import SAFE_TAIL_NS

    rec = _one_passing_test(pytester, tmp_path, OPEN_AT_CLOSE)
    assert rec.metadata()["hil.clock"]["clock"] == "virtual"
    times = {topic: [] for topic in rec.topics()}
    for topic, lt, _pt, _m in rec.messages():
        times[topic].append(lt)
    late = {t: max(v) - VIRTUAL_EPOCH_NS for t, v in times.items()
            if v and not VIRTUAL_EPOCH_NS <= max(v) < VIRTUAL_EPOCH_NS + 3600 * 10**9}
    assert late == {}
    # the two written at close are on the record, at the bench time the recording ended
    end = max(max(v) for v in times.values() if v)
    assert [(lt, m["status"]) for _t, lt, _pt, m in rec.messages("/canopen/can0/sdo")
            if m["node"] == 5] == [(end, "timeout")]
    assert [lt for _t, lt, _pt, m in rec.messages("/modbus/rs485")
            if m.get("unanswered") and m["unit"] == 5] == [end]
    # after the safe state the bench ran on SAFE_TAIL_NS, as after a plan (docs/clock.md):
    # the recording ended at the instant the safe state was reached
    [safe_t] = [lt for _t, lt, _pt, m in rec.messages("/safety")
                if m["action"] == "safe_state_reached"]
    assert end >= safe_t + SAFE_TAIL_NS
    assert max(times["/drive/drive1/state"]) >= safe_t + SAFE_TAIL_NS


LONG = '''
import pytest
from hil import clock

@pytest.mark.hil
def test_long(hil_drive):
    hil_drive.set_function("SON", True)
    assert clock.wait_for(lambda: hil_drive.do_active("BRKR"), 2.0)
    print("MOVING", flush=True)
    clock.sleep(900)
'''


@pytest.mark.integration
@pytest.mark.parametrize(("clk", "sig"), [("virtual", "SIGINT"), ("virtual", "SIGTERM"),
                                          ("real", "SIGTERM")])
def test_a_fixture_test_stopped_by_a_signal_leaves_the_bench_safe(tmp_path, clk, sig) -> None:
    """Ctrl-C in a fixture test on the virtual clock landed inside a clock event (a host
    tick that had not scheduled the next): the model stopped, BRKR never went off and the
    safe state was not confirmed; SIGTERM killed pytest with no safe state at all and a
    truncated recording (an outside review). Both now stop the test as `hil run` does."""
    import signal
    import subprocess
    import sys
    import time

    from hil.record.reader import Recording

    (tmp_path / "test_long.py").write_text(LONG)
    out = tmp_path / "out"
    proc = subprocess.Popen([sys.executable, "-m", "pytest", "-q", "-s", "-p", "no:cacheprovider",
                             "-p", "no:randomly", f"--hil-out={out}", f"--hil-clock={clk}",
                             "test_long.py"], cwd=tmp_path, stdout=subprocess.PIPE,
                            stderr=subprocess.STDOUT, text=True)
    try:
        assert proc.stdout is not None
        for line in proc.stdout:
            if "MOVING" in line:
                break
        time.sleep(0.5)
        proc.send_signal(getattr(signal, sig))
        proc.communicate(timeout=60)
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait(10)
    [path] = out.glob("*.mcap")
    rec = Recording.open(path)
    assert not rec.truncated, rec.error
    result = rec.metadata()["hil.result"]
    assert result["status"] == "aborted" and sig in result["reason"], result
    assert result["safe_state_ok"] in ("true", "True"), result
    actions = [m["action"] for *_t, m in rec.messages(["/safety"])]
    assert actions and actions[-1] == "safe_state_reached", actions


def test_a_plan_tag_that_is_a_pytest_marker_does_not_change_how_it_runs(
        pytester: pytest.Pytester) -> None:
    """Plan tags become markers; a tag `skip`, `xfail`, `flaky` or `timeout` skipped the
    plan, made its failure XFAIL, reran it on the bench or crashed the session, and `axis:x`
    broke --strict-markers (an outside review). Such tags are not applied, with a warning."""
    plans = pytester.mkdir("plans")
    text = _shipped("emgs").read_text()
    assert "tags: [emgs, alarm, brake, safety]" in text
    for i, tag in enumerate(("skip", "xfail", "flaky", "timeout", "'axis:x'")):
        (plans / f"p{i}.yaml").write_text(
            text.replace("name: emgs", f"name: p{i}")
            .replace("tags: [emgs, alarm, brake, safety]", f"tags: [brake, {tag}]")
            .rstrip("\n") + "\n  - expect: {alarm: AL013}\n")  # released: AL013 is gone
    pytester.makeini("[pytest]\nhil_plans = plans\n")
    result = pytester.runpytest_subprocess("-m", "brake", "-q", "-p", "no:cacheprovider",
                                           "--strict-markers", "-W", "default")
    result.assert_outcomes(failed=5)  # every plan ran, and failed at its last step
    assert "is not applied as a marker" in result.stdout.str()


def test_hil_run_plan_takes_a_name_from_the_projects_plans_first(pytester: pytest.Pytester
                                                                 ) -> None:
    """`hil_run_plan("servo_on_off_brake")` ran hil's own plan even when the project's
    `hil_plans` holds its own of that name, and a plan only the project has was not found
    (an outside review)."""
    plans = pytester.mkdir("plans")
    text = _shipped("servo_on_off_brake").read_text()
    (plans / "servo_on_off_brake.yaml").write_text(
        text.rstrip("\n") + "\n  - expect: {alarm: AL999}\n")  # the project's own: fails
    (plans / "only_here.yaml").write_text(text.replace("name: servo_on_off_brake",
                                                       "name: only_here"))
    pytester.makeini("[pytest]\nhil_plans = plans\n")
    pytester.makepyfile(test_runs='''
def test_project_plan(hil_run_plan):
    assert not hil_run_plan("servo_on_off_brake").passed

def test_only_here(hil_run_plan):
    assert hil_run_plan("only_here").passed
''')
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "test_runs.py")
    result.assert_outcomes(passed=2)


def test_two_test_ids_that_read_alike_keep_a_recording_each(pytester: pytest.Pytester,
                                                            tmp_path) -> None:
    """`test_move[fast]` and `test_move_fast`, `a/test_b.py::t` and `a_test_b.py::t` wrote
    one file, the later test over the earlier (an outside review)."""
    body = ("import pytest\n@pytest.mark.parametrize('p', ['fast'])\n"
            "def test_move(hil_recorder, p):\n    pass\n"
            "def test_move_fast(hil_recorder):\n    pass\n")
    pytester.makepyfile(test_one=body)
    pytester.mkdir("a")
    (pytester.path / "a" / "test_b.py").write_text("def test_t(hil_recorder):\n    pass\n")
    (pytester.path / "a_test_b.py").write_text("def test_t(hil_recorder):\n    pass\n")
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", f"--hil-out={out}",
                                           "test_one.py", "a/test_b.py", "a_test_b.py")
    result.assert_outcomes(passed=4)
    assert len(list(out.glob("*.mcap"))) == 4, sorted(p.name for p in out.glob("*"))
    out2 = tmp_path / "out2"  # a parametrized id's name depends on the id alone: xdist too
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", f"--hil-out={out2}",
                                           "-n", "2", "test_one.py")
    result.assert_outcomes(passed=2)
    assert len(list(out2.glob("*.mcap"))) == 2, sorted(p.name for p in out2.glob("*"))


@pytest.mark.skipif(not __import__("os").path.isdir("/proc/self"), reason="needs /proc")
def test_an_output_directory_nothing_can_be_written_to_is_a_usage_error(
        pytester: pytest.Pytester, tmp_path) -> None:
    """`--hil-out` / `hil run --out` on a directory nothing can be made in (a read-only
    mount, /proc) failed every test with a PermissionError traceback (an outside review);
    it is one usage error before anything runs, as a file there is."""
    from hil.cli import main
    from hil.fileio import dir_problem

    assert dir_problem("/proc") == "not writable"
    assert dir_problem("/proc/hil-out") == "/proc is not writable"
    assert dir_problem(tmp_path / "new" / "dir") is None
    assert main(["run", "emgs", "--out", "/proc/hil-out", "-q"]) == 2
    pytester.makepyfile(test_one="def test_a(hil_recorder):\n    pass\n")
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "--hil-out=/proc")
    assert result.ret == pytest.ExitCode.USAGE_ERROR
    assert "--hil-out /proc: not writable" in result.stderr.str()


def test_a_hil_plans_directory_that_is_not_there_is_said(pytester: pytest.Pytester) -> None:
    """`hil_plans = plan` (a typo) collected nothing without a word (an outside review)."""
    pytester.makeini("[pytest]\nhil_plans = plan\n")
    pytester.makepyfile(test_one="def test_a():\n    pass\n")
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider")
    result.assert_outcomes(passed=1, warnings=1)
    assert "hil_plans:" in result.stdout.str() and "is not a directory" in result.stdout.str()


def test_xdist_workers_never_share_one_bench(pytester: pytest.Pytester) -> None:
    """`hil run -j` runs a real bench (or one on fixed transports) one plan at a time; under
    pytest -n 2 both workers would have driven it at once (an outside review)."""
    from hil.paths import fixture

    text = fixture("benches", "virtual-zenoh.yaml").read_text()
    for _ in range(3):
        text = text.replace("tcp/127.0.0.1:auto", "tcp/127.0.0.1:17447", 1)
    (pytester.path / "fixed.yaml").write_text(text)
    pytester.makepyfile(test_one="def test_a(hil_bench):\n    pass\n"
                                 "def test_b(hil_bench):\n    pass\n")
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-n", "2",
                                           "--hil-bench=fixed.yaml")
    assert result.ret != 0
    assert "pytest-xdist with 2 workers" in (result.stdout.str() + result.stderr.str())
    ok = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-n", "2")
    ok.assert_outcomes(passed=2)  # the built-in virtual bench: private to each worker


def test_a_tag_the_project_declares_as_a_marker_is_still_applied(pytester: pytest.Pytester
                                                                 ) -> None:
    """A project that declares `brake` in its own ini `markers` (as --strict-markers asks)
    lost the tag on its plans: `-m brake` selected nothing (a review of the change)."""
    plans = pytester.mkdir("plans")
    (plans / "emgs.yaml").write_text(_shipped("emgs").read_text())
    pytester.makeini("[pytest]\nhil_plans = plans\nmarkers =\n    brake: brake tests\n")
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-m", "brake",
                                           "--collect-only")
    assert "1 test collected" in result.stdout.str() or "emgs" in result.stdout.str(), \
        result.stdout.str()
    assert "not applied" not in result.stdout.str()



@pytest.mark.parametrize("config", ["ini", "pyproject"])
def test_a_declared_marker_is_found_without_a_deprecation_warning(pytester: pytest.Pytester,
                                                                  config: str) -> None:
    """The plugin read the project's own markers through `config.inicfg`, which pytest 9
    deprecates: every run printed two PytestRemovedIn10Warning lines. It reads the config
    file instead, an ini or a pyproject.toml alike."""
    plans = pytester.mkdir("plans")
    (plans / "emgs.yaml").write_text(_shipped("emgs").read_text())
    if config == "ini":
        pytester.makeini("[pytest]\nhil_plans = plans\nmarkers =\n    brake: brake tests\n")
    else:
        pytester.makepyprojecttoml('[tool.pytest.ini_options]\nhil_plans = "plans"\n'
                                   'markers = ["brake: brake tests"]\n')
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", "-m", "brake",
                                           "--collect-only", "-W", "error::DeprecationWarning")
    out = result.stdout.str() + result.stderr.str()
    assert result.ret == 0, out
    assert "emgs" in out and "not applied" not in out and "inicfg" not in out


TEARDOWN = '''
import pytest

@pytest.fixture
def axis(hil_drive):            # torn down before hil_session: its error came too late
    yield hil_drive
    raise RuntimeError("the axis fixture could not park")

@pytest.fixture
def late():                     # set up first, so torn down after the recorder's fixture
    yield
    raise ValueError("late fixture broke")

@pytest.fixture
def skips_late():
    yield
    pytest.skip("nothing to park")

@pytest.mark.hil
def test_teardown_fails(axis):
    axis.set_function("SON", True)

@pytest.mark.hil
def test_late_teardown_fails(late, hil_drive):
    hil_drive.set_function("SON", True)

@pytest.mark.hil
def test_late_skip(skips_late, hil_drive):
    hil_drive.set_function("SON", True)

@pytest.mark.hil
def test_clean(hil_drive):
    hil_drive.set_function("SON", True)

@pytest.mark.hil
def test_check_twice(hil_drive, hil_recorder, hil_check):
    hil_drive.write_param("P1.042", 80)
    hil_drive.set_function("SON", True)
    hil_drive.dio.wait_for("DO6", True, 2.0)
    first = hil_check("servo_on_brake", params={"P1.042": 80})
    second = hil_check("servo_on_brake", params={"P1.042": 80})
    assert [v.to_dict() for v in first] == [v.to_dict() for v in second]
'''


def test_a_fixture_teardown_error_is_the_recordings_result(pytester: pytest.Pytester,
                                                           tmp_path) -> None:
    """A fixture's teardown error is an error of the test in pytest, so its recording must
    not say `pass` (an outside review found `hil.result` pass beside pytest's ERROR); a
    `hil_check` of the same spec twice records each verdict once."""
    from hil.record.reader import Recording

    pytester.makepyfile(test_td=TEARDOWN)
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-q", "-p", "no:cacheprovider", f"--hil-out={out}")
    result.assert_outcomes(passed=5, errors=2, skipped=1)  # the skipped teardown: a pass too

    def rec_of(part: str) -> Recording:
        [path] = [p for p in out.glob("*.mcap") if part in p.name]
        return Recording.open(path)

    for part, why in (("test_teardown_fails", "could not park"),
                      ("test_late_teardown_fails", "late fixture broke")):
        res = rec_of(part).metadata()["hil.result"]
        assert res["status"] == "error" and why in res["reason"], res
        assert res["safe_state_ok"] in (True, "True", "true"), res
    assert rec_of("test_clean").metadata()["hil.result"]["status"] == "pass"
    assert rec_of("test_late_skip").metadata()["hil.result"]["status"] == "skipped"
    twice = rec_of("test_check_twice")
    assert not twice.truncated
    verdicts = [m for *_t, m in twice.messages(["/timing/verdicts"])]
    keys = [(v["spec"], v["constraint"], v["occurrence"], v["t_ns"]) for v in verdicts]
    assert verdicts and len(keys) == len(set(keys)), keys


UNSAFE = '''
import pytest
from hil import clock

@pytest.mark.hil
def test_do6_remapped(hil_drive):
    hil_drive.write_param("P2.041", 0x0101)  # DO6 now SRDY: BRKR is on no line
    hil_drive.set_function("SON", True)
    clock.sleep(0.2)
'''


def test_a_test_that_leaves_the_bench_unsafe_errors_at_teardown(pytester: pytest.Pytester,
                                                                tmp_path) -> None:
    """The test passed, the safe state could not be confirmed (the brake wait timed out):
    pytest said "1 passed" and exited 0 (an outside probe). The teardown now errors, and the
    recording's `hil.result` says error."""
    from hil.record.reader import Recording

    pytester.makepyfile(test_one=UNSAFE)
    out = tmp_path / "out"
    result = pytester.runpytest_subprocess("-m", "hil", "-q", "-p", "no:cacheprovider",
                                           f"--hil-out={out}")
    result.assert_outcomes(passed=1, errors=1)
    result.stdout.fnmatch_lines(["*safe state was not confirmed*BRKR*"])
    (path,) = out.glob("*.mcap")
    meta = Recording.open(path).metadata()["hil.result"]
    assert meta["status"] == "error" and meta["safe_state_ok"] == "false", meta
