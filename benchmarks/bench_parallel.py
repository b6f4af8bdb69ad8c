"""Wall time of a plan suite at `hil run -j 1` and `-j N` in the same run, and their ratio.

Each run is the real command (`python -m hil.cli run PLAN ... -q -j N --out TMP`) in a child
process, one after the other, on the built-in virtual bench. The default suite is the 18
plans shipped when `hil run -j` was asked for (issue 18: brake, STO, EMGS, limits, alarm
reset, CiA 402, PP/PV, parameters, homing, absolute encoder); `--all` runs every shipped
plan. The statuses of both runs are compared: a plan that passes at -j 1 and not at -j N
(timing under load) is listed.

    .venv/bin/python benchmarks/bench_parallel.py [--jobs 2] [--all] [PLAN ...]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from hil.paths import plans_dir
from hil.record import topics
from hil.record.reader import Recording

SUITE_18 = [
    "absolute_handshake", "absolute_overflow", "absolute_power_cycle", "alarm_reset",
    "cia402_power_states", "emgs", "homing_home_switch", "homing_limits", "homing_pr",
    "limit_switches", "param_access", "pp_move", "pv_move", "servo_brake_settings",
    "servo_on_off_brake", "sto_both", "sto_short_dropout", "sto_single_channel",
]


def _run(plans: list[str], jobs: int, out: Path) -> tuple[float, int, dict[str, str]]:
    argv = [sys.executable, "-m", "hil.cli", "run", *plans, "-q", "-j", str(jobs),
            "--out", str(out)]
    t0 = time.perf_counter()
    p = subprocess.run(argv, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t0
    status = {}
    for line in p.stdout.splitlines():
        cols = line.split()
        if len(cols) >= 2 and cols[0] in plans:
            status[cols[0]] = cols[1]
    if p.returncode not in (0, 1):
        print(p.stdout[-2000:], p.stderr[-2000:], file=sys.stderr)
    return wall, p.returncode, status


def main(argv: list[str]) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("plans", nargs="*", help="plans (default: the 18-plan suite)")
    ap.add_argument("--jobs", "-j", type=int, default=2, help="N of the parallel run (2)")
    ap.add_argument("--all", action="store_true", help="every shipped plan")
    args = ap.parse_args(argv)
    plans = args.plans or ([] if args.all else SUITE_18)
    if args.all:
        plans = sorted(p.stem for p in plans_dir().glob("*.yaml"))
    print(f"{len(plans)} plans, {os.cpu_count()} CPUs, load average "
          f"{' '.join(f'{x:.2f}' for x in os.getloadavg())}")
    with tempfile.TemporaryDirectory() as tmp:
        w1, c1, s1 = _run(plans, 1, Path(tmp) / "j1")
        print(f"-j 1: {w1:7.2f} s  exit {c1}  {sum(v == 'PASS' for v in s1.values())}"
              f"/{len(plans)} passed")
        wn, cn, sn = _run(plans, args.jobs, Path(tmp) / f"j{args.jobs}")
        print(f"-j {args.jobs}: {wn:7.2f} s  exit {cn}  "
              f"{sum(v == 'PASS' for v in sn.values())}/{len(plans)} passed")
        print(f"ratio -j {args.jobs} / -j 1 = {wn / w1:.2f} (speed-up {w1 / wn:.2f}x)")
        differ = {p: (s1.get(p), sn.get(p)) for p in plans if s1.get(p) != sn.get(p)}
        for p, (a, b) in differ.items():
            print(f"  {p}: -j 1 {a}, -j {args.jobs} {b}")
            for run, st in (("1", a), (str(args.jobs), b)):
                if st != "PASS":
                    for why in _not_passed(Path(tmp) / f"j{run}" / f"{p}.mcap"):
                        print(f"    -j {run}: {why}")
    return 0 if c1 == cn and not differ else 1


def _not_passed(path: Path) -> list[str]:
    """The steps and timing verdicts of a recording that did not pass."""
    rec = Recording.open(path)
    out = [f"step {m.get('step')}: {m.get('status')}: {m.get('message')}"
           for *_t, m in rec.messages(topics.PLAN_STEPS)
           if m.get("status") not in (None, "pass", "skipped")]
    out += [f"{m.get('spec')}: {m.get('constraint')}: {m.get('status')}: {m.get('message')}"
            for *_t, m in rec.messages(topics.TIMING_VERDICTS)
            if m.get("status") in ("fail", "inconclusive")]
    return out


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
