"""`hil report` of a homing recording: wall time, peak memory and page size, beside a bare
`mcap` read of the same file (JSON decoded) in the same run.

    .venv/bin/python benchmarks/bench_report.py [RECORDING.mcap]

Without a file, runs the shipped `homing_home_switch` plan on the built-in virtual bench (in
virtual time) first. Each measurement runs in its own process (peak RSS is per process).
Goals (the reviewer issue): under 2 s, under 100 MB, a page under 1 MB. Prints; asserts
nothing.
"""

from __future__ import annotations

import io
import json
import resource
import subprocess
import sys
import tempfile
from pathlib import Path

CHILD = r"""
import json, sys, time
t = time.perf_counter()
if sys.argv[1] == "bare":
    from mcap.reader import make_reader
    with open(sys.argv[2], "rb") as f:
        n = sum(1 for _ in (json.loads(m.data) for _, _, m in make_reader(f).iter_messages()))
else:
    from hil.report.html import write_html
    write_html(sys.argv[2], sys.argv[3])
wall = time.perf_counter() - t
# VmHWM: this program's peak (ru_maxrss would include the parent's, inherited over fork)
hwm = next(int(x.split()[1]) for x in open("/proc/self/status") if x.startswith("VmHWM"))
print(json.dumps({"wall": wall, "rss_mb": hwm / 1024}))
"""


def _measure(*args: str) -> dict:
    out = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True,
                         check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main(argv: list[str]) -> int:
    with tempfile.TemporaryDirectory() as tmp:
        if argv:
            rec = Path(argv[0])
        else:
            from hil.bench.bench import load_bench
            from hil.plan.plan import find_plans, load_plan
            from hil.plan.runner import run_plans

            [r] = run_plans([load_plan(find_plans(["homing_home_switch"])[0])], load_bench(),
                            Path(tmp), stream=io.StringIO(), quiet=True)
            rec = Path(r.recording)
        page = Path(tmp) / "page.html"
        bare = _measure("bare", str(rec))
        rep = _measure("report", str(rec), str(page))
        size = page.stat().st_size
        print(f"recording {rec.name}: {rec.stat().st_size / 1e6:.1f} MB; peak RSS of this "
              f"process {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MB")
        print(f"{'':<28} {'wall s':>8} {'peak MB':>8}")
        print(f"{'bare mcap read + JSON':<28} {bare['wall']:8.2f} {bare['rss_mb']:8.0f}")
        print(f"{'hil report':<28} {rep['wall']:8.2f} {rep['rss_mb']:8.0f}")
        print(f"ratio report / bare: {rep['wall'] / bare['wall']:.1f}x time, "
              f"{rep['rss_mb'] / bare['rss_mb']:.1f}x memory; page {size / 1e6:.2f} MB "
              "(goals: < 2 s, < 100 MB, page < 1 MB)")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
