"""`hil run [PLAN ...] [--bench FILE] [--out DIR]`, with selection (`-k`, `-m`, globs,
`--list`), progress (`-q`, `-v`, `--log-level`), `HIL_BENCH` and plans in parallel (`-j N`,
hil/plan/parallel.py)."""

from __future__ import annotations

import argparse
import contextlib
import logging
import os
import signal
import sys
import threading
from collections.abc import Iterator
from pathlib import Path

from hil.bench.bench import CLOCKS, Bench, line_warnings, load_bench, with_clock
from hil.bench.yamlio import PlanFileError
from hil.fileio import dir_problem
from hil.plan.events import Listener
from hil.plan.listeners import StepLines
from hil.plan.parallel import jobs_from_arg, parallel_blocker, run_parallel, usable_cpus
from hil.plan.plan import Plan, bench_constant_warnings, check_plan, find_plans, load_plan
from hil.plan.plansdir import choose_plans_dir
from hil.plan.progress import RunProgress
from hil.plan.runner import (
    Interrupts,
    output_stems,
    run_plans,
    signal_text,
    summary_table,
    timing_specs,
)
from hil.plan.select import ExprError, select
from hil.report.index import write_index
from hil.report.junit import write_junit
from hil.terminal import terminal_lines, terminal_text

BENCH_ENV = "HIL_BENCH"  # like labgrid's LG_ENV: the bench file when --bench is not given
LOG_LEVELS = ("debug", "info", "warning", "error", "critical")


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("plans", nargs="*", metavar="PLAN",
                        help="plan files, plan names or globs like 'pr_*' (default: all in "
                        "the plans directory)")
    parser.add_argument("--bench", metavar="FILE",
                        help=f"bench file (default: ${BENCH_ENV} if set, else the built-in "
                        "virtual bench)")
    parser.add_argument("--out", metavar="DIR", default="reports",
                        help="where recordings and reports go (default: reports/)")
    parser.add_argument("-k", metavar="EXPR", dest="keyword",
                        help="only plans whose name, file or tags contain the words of EXPR "
                        "(and, or, not, parentheses), e.g. -k 'brake and not sto'")
    parser.add_argument("-m", metavar="EXPR", dest="marker",
                        help="only plans whose tags match EXPR, e.g. -m brake, -m 'pr or homing'")
    parser.add_argument("--lf", "--last-failed", action="store_true", dest="last_failed",
                        help="only the plans that failed (or errored) in the previous run into "
                        "--out (its junit.xml), as pytest's --lf; all selected plans when none "
                        "failed or there was no previous run")
    parser.add_argument("--list", action="store_true",
                        help="list the selected plans (name, steps, tags, file); run nothing")
    parser.add_argument("-q", "--quiet", action="store_true",
                        help="no progress; only the summary table and errors")
    parser.add_argument("-v", "--verbose", action="count", default=0,
                        help="one line per step (-vv: also info logs)")
    parser.add_argument("--log-level", choices=LOG_LEVELS, metavar="LEVEL",
                        help=f"log messages of this level and above to stderr "
                        f"({', '.join(LOG_LEVELS)}; default: warning)")
    parser.add_argument("-j", "--jobs", metavar="N", default=None,
                        help="run N plans at a time, each in its own process on its own "
                        "virtual bench (0 or auto: one per usable CPU). Default: one per CPU "
                        "(at most 8) for 8 plans or more in virtual time where the bench "
                        "allows it and without -v, else 1. With -j, a bench that is not "
                        "virtual, or shares a fixed transport, runs plans one at a time")
    parser.add_argument("--clock", choices=CLOCKS, default=None,
                        help="the bench's clock: virtual (the model's, deterministic and much "
                        "faster than real time) or real (the wall clock). Default: the bench "
                        "file's clock:, else virtual where the bench can run on it and names no "
                        "CAN channel (the built-in virtual bench), else real (docs/clock.md)")
    parser.add_argument("--allow-inconclusive", action="store_true",
                        help="count inconclusive timing verdicts as passed")
    parser.add_argument("--check", action="store_true",
                        help="only validate the plans against the bench; nothing moves")
    parser.add_argument("--plans", metavar="DIR", dest="plans_dir",
                        help="plans directory for plan names and the default set (default: "
                        "plans/ of the hil checkout the current directory is in, else the "
                        "installed plans)")


