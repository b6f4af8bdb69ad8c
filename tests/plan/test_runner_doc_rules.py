"""What docs/plans.md and the README promise of `hil run`, each checked on the built-in virtual
bench in virtual time (an outside review, helper-20 in wave 3 session 12, found each broken):
a bad `--out`, every bad file named, a zero timeout, `since:` on a name two steps share, a
`wait_until` longer than the bench's step timeout, skipped steps under `-v`, the plan page's
link to the run's index."""

from __future__ import annotations

from pathlib import Path

import pytest

from hil.cli import main as hil

OK = "name: ok\nsteps:\n  - expect: {do: {SRDY: on}}\n"


def _plan(tmp_path: Path, name: str, text: str) -> str:
    p = tmp_path / f"{name}.yaml"
    p.write_text(text)
    return str(p)


@pytest.mark.parametrize("where", ["afile", "afile/sub"])
def test_an_out_that_is_a_file_is_bad_input_and_nothing_runs(tmp_path, capsys, where):
    """README: "Every command exits 2 on bad input"; the reason on stderr, no traceback."""
    plan = _plan(tmp_path, "ok", OK)
    (tmp_path / "afile").write_text("not a directory")
    for extra in ([], ["--check"]):
        assert hil(["run", "-q", "-j", "1", *extra, "--out", str(tmp_path / where), plan]) == 2
        err = capsys.readouterr().err
        assert "--out" in err and "not a directory" in err and "Traceback" not in err
    assert (tmp_path / "afile").read_text() == "not a directory"


def test_every_bad_plan_file_is_named_not_only_the_first(tmp_path, capsys):
    """docs/plans.md: `--check` says "Everything a run would refuse, each as
    `file:line: field: problem`"."""
    good = _plan(tmp_path, "ok", OK)
    bad1 = _plan(tmp_path, "bad1", "name: bad1\nsteps:\n  - wait: 10 parsecs\n")
    bad2 = _plan(tmp_path, "bad2", "name: bad2\nsteps:\n  - di: {SON: maybe}\n")
    # a file that parses but the bench refuses (no such drive): named beside the others
    bad3 = _plan(tmp_path, "bad3", "name: bad3\nsteps:\n  - expect: {state: FAULT}\n"
                 "    drive: nosuch\n")
    for extra in (["--check"], ["--out", str(tmp_path / "out")]):
        assert hil(["run", "-q", "-j", "1", *extra, good, bad1, bad2, bad3]) == 2
        err = capsys.readouterr().err
        assert "bad1.yaml:3: steps[0].wait" in err and "bad2.yaml:3: steps[0].di.SON" in err
        assert "bad3.yaml:3: steps[0].drive: bench 'virtual' has no drive 'nosuch'" in err
        assert "ok.yaml" not in err
    # -k / -m select among the files that loaded: an unselected one is not checked
    assert hil(["run", "-q", "--check", "-k", "ok", good, bad1, bad3]) == 2
    err = capsys.readouterr().err
    assert "bad1.yaml:3: steps[0].wait" in err and "bad3.yaml" not in err
    assert not (tmp_path / "out").exists()  # nothing ran


@pytest.mark.parametrize("step", ["  - wait: 5s\n    timeout: 0ms\n",
                                  "  - wait_until: {do: {BRKR: on}, timeout: 0s}\n"])
def test_a_zero_timeout_is_refused(tmp_path, capsys, step):
    """"the step ends at its timeout": 0 is no timeout the runner could keep."""
    plan = _plan(tmp_path, "zero", f"name: zero\nsteps:\n{step}")
    assert hil(["run", "--check", plan]) == 2
    assert "timeout: must be > 0" in capsys.readouterr().err


