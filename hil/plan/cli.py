"""`hil run [PLAN ...] [--bench FILE] [--out DIR] [--quiet]`."""

from __future__ import annotations

import argparse
import sys
from pathlib import Path


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("plans", nargs="*", metavar="PLAN",
                        help="plan files or plan names (default: all in the plans directory)")
    parser.add_argument("--bench", metavar="FILE",
                        help="bench file (default: the built-in virtual bench)")
    parser.add_argument("--out", metavar="DIR", default="reports",
                        help="where recordings and reports go (default: reports/)")
    parser.add_argument("-q", "--quiet", action="store_true", help="no per-step progress")
    parser.add_argument("--allow-inconclusive", action="store_true",
                        help="count inconclusive timing verdicts as passed")
    parser.add_argument("--check", action="store_true",
                        help="only validate the plans against the bench; nothing moves")
    parser.add_argument("--plans", metavar="DIR", dest="plans_dir",
                        help="plans directory for plan names and the default set (default: "
                        "plans/ of the hil checkout the current directory is in, else the "
                        "installed plans)")


def main(args: argparse.Namespace) -> int:
    from hil.plan.bench import load_bench
    from hil.plan.plan import check_plan, find_plans, load_plan
    from hil.plan.plansdir import choose_plans_dir
    from hil.plan.runner import run_plans, summary_table, timing_specs
    from hil.plan.yamlio import PlanFileError
    from hil.report.junit import write_junit

    try:
        plans_dir, why = choose_plans_dir(args.plans_dir)
    except ValueError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    print(f"plans: {plans_dir} ({why})", file=sys.stderr)
    try:
        bench = load_bench(args.bench)
        plans = [load_plan(p) for p in find_plans(args.plans, plans_dir)]
        if not plans:
            print("hil run: no plans found", file=sys.stderr)
            return 2
        if args.check:
            ids = set(timing_specs())
            for p in plans:
                check_plan(p, bench, ids)
                print(f"{p.path}: ok ({len(p.steps)} steps)")
            return 0
    except PlanFileError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    out = Path(args.out)
    try:
        results = run_plans(plans, bench, out, quiet=args.quiet,
                            allow_inconclusive=args.allow_inconclusive)
    except PlanFileError as e:
        print(f"hil run: {e}", file=sys.stderr)
        return 2
    write_junit([r.recording for r in results], out / "junit.xml")
    print(summary_table(results))
    from hil.report.index import write_index

    print(f"index: {write_index([r.recording for r in results], out / 'index.html')}")
    return 0 if all(r.passed for r in results) else 1
