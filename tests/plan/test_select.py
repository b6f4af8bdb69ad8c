"""Plan selection for `hil run`: -k / -m expressions, globs, --list, HIL_BENCH (issue 18)."""

from __future__ import annotations

import os
import re
import subprocess
import sys
from pathlib import Path
from types import SimpleNamespace

import pytest

from hil.bench.yamlio import PlanFileError
from hil.paths import fixture
from hil.plan.plan import find_plans
from hil.plan.select import Expr, ExprError, matches, select


def P(name, tags=(), path=None):
    return SimpleNamespace(name=name, tags=list(tags), path=path or f"plans/{name}.yaml")


@pytest.mark.parametrize(("expr", "names", "want"), [
    ("brake", {"servo_on_off_brake"}, True),
    ("BRAKE", {"servo_on_off_brake"}, True),  # -k is case-insensitive, like pytest
    ("brake and not sto", {"sto_both", "brake"}, False),
    ("brake and not sto", {"servo_brake_settings"}, True),
    ("(pr or homing) and not capture", {"capture_pr50", "pr"}, False),
    ("(pr or homing) and not capture", {"homing_limits"}, True),
    ("not not pr", {"pr_jump_loop"}, True),
])
def test_keyword_expressions(expr, names, want):
    assert matches(expr, names) is want


def test_marker_expressions_match_whole_tags_or_globs():
    assert not Expr.parse("bra").match(["brake"], exact=True)  # -m: a tag, not a substring
    assert Expr.parse("brake or sto").match(["sto"], exact=True)
    assert Expr.parse("fault_*").match(["fault_can"], exact=True)


@pytest.mark.parametrize(("expr", "why"), [
    ("", "empty expression"), ("brake and", "ends too early"), ("(brake", "missing ')'"),
    ("brake sto", "unexpected 'sto'"), ("and brake", "unexpected 'and'"),
    ("brake or )", "unexpected ')'"), ("a;b", "unexpected 'a;b'"),
])
def test_malformed_expressions_say_what_is_wrong(expr, why):
    with pytest.raises(ExprError, match=re.escape(why)):
        Expr.parse(expr)


def test_select_applies_k_and_m_together():
    plans = [P("servo_on_off_brake", ["brake"]), P("sto_both", ["sto", "brake"]),
             P("pr_jump_loop", ["pr", "motion"])]
    assert [p.name for p in select(plans, marker="brake")] == ["servo_on_off_brake", "sto_both"]
    assert [p.name for p in select(plans, "not sto", "brake")] == ["servo_on_off_brake"]
    assert [p.name for p in select(plans, "motion")] == ["pr_jump_loop"]  # -k sees tags too


def test_globs_pick_plans_by_name(tmp_path):
    for n in ("pr_a", "pr_b", "sto_c"):
        (tmp_path / f"{n}.yaml").write_text("name: x\nsteps:\n  - wait: 1ms\n")
    assert [p.stem for p in find_plans(["pr_*"], tmp_path)] == ["pr_a", "pr_b"]
    assert [p.stem for p in find_plans(["pr_b", "pr_*"], tmp_path)] == ["pr_b", "pr_a"]
    with pytest.raises(PlanFileError, match="no plan matches 'zz_\\*'"):
        find_plans(["zz_*"], tmp_path)


def test_long_and_deep_expressions_give_an_error_not_a_recursion_error():
    """`x or x or ...` 20 000 times matched through 20 000 nested calls and `((((...` or
    `not not ...` 5 000 deep recursed in the parser: RecursionError tracebacks. Chains are
    now flat, and nesting beyond MAX_DEPTH is an ExprError (exit 2 in `hil run`)."""
    assert matches(" or ".join(["zz"] * 20_000 + ["brake"]), {"servo_on_off_brake"})
    assert not matches(" and ".join(["brake"] * 20_000 + ["zz"]), {"servo_on_off_brake"})
    assert matches("(" * 50 + "not " * 40 + "brake" + ")" * 50, {"brake"})
    for deep in ("(" * 5000 + "pr" + ")" * 5000, "not " * 5000 + "pr"):
        with pytest.raises(ExprError, match="nested more than 100 deep"):
            Expr.parse(deep)


def test_absolute_and_bad_globs(tmp_path):
    """An absolute glob (pathlib globs relative patterns only) and `**` inside a name gave a
    traceback; now the plans it matches, or a PlanFileError that `hil run` reports (exit 2)."""
    for n in ("pr_a", "pr_b"):
        (tmp_path / f"{n}.yaml").write_text("name: x\nsteps:\n  - wait: 1ms\n")
    assert find_plans([f"{tmp_path}/pr_*"], tmp_path) == [tmp_path / "pr_a.yaml",
                                                           tmp_path / "pr_b.yaml"]
    with pytest.raises(PlanFileError, match="no plan matches"):
        find_plans([f"{tmp_path}/zz_*.yaml"], tmp_path)
    for bad in ("x**", f"{tmp_path}/**"):
        with pytest.raises(PlanFileError, match="not a usable glob"):
            find_plans([bad], tmp_path)
    r = _hil("--list", "/nonexistent-hil/*.yaml")
    assert r.returncode == 2 and "no plan matches '/nonexistent-hil/*.yaml'" in r.stderr
    assert "Traceback" not in r.stderr