def _last_failed(plans: list, out: Path, *, quiet: bool) -> list:
    """The plans whose testcase in the previous run's `<out>/junit.xml` failed or errored."""
    import xml.etree.ElementTree as ET

    junit = out / "junit.xml"
    try:
        cases = list(ET.parse(junit).getroot().iter("testcase"))
    except (OSError, ET.ParseError):
        if not quiet:
            print(f"--last-failed: no previous run in {out} (no readable junit.xml): "
                  "running the selection", file=sys.stderr)
        return plans
    # each failed testcase names its plan and its recording (`<stem>.mcap`): two plans of one
    # name in different folders are told apart by the recording, as the run named them
    stems = output_stems(plans)
    chosen_ix: set[int] = set()
    ran: set[str] = set()  # the recordings the previous run made
    for c in cases:
        rec = next((Path(pr.get("value") or "").stem for pr in c.iter("property")
                    if pr.get("name") == "recording"), None)
        if rec is not None:
            ran.add(rec)
        if c.find("failure") is None and c.find("error") is None:
            continue
        same = [i for i, st in enumerate(stems) if rec is not None and st == rec]
        chosen_ix.update(same or (i for i, p in enumerate(plans) if p.name == c.get("name")))
    for i, st in enumerate(stems):  # not reached by an interrupted previous run: its own
        if st in ran or i in chosen_ix:  # JUnit file, from the last run that ran it, says
            continue
        try:
            own = ET.parse(out / f"{st}.junit.xml").getroot()
        except (OSError, ET.ParseError):
            continue
        if any(c.find("failure") is not None or c.find("error") is not None
               for c in own.iter("testcase")):
            chosen_ix.add(i)
    chosen = [p for i, p in enumerate(plans) if i in chosen_ix]
    if not chosen:
        if not quiet:
            print(f"--last-failed: none of the selected plans failed in the previous run "
                  f"({junit}): running the selection", file=sys.stderr)
        return plans
    if not quiet:
        print(f"--last-failed: {len(chosen)} of {len(plans)} plan(s) failed last time",
              file=sys.stderr)
    return chosen


def _logging(args: argparse.Namespace) -> None:
    level = args.log_level or ("info" if args.verbose >= 2 else
                               "error" if args.quiet else "warning")
    logging.basicConfig(level=level.upper(), stream=sys.stderr,
                        format="%(levelname)s %(name)s: %(message)s")


def _bench_path(args: argparse.Namespace) -> str | None:
    return args.bench or os.environ.get(BENCH_ENV) or None


def _listing(plans: list[Plan]) -> str:
    rows = [(p.name, str(len(p.steps)), ", ".join(p.tags), p.path) for p in plans]
    widths = [max(len(r[i]) for r in rows) for i in range(3)]
    return "\n".join(f"{r[0]:<{widths[0]}}  {r[1]:>{widths[1]}} steps  "
                     f"{r[2]:<{widths[2]}}  {r[3]}".rstrip() for r in rows)


def _listeners(args: argparse.Namespace, plans: list[Plan]) -> list[Listener]:
    if args.quiet:
        return []
    if args.verbose:
        return [StepLines()]
    return [RunProgress(sum(len(p.steps) for p in plans), len(plans))]


DEFAULT_PARALLEL_MIN_PLANS = 8  # without -j: fewer plans than this run one at a time
DEFAULT_JOBS_MAX = 8  # without -j: at most this many workers, whatever the CPU count


def _jobs(args: argparse.Namespace, bench: Bench, n_plans: int) -> int:
    """Plans at a time: `-j`, but 1 where the bench cannot be shared (said on stderr).
    Without `-j`: one per usable CPU (at most 8) in virtual time on a bench whose runs share
    nothing, for 8 plans or more and without `-v` (the plans are CPU-bound and independent
    there, docs/plans.md); else one at a time, silently."""
    if args.jobs is None:
        if (bench.clock != "virtual" or parallel_blocker(bench) is not None
                or n_plans < DEFAULT_PARALLEL_MIN_PLANS or args.verbose):
            return 1  # a worker's start (~2 s of imports) is not won back on a few plans
        jobs = min(usable_cpus(), DEFAULT_JOBS_MAX, n_plans)
        if jobs > 1 and not args.quiet:
            print(f"jobs: {jobs} plans at a time (one per CPU in virtual time; -j 1 for one "
                  "at a time)", file=sys.stderr)
        return jobs
    jobs = min(jobs_from_arg(args.jobs), n_plans)
    if jobs > 1 and (why := parallel_blocker(bench)) is not None:
        print(f"hil run: -j {args.jobs}: {why}; running plans one at a time", file=sys.stderr)
        return 1
    if jobs > 1 and not args.quiet:
        print(f"jobs: {jobs} plans at a time, each on its own virtual bench", file=sys.stderr)
    return jobs


def main(args: argparse.Namespace) -> int:
    with _sigterm_as_ctrl_c():
        return _main(args)