def test_since_a_name_two_earlier_steps_share_is_refused(tmp_path, capsys):
    """`since:` "the `name` of an earlier step (its start)": with two such steps, which one
    is not said, so the plan is refused with both lines."""
    plan = _plan(tmp_path, "dup", """\
name: dup
steps:
  - di: {SON: on}
    name: a
  - wait: 20ms
  - di: {SON: on}
    name: a
  - check_timing: {spec: servo_on_brake, since: a}
""")
    assert hil(["run", "--check", plan]) == 2
    assert "dup.yaml:8: steps[3].check_timing.since: 'a' names 2 earlier steps (lines 3, 6)" \
        in capsys.readouterr().err


def test_a_wait_until_longer_than_the_step_timeout_fails_at_its_own_timeout(tmp_path, capsys):
    """A `wait_until` takes its timeout inside it (not `timeout:` on the step); 70 s on a
    bench whose step timeout is 60 s fails at 70 s saying what it saw, not as a step error."""
    plan = _plan(tmp_path, "long", "name: long\nsteps:\n"
                 "  - wait_until: {do: {BRKR: on}, timeout: 70s}\n")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out"), plan]) == 1
    err = capsys.readouterr().err
    assert "FAIL" in err and "timeout 70000 ms waiting for DO BRKR on; saw BRKR off" in err
    assert "step timeout 60 s" not in err


def test_a_wait_or_an_own_timeout_longer_than_the_step_timeout_is_kept(tmp_path, capsys):
    """A `wait: 70s` (and a `pr_wait` whose own timeout is 70 s) on a bench whose step
    timeout is 60 s: the plan said to wait that long, so the wait ends and the `pr_wait`
    fails at its own timeout saying what it saw; neither is cut as a step error at 60 s (an
    outside fuzz found `wait: 1000s` passing `--check` and erroring at the bench's 60 s)."""
    plan = _plan(tmp_path, "longwait", "name: longwait\nsteps:\n  - wait: 70s\n"
                 "  - pr_wait: {pr: 1, state: in_position, timeout: 70s}\n")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out"), plan]) == 1
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("  [")]
    assert "PASS" in lines[0], lines
    assert "FAIL" in lines[1] and "step timeout" not in lines[1], lines


def test_a_step_level_timeout_still_bounds_a_step_with_its_own(tmp_path, capsys):
    """A step-level `timeout:` is the plan's word for the whole step: a `pr_wait` (default
    inner timeout 5 s) with `timeout: 300ms` ends at 300 ms as a step timeout, and a `wait:
    2s` with `timeout: 500ms` too (a review found both run to their inner times)."""
    plan = _plan(tmp_path, "bounded", "name: bounded\nsteps:\n"
                 "  - pr_wait: {pr: 1, state: in_position}\n    timeout: 300ms\n")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out"), plan]) == 1
    err = capsys.readouterr().err
    assert "step timeout 0.3 s" in err, err
    plan = _plan(tmp_path, "bounded2", "name: bounded2\nsteps:\n"
                 "  - wait: 2s\n    timeout: 500ms\n")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out2"), plan]) == 1
    assert "step timeout 0.5 s" in capsys.readouterr().err


def test_verbose_prints_every_step_skipped_ones_too(tmp_path, capsys):
    """docs/plans.md: "`-v` prints one line per step with its status"."""
    plan = _plan(tmp_path, "f", """\
name: f
steps:
  - expect: {do: {BRKR: on}}
  - wait: 10ms
  - expect: {alarm: none}
""")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out"), plan]) == 1
    lines = [ln for ln in capsys.readouterr().err.splitlines() if ln.startswith("  [")]
    assert [ln.split()[1] for ln in lines] == ["1/3]", "2/3]", "3/3]"]
    assert "SKIPPED" in lines[1] and "SKIPPED" in lines[2]


def test_a_plan_page_links_to_the_run_index_written_after_it(tmp_path):
    """README (`hil report`): the page "links back to the run's index and to the recording";
    `hil run` writes index.html after the plan pages, in a fresh folder too."""
    plan = _plan(tmp_path, "ok", OK)
    out = tmp_path / "fresh"
    assert hil(["run", "-q", "-j", "1", "--out", str(out), plan]) == 0
    page = (out / "ok.html").read_text()
    assert "href='index.html'" in page and (out / "index.html").exists()
    assert "href='ok.mcap'" in page


