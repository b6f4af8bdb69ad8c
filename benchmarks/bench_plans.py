"""Wall time of the whole virtual plan suite beside the delays the manual itself imposes.

The unavoidable part of a plan is what the drive must be given by design: waits and pulse
widths written in the plan, the manual delays a plan names on a step (`imposed:`, e.g. the
1 s before AL501 inside a wait_until), and the timing windows the manual fixes (for each
judged verdict, the lower limit of its window, e.g. P1.042 between servo on and BRKR). The
ratio wall / imposed shows what the harness adds (bench start-up, bus round trips, polling).

    .venv/bin/python benchmarks/bench_plans.py [--bench FILE] [PLAN ...]
"""

from __future__ import annotations

import argparse
import io
import sys
import tempfile
import time
from pathlib import Path

from hil.bench.bench import load_bench
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plans


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plans", nargs="*")
    ap.add_argument("--bench", help="bench file (default: the built-in virtual bench)")
    args = ap.parse_args(argv)
    bench = load_bench(args.bench)
    plans = [load_plan(p) for p in find_plans(args.plans or None)]
    with tempfile.TemporaryDirectory() as tmp:
        t0 = time.perf_counter()
        results = run_plans(plans, bench, Path(tmp), stream=io.StringIO(), quiet=True,
                            allow_inconclusive=True)
        wall = time.perf_counter() - t0
    print(f"bench {bench.name} ({bench.process if bench.virtual else 'real'})")
    print(f"{'plan':<24} {'wall s':>8} {'plan s':>8} {'windows s':>9} {'imposed s':>9} "
          f"{'ratio':>7} status")
    tot_i = 0.0
    for p, r in zip(plans, results, strict=True):
        waits = sum(s.imposed_ns for s in p.steps) / 1e9
        windows = sum(max(0.0, float((v.get("window_ms") or [0])[0] or 0)) for s in r.steps
                      for v in s.verdicts if v.get("status") != "skipped") / 1e3
        w = r.duration_ns / 1e9
        imposed = waits + windows
        tot_i += imposed
        ratio = w / imposed if imposed else float("inf")
        print(f"{p.name:<24} {w:8.3f} {waits:8.3f} {windows:9.3f} {imposed:9.3f} {ratio:7.2f} "
              f"{r.status}")
    print(f"{'TOTAL (whole suite)':<24} {wall:8.3f} {'':>8} {'':>9} {tot_i:9.3f} "
          f"{wall / tot_i if tot_i else 0:7.2f}  (wall / manual-imposed delays)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