@contextlib.contextmanager
def _sigterm_as_ctrl_c() -> Iterator[None]:
    """SIGTERM stops `hil run` as Ctrl-C does everywhere, not only while a plan runs (a
    plan, and `-j`, put their own handlers in place meanwhile): between plans and while the
    run's files are written it had killed the process outright (exit -15, helper-140)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum: int, frame: object) -> None:
        raise KeyboardInterrupt(signal_text(signum))

    old = signal.signal(signal.SIGTERM, handler)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


@contextlib.contextmanager
def _signals_held() -> Iterator[None]:
    """A Ctrl-C or SIGTERM while the run's junit.xml, summary and index.html are written
    waits until they are, then stops the run (exit 130): they had been left half done."""
    with Interrupts(hold=True, held=b"\nhil: writing the run's junit.xml and index.html; "
                    b"stopping after that\n") as intr:
        yield
    intr.release()


def _main(args: argparse.Namespace) -> int:
    _logging(args)
    try:
        if args.jobs is not None:
            jobs_from_arg(args.jobs)
    except ValueError as e:
        print(f"hil run: -j: {e}", file=sys.stderr)
        return 2
    try:
        plans_dir, why = choose_plans_dir(args.plans_dir)
    except ValueError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    bench_path = _bench_path(args)
    if not args.quiet:
        print(f"plans: {plans_dir} ({why})", file=sys.stderr)
        if bench_path and not args.bench:
            print(f"bench: {bench_path} (from ${BENCH_ENV})", file=sys.stderr)
    try:
        bench = load_bench(bench_path)
        try:
            bench = with_clock(bench, args.clock)
        except ValueError as e:  # --clock virtual on a bench that cannot
            print(f"hil run: --clock: {e}", file=sys.stderr)
            return 2
        loaded, bad = [], []
        for path in find_plans(args.plans, plans_dir):
            try:
                loaded.append(load_plan(path))
            except PlanFileError as e:  # every bad file is named, not only the first
                bad.append(e)
        if bad:
            for e in bad:
                print(f"hil run: {e}", file=sys.stderr)
            # the files that did load are checked against the bench too: an error there
            # is named now, not in the next run once the first file is mended
            _check_each(select(loaded, args.keyword, args.marker), bench, say_ok=False)
            return 2
        plans = select(loaded, args.keyword, args.marker)
    except PlanFileError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    except ExprError as e:
        print(f"hil run: -k/-m: {e}", file=sys.stderr)
        return 2
    if args.last_failed:
        plans = _last_failed(plans, Path(args.out), quiet=args.quiet)
    if not plans:
        print("hil run: no plans found" + (" (none selected by -k/-m)"
                                            if args.keyword or args.marker else ""),
              file=sys.stderr)
        return 2 if not (args.keyword or args.marker) else 5
    if args.list:
        print(terminal_lines(_listing(plans)))
        return 0
    out = Path(args.out)
    if (why := dir_problem(out)) is not None:
        print(f"hil run: --out {args.out}: {why}", file=sys.stderr)
        return 2
    for warning in [*bench_constant_warnings(bench, timing_specs()), *line_warnings(bench)]:
        print(f"hil run: warning: {warning}", file=sys.stderr)
    try:
        if args.check:
            return 2 if _check_each(plans, bench, say_ok=True) else 0
        jobs = _jobs(args, bench, len(plans))
        try:
            if jobs > 1:
                results = run_parallel(plans, bench, out, jobs=jobs,
                                       allow_inconclusive=args.allow_inconclusive,
                                       listeners=_listeners(args, plans))
            else:
                results = run_plans(plans, bench, out,
                                    allow_inconclusive=args.allow_inconclusive,
                                    listeners=_listeners(args, plans))
        except KeyboardInterrupt as e:  # the run's junit.xml and index.html say what ran,
            # the stopped plan aborted: a previous run's files must not stand for this one
            with contextlib.suppress(KeyboardInterrupt), _signals_held():
                _summarise(getattr(e, "results", []), out, len(plans))
            raise
    except PlanFileError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    with _signals_held():
        _summarise(results, out, len(plans))
    return 0 if all(r.passed for r in results) else 1


def _check_each(plans: list, bench: Bench, *, say_ok: bool) -> int:
    """Check every plan against the bench, each error said on stderr (and, with `say_ok`,
    each plan that passes on stdout); the number that failed."""
    specs = timing_specs()
    failed = 0
    for p in plans:
        try:
            check_plan(p, bench, specs)
        except PlanFileError as e:
            print(f"hil run: {e}", file=sys.stderr)
            failed += 1
            continue
        if say_ok:
            print(terminal_text(f"{p.path}: ok ({len(p.steps)} steps)"))
    return failed


def _summarise(results: list, out: Path, selected: int) -> None:
    """The run's junit.xml, summary table and index.html from `results`."""
    recordings = [r.recording for r in results if r.recording and Path(r.recording).exists()]
    write_junit(recordings, out / "junit.xml")
    if results:
        print(terminal_lines(summary_table(results)))
    if len(results) < selected:
        print(f"interrupted: {len(results)} of {selected} plans ran", file=sys.stderr)
    print(f"index: {write_index(recordings, out / 'index.html')}")