def test_a_write_the_drive_refuses_is_refused_by_check_p0_001(tmp_path, capsys):
    """--check refuses what a run would: P0.001 takes only 0 (the alarm reset, L7079-7083); the
    drive answers anything else with Modbus exception 03h."""
    bad = _plan(tmp_path, "p1", "name: p1\nsteps:\n  - write: {P0.001: 5}\n")
    good = _plan(tmp_path, "p0", "name: p0\nsteps:\n  - write: {P0.001: 0}\n")
    assert hil(["run", "--check", bad]) == 2
    assert "p1.yaml:3: " in (err := capsys.readouterr().err) and "only 0" in err
    assert hil(["run", "--check", good]) == 0


def test_a_plan_argument_that_exists_but_is_no_plan_file_says_so(tmp_path, capsys):
    (tmp_path / "notes.txt").write_text("name: x\n")
    for arg, what in ((str(tmp_path / "notes.txt"), "not a .yaml file"),
                      (str(tmp_path), "a directory")):
        assert hil(["run", "--check", arg]) == 2
        err = capsys.readouterr().err
        assert what in err and "no such plan file" not in err


def test_the_plans_params_are_cited_at_their_own_line(tmp_path):
    """A step is cited as `file:line`; the `params:` the runner writes first is no step of
    the list, but it has a line too (not "line 0")."""
    plan = _plan(tmp_path, "pl", "name: pl\n\nparams: {P1.042: 100}\nsteps:\n"
                 "  - expect: {do: {SRDY: on}}\n")
    out = tmp_path / "out"
    assert hil(["run", "-q", "-j", "1", "--out", str(out), plan]) == 0
    junit = (out / "junit.xml").read_text()
    assert "step params" in junit and "pl.yaml:3): P1.042=100" in junit


def test_a_virtual_drive_whose_model_fails_ends_the_plan(tmp_path, capsys, monkeypatch):
    """A drive model that raises (a bench value the model cannot take) used to leave the
    drive's outputs frozen and the plan passing; the bench now reports the drive dead and the
    step errors, as a drive process that died does."""
    from hil.model.drive import Drive

    real = Drive._integrate_to

    def failing(self, stop):  # the model breaks 50 ms into the plan
        if self.sched.now > 50_000_000:
            raise ValueError("cannot convert float NaN to integer")
        return real(self, stop)

    monkeypatch.setattr(Drive, "_integrate_to", failing)
    plan = _plan(tmp_path, "m", "name: m\nsteps:\n  - wait: 200ms\n  - wait: 10ms\n")
    assert hil(["run", "-v", "-j", "1", "--out", str(tmp_path / "out"), plan]) == 1
    err = capsys.readouterr().err
    assert "ERROR" in err and "its model failed (ValueError" in err


def test_hil_check_svg_on_a_plan_recording_draws_each_check(tmp_path, capsys):
    """docs/timing.md: `--svg DIR` writes the diagrams, and a DIR that is a file is bad input
    (exit 2); on a plan recording too, where each check step is judged as it was run."""
    out = tmp_path / "out"
    assert hil(["run", "-q", "-j", "1", "--out", str(out), "servo_on_off_brake"]) == 0
    rec = str(out / "servo_on_off_brake.mcap")
    svgs = tmp_path / "svg"
    assert hil(["check", rec, "--svg", str(svgs)]) == 0
    drawn = sorted(p.name for p in svgs.iterdir())
    assert drawn and all(n.endswith(".svg") for n in drawn)
    assert all((svgs / n).read_text().startswith("<svg") for n in drawn)
    (tmp_path / "afile").write_text("x")
    capsys.readouterr()
    assert hil(["check", rec, "--svg", str(tmp_path / "afile")]) == 2
    assert "--svg" in capsys.readouterr().err