def _hil(*args: str, env: dict | None = None, cwd: Path | None = None
         ) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hil.cli", "run", *args], capture_output=True,
                          text=True, timeout=120, env={**os.environ, **(env or {})}, cwd=cwd)


def test_list_shows_selected_plans_with_tags_and_runs_nothing(tmp_path):
    r = _hil("--list", "-m", "sto", "--out", str(tmp_path / "out"))
    assert r.returncode == 0, r.stderr
    names = [line.split()[0] for line in r.stdout.splitlines()]
    assert names == ["sto_both", "sto_short_dropout", "sto_single_channel"]
    assert "sto, safety" in r.stdout
    assert not (tmp_path / "out").exists()


def test_bad_expression_is_a_usage_error_and_empty_selection_exit_5():
    r = _hil("--list", "-k", "brake and")
    assert r.returncode == 2 and "-k/-m: 'brake and': expression ends too early" in r.stderr
    r = _hil("--list", "-m", "no_such_tag")
    assert r.returncode == 5 and "none selected by -k/-m" in r.stderr


def test_hil_bench_environment_variable_chooses_the_bench(tmp_path):
    bench = tmp_path / "mine.yaml"
    bench.write_text(fixture("benches", "virtual.yaml").read_text().replace(
        "name: virtual", "name: from_env", 1))
    r = _hil("--check", "servo_on_off_brake", env={"HIL_BENCH": str(bench)})
    assert r.returncode == 0, r.stderr
    assert f"bench: {bench} (from $HIL_BENCH)" in r.stderr
    r = _hil("--check", "servo_on_off_brake", env={"HIL_BENCH": str(tmp_path / "nope.yaml")})
    assert r.returncode == 2 and "nope.yaml" in r.stderr


def test_last_failed_reruns_only_what_failed(tmp_path, capsys):
    """`hil run --lf`: the plans whose testcase failed in `<out>/junit.xml`; all of them when
    there was no previous run or none failed (as pytest's --lf)."""
    from hil.cli import main as hil

    plans = tmp_path / "plans"
    plans.mkdir()
    (plans / "ok.yaml").write_text("name: ok\nsteps:\n  - expect: {do: {SRDY: on}}\n")
    (plans / "bad.yaml").write_text("name: bad\nsteps:\n  - expect: {do: {BRKR: on}}\n")
    out = tmp_path / "out"
    args = ["run", "-q", "--plans", str(plans), "--out", str(out), "--lf"]
    assert hil(args) == 1  # no previous run: both ran, bad failed
    assert "no previous run" not in capsys.readouterr().err  # -q
    (out / "ok.mcap").unlink()
    assert hil([*args[:1], *args[2:]]) == 1  # not quiet now: only bad runs again
    err = capsys.readouterr().err
    assert "1 of 2 plan(s) failed last time" in err
    assert not (out / "ok.mcap").exists()


def test_last_failed_tells_two_plans_of_one_name_apart_by_their_recording(tmp_path, capsys):
    """Two plans named `same` in two folders run as `a-same` and `b-same`; only b failed, so
    `--lf` runs only b (README: "only the plans that failed in the previous run")."""
    from hil.cli import main as hil

    for folder, want in (("a", "SRDY"), ("b", "BRKR")):
        (tmp_path / folder).mkdir()
        (tmp_path / folder / "same.yaml").write_text(
            f"name: same\nsteps:\n  - expect: {{do: {{{want}: on}}}}\n")
    out = tmp_path / "out"
    files = [str(tmp_path / "a" / "same.yaml"), str(tmp_path / "b" / "same.yaml")]
    assert hil(["run", "-q", "-j", "1", "--out", str(out), *files]) == 1
    capsys.readouterr()
    assert hil(["run", "-j", "1", "--out", str(out), "--lf", "--list", *files]) == 0
    cap = capsys.readouterr()
    assert "1 of 2 plan(s) failed last time" in cap.err
    assert [line.split()[-1] for line in cap.out.splitlines()] == [files[1]]


def test_last_failed_remembers_a_failure_an_interrupted_run_never_reached(tmp_path, capsys):
    """An interrupted run writes junit.xml for the plans it ran; a plan it never reached
    keeps its own JUnit file from the last run that ran it, and `--lf` still picks it when
    it failed there (as pytest's --lf remembers; an outside review found it forgotten)."""
    from hil.cli import main as hil

    plans = tmp_path / "plans"
    plans.mkdir()
    (plans / "ok.yaml").write_text("name: ok\nsteps:\n  - expect: {do: {SRDY: on}}\n")
    (plans / "bad.yaml").write_text("name: bad\nsteps:\n  - expect: {do: {BRKR: on}}\n")
    out = tmp_path / "out"
    base = ["run", "-q", "--plans", str(plans), "--out", str(out)]
    assert hil([*base, "bad", "ok"]) == 1
    assert hil([*base, "ok"]) == 0  # as a run stopped before `bad`: junit.xml has ok alone
    capsys.readouterr()
    assert hil([*base[:1], *base[2:], "--lf", "--list"]) == 0
    captured = capsys.readouterr()
    assert "1 of 2 plan(s) failed last time" in captured.err
    assert "bad" in captured.out and "ok " not in captured.out
