"""Every shipped plan on the built-in virtual bench at `--clock virtual` and `--clock real`, in
the same run: wall time of each, the ratio, and every verdict that differs (docs/clock.md).

    .venv/bin/python benchmarks/bench_clock.py [PLAN ...] [--repeat-virtual]

The axis-group plans (plans/group) are not run: on the wall clock a Python host misses
their SYNC cycles (docs/clock.md). Prints; asserts nothing. The virtual pass runs the plans
one at a time, like the real one; a last line also times the virtual pass as `hil run` runs
it by default (one plan per usable CPU, docs/plans.md) against the same real pass.
`--repeat-virtual` also runs the virtual pass twice and counts the recordings whose messages
differ (topics, log times, payloads): determinism.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import os
import sys
import tempfile
import time
from pathlib import Path

from mcap.reader import make_reader

from hil.bench.bench import load_bench
from hil.plan.cli import DEFAULT_JOBS_MAX, DEFAULT_PARALLEL_MIN_PLANS
from hil.plan.parallel import run_parallel, usable_cpus
from hil.plan.plan import find_plans, load_plan
from hil.plan.runner import run_plans


def _run(plans: list, bench, out: Path) -> tuple[float, list]:
    t0 = time.perf_counter()
    results = run_plans(plans, bench, out, stream=io.StringIO(), quiet=True,
                        allow_inconclusive=False)
    return time.perf_counter() - t0, results


def _verdicts(result) -> dict[tuple[int, str], str]:
    """Each step's status and each of its verdicts, keyed by spec, constraint and the
    constraint's n-th verdict in the step: a verdict only one clock gave shows as None."""
    out = {}
    for s in result.steps:
        out[(s.index, "step")] = s.status
        seen: dict[tuple, int] = {}
        for v in s.verdicts:
            key = (v.get("spec"), v.get("constraint"))
            n = seen[key] = seen.get(key, -1) + 1
            out[(s.index, f"{key[0]} / {key[1]} #{n}")] = str(v.get("status"))
    return out


def _messages(path: str) -> list[tuple[str, int, bytes]]:
    with open(path, "rb") as f:
        return [(ch.topic, m.log_time, bytes(m.data))
                for _, ch, m in make_reader(f).iter_messages(log_time_order=False)]


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plans", nargs="*")
    ap.add_argument("--repeat-virtual", action="store_true")
    args = ap.parse_args(argv)
    base = load_bench(None)
    plans = [load_plan(p) for p in find_plans(args.plans or None)]
    print(f"{len(plans)} plans, built-in virtual bench, {os.cpu_count()} CPUs, "
          f"load {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        wall_v, res_v = _run(plans, dataclasses.replace(base, clock="virtual"),
                             Path(tmp, "virtual"))
        wall_r, res_r = _run(plans, dataclasses.replace(base, clock="real"), Path(tmp, "real"))
        print(f"{'plan':<24} {'virtual s':>9} {'real s':>8} {'ratio':>7}  status (v/r)")
        differ = []
        for p, rv, rr in zip(plans, res_v, res_r, strict=True):
            v, r = rv.duration_ns / 1e9, rr.duration_ns / 1e9
            print(f"{p.name:<24} {v:9.3f} {r:8.3f} {r / v if v else 0:7.1f}  "
                  f"{rv.status}/{rr.status}")
            dv, dr = _verdicts(rv), _verdicts(rr)
            for k in sorted(set(dv) | set(dr), key=str):
                if dv.get(k) != dr.get(k):
                    differ.append(f"{p.name} step {k[0]} {k[1]}: virtual {dv.get(k)}, "
                                  f"real {dr.get(k)}")
        print(f"{'TOTAL (run_plans)':<24} {wall_v:9.3f} {wall_r:8.3f} "
              f"{wall_r / wall_v if wall_v else 0:7.1f}  (real / virtual)")
        # what `hil run` does by default in virtual time: one plan per usable CPU
        jobs = min(usable_cpus(), DEFAULT_JOBS_MAX, len(plans))
        if jobs > 1 and len(plans) >= DEFAULT_PARALLEL_MIN_PLANS:
            t0 = time.perf_counter()
            run_parallel(plans, dataclasses.replace(base, clock="virtual"), Path(tmp, "jobs"),
                         jobs=jobs)
            wall_j = time.perf_counter() - t0
            print(f"{f'TOTAL (hil run, -j {jobs})':<24} {wall_j:9.3f} {wall_r:8.3f} "
                  f"{wall_r / wall_j if wall_j else 0:7.1f}  (the real pass as above: one at "
                  "a time, as `hil run --clock real` runs)")
        print(f"verdicts that differ: {len(differ)}")
        for line in differ:
            print("  " + line)
        if args.repeat_virtual:
            _, res_v2 = _run(plans, dataclasses.replace(base, clock="virtual"),
                             Path(tmp, "virtual2"))
            same = sum(_messages(a.recording) == _messages(b.recording)
                       for a, b in zip(res_v, res_v2, strict=True))
            print(f"determinism: {same}/{len(plans)} recordings identical over two virtual runs")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