def test_a_hil_drive_process_whose_model_fails_exits(monkeypatch, capsys):
    """`hil drive` (the drive of a subprocess bench) stops with exit 1 when its model fails,
    so the runner sees the process die rather than a drive whose outputs froze."""
    from hil.model.drive import Drive

    real = Drive._integrate_to

    def failing(self, stop):
        if self.sched.now > 20_000_000:
            raise ValueError("cannot convert float NaN to integer")
        return real(self, stop)

    monkeypatch.setattr(Drive, "_integrate_to", failing)
    import signal

    saved = {sig: signal.getsignal(sig) for sig in (signal.SIGINT, signal.SIGTERM)}
    try:  # `hil drive` installs its own handlers: this process's come back after
        assert hil(["drive", "--dio", "virtual:model-fails", "--di", "8=1"]) == 1
    finally:
        for sig, handler in saved.items():
            signal.signal(sig, handler)
    assert "the model failed (ValueError" in capsys.readouterr().err



def test_a_p3001_digit_the_drive_refuses_is_refused_by_check(tmp_path, capsys):
    """P3.001's digits have ranges of their own (X 0-5, Y 0, Z 0-4, U 0-3, L10519-L10522):
    0x0006 is inside the table's 0x0000-0x3405 but its X is not, so --check refuses it at its
    line, as the drive would (exception 03h)."""
    bad = _plan(tmp_path, "b", "name: b\nsteps:\n  - write: {P3.001: 0x0006}\n")
    good = _plan(tmp_path, "g", "name: g\nsteps:\n  - write: {P3.001: 0x0203}\n")
    assert hil(["run", "--check", bad]) == 2
    err = capsys.readouterr().err
    assert "b.yaml:3: " in err and "digit X = 6" in err and "L10519" in err
    assert hil(["run", "--check", good]) == 0


def test_an_interrupt_is_recorded_with_the_signal_that_made_it() -> None:
    """hil.result's reason and the cut step's message name SIGINT or SIGTERM (a supervisor's
    SIGTERM and an operator's Ctrl-C read the same before)."""
    import signal

    from hil.plan.runner import interrupt_cause, signal_text

    assert signal_text(signal.SIGINT) == "SIGINT (Ctrl-C)"
    assert signal_text(signal.SIGTERM) == "SIGTERM"
    assert interrupt_cause(KeyboardInterrupt(signal_text(signal.SIGTERM))) == "SIGTERM"
    assert interrupt_cause(KeyboardInterrupt()) == "Ctrl-C / SIGTERM"  # raised elsewhere


def test_check_judges_a_plans_params_in_order_as_the_virtual_drive_takes_them(tmp_path,
                                                                             capsys):
    """docs/plans.md: `--check` refuses what a run would. An outside probe (session 22):
    `params: {P1.044: 1, P1.045: 2}` passed the check and the run ended in ERROR, the drive
    refusing P1.044 = 1 against the P1.045 it still had (1/100000, L8547, a PT mode)."""
    def plan(name: str, pairs: str) -> str:
        return _plan(tmp_path, name, f"name: {name}\nparams:\n{pairs}steps:\n  - wait: 1ms\n")

    never = plan("never", "  P1.044: 1\n  P1.045: 2\n")
    m_first = plan("mfirst", "  P1.044: 10000\n  P1.045: 1000\n")
    assert hil(["run", "-q", "--check", never, m_first]) == 2
    err = capsys.readouterr().err
    assert ("never.yaml:3: params.P1.044: P1.044 = 1: e-gear ratio 1/100000 outside" in err
            and "neither order reaches 1/2 from the drive's 16777216/100000" in err)
    assert ("mfirst.yaml:3: params.P1.044: P1.044 = 10000: e-gear ratio 10000/100000" in err
            and "write the denominator P1.045 first" in err)
    # listed the other way round the run takes it, and the check says so
    swapped = plan("swapped", "  P1.045: 1000\n  P1.044: 10000\n")
    assert hil(["run", "-q", "--check", swapped]) == 0
    assert hil(["run", "-q", "-j", "1", "--out", str(tmp_path / "out"), swapped]) == 0
