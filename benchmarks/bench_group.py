"""Scale of the axis group (issue 27): the largest number of axes one virtual 1 Mbit/s CAN
bus carries at SYNC 1, 2 and 4 ms with 0 missed cycles, beside the limit the wire's bit time
allows, and the CPU cost per axis-cycle. A cycle is missed when an axis's TPDO did not come
before the next SYNC (the group's own count); "late" counts the cycles that began more than
half a period late, an interval over 1.5 periods (on the wall clock the producer's thread woke
late, and the drive saw a SYNC off 1006h). A run carries its axes with neither. Prints,
asserts nothing.

    .venv/bin/python benchmarks/bench_group.py [--seconds 600] [--cycles 1,2,4]
        [--clock virtual|real] [--transport inproc|zenoh] [--start N] [--fifo PRIO]

Each run is a plan on a generated bench of N virtual A3 on one in-process bus, in virtual
time: `group` (IP mode, RPDO + SYNC + TPDO per axis per cycle), a harmonic PG move on every
axis, then `--seconds` of bench time; missed cycles are read from the recording. N starts at
the plan checker's limit (worst-case stuffing, 115 bits a 6-byte PDO frame; the checker
refuses more) and goes down until a run has 0 missed cycles; the wire's exact limit is printed
beside it (the frames' own stuff bits, hil.transport.sim.frame_bits). Each run's progress goes
to stderr.
`--clock real` runs the same on the wall clock (the real-time path: how many axes one host
carries with 0 missed cycles); `--transport zenoh` puts each drive in a `hil drive` process
reached over zenoh on loopback. `--start N` begins the search at N. `--fifo PRIO` sets
`HIL_RT_PRIORITY` for the runs: the drive hosts' tickers and the group's cycle thread at
`SCHED_FIFO` (hil.realtime; the `hil drive` processes inherit it).
The baseline is that exact limit; the CPU cost is the process CPU time (drive models, bus,
recorder and group together) over axis-cycles, and "bench time / wall" how much faster than
real time the run went.
"""

from __future__ import annotations

import argparse
import itertools
import json
import os
import resource
import sys
import tempfile
import time
from dataclasses import replace
from pathlib import Path

import can
from mcap.reader import make_reader

from hil.bench.bench import loads_bench
from hil.drivers.axis_group import worst_case_bits
from hil.plan.plan import loads_plan
from hil.plan.runner import run_plan
from hil.transport.sim import frame_bits

ZENOH = "zenoh:auto?listen=tcp/127.0.0.1:auto"  # the drive listens, the harness connects


def _bench(n: int, transport: str = "inproc") -> str:
    """N A3 on one bus: in this process on `virtual:` (inproc), or each a `hil drive` process
    reached over zenoh on loopback (zenoh: the real-time path of a remote bench)."""
    url, process = ("virtual:auto", "inproc") if transport == "inproc" else (ZENOH, "subprocess")
    drives = "\n".join(
        f"  axis{i}: {{profile: asda-a3, can: can0, node_id: {i}, param_via: sdo,\n"
        f"           dio: \"{url}\", wiring: {{SON: DI1, EMGS: \"DI8:b\"}},\n"
        f"           mechanics: {{nl_rev: -1000, pl_rev: 1000, hard_stop_neg_rev: null,\n"
        f"                       hard_stop_pos_rev: null}}}}"
        for i in range(1, n + 1))
    return (f"name: group{n}\nvirtual: true\nprocess: {process}\ncan:\n  can0: \"{url}\"\n"
            f"drives:\n{drives}\nsafe_state: {{controlword: disable_voltage, wait_brake: false,"
            " timeout: 3s}\n"
            "motion_allowed: true\n")


def _plan(n: int, cycle_ms: int, seconds: float) -> str:
    """The move, then `seconds` of bench time in 10 s waits: each step stays well inside its
    step timeout and the runner's wall-clock watchdog (timeout + 60 s)."""
    axes = ", ".join(f"axis{i}" for i in range(1, n + 1))
    chunks, rest = divmod(seconds, 10.0)
    waits = "  - wait: 10s\n" * int(chunks) + (f"  - wait: {rest:g}s\n" if rest else "")
    return (f"name: scale\nsteps:\n  - group: {{axes: [{axes}], cycle: {cycle_ms}ms}}\n"
            f"  - group_move: {{axes: [{axes}], to: 1000000, speed: 200000, acc: 400000, "
            f"dec: 400000, ramp: 2}}\n{waits}  - group_stop: {{}}\n")


def exact_limit(cycle_ms: int, bitrate: int = 1_000_000) -> int:
    """Axes whose RPDO + TPDO (with their real stuff bits, zero data: the worst is higher)
    and the SYNC fit a cycle."""
    def bits(cob: int, dlc: int) -> int:
        return frame_bits(can.Message(arbitration_id=cob, data=bytes(dlc), is_extended_id=False))
    budget = bitrate * cycle_ms / 1000 - bits(0x80, 0)
    n = 0
    while budget >= bits(0x201 + n, 6) + bits(0x181 + n, 6):
        budget -= bits(0x201 + n, 6) + bits(0x181 + n, 6)
        n += 1
    return n


def checker_limit(cycle_ms: int, bitrate: int = 1_000_000) -> int:
    """The most axes the plan checker admits (worst_case_bits within the cycle)."""
    n = 0
    while worst_case_bits(n + 1) <= bitrate * cycle_ms / 1000:
        n += 1
    return n


def run(n: int, cycle_ms: int, seconds: float, clock: str = "virtual",
        transport: str = "inproc") -> tuple[int, int, int, float]:
    with tempfile.TemporaryDirectory() as tmp:
        path, text = Path(tmp) / "bench.yaml", _bench(n, transport)
        path.write_text(text)  # `hil drive` processes read the bench from its file
        bench = replace(loads_bench(text, str(path)), clock=clock)
        t0 = time.process_time()
        res = run_plan(loads_plan(_plan(n, cycle_ms, seconds), "scale.yaml"), bench,
                       Path(tmp))
        cpu = time.process_time() - t0
        with open(res.recording, "rb") as f:
            msgs = [m for _, _, m in make_reader(f).iter_messages(topics=["/group/axes/cycle"])]
    cycles = [json.loads(m.data) for m in msgs]
    missed = sum(1 for c in cycles if c["missed"])
    # cycles the master itself began late (an interval over 1.5 periods): on the wall clock
    # the producer can fall behind without any TPDO missing
    times = [m.log_time for m in msgs]
    late = sum(1 for a, b in itertools.pairwise(times) if b - a > cycle_ms * 1_500_000)
    if not res.passed:
        missed = max(missed, 1)
    return len(cycles), missed, late, cpu


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=600.0, help="bench time per run")
    ap.add_argument("--cycles", default="1,2,4", help="SYNC cycles in ms")
    ap.add_argument("--clock", choices=("virtual", "real"), default="virtual",
                    help="virtual time (default) or the wall clock (the real-time path)")
    ap.add_argument("--transport", choices=("inproc", "zenoh"), default="inproc",
                    help="drives in this process (default) or each a `hil drive` process "
                    "over zenoh on loopback (real time only)")
    ap.add_argument("--start", type=int, default=0,
                    help="first N to try (default: the plan checker's limit)")
    ap.add_argument("--fifo", type=int, default=0, metavar="PRIO",
                    help="HIL_RT_PRIORITY for the runs (SCHED_FIFO, real time only)")
    a = ap.parse_args()
    if a.fifo:
        os.environ["HIL_RT_PRIORITY"] = str(a.fifo)
    if a.transport == "zenoh" and a.clock != "real":
        ap.error("--transport zenoh runs on the wall clock: add --clock real")
    print(f"bench time per run: {a.seconds:g} s, clock {a.clock}, drives {a.transport}, "
          f"{os.cpu_count()} CPUs, load {os.getloadavg()[0]:.2f}"
          + (f", HIL_RT_PRIORITY={a.fifo}" if a.fifo else ""), flush=True)
    rows = []
    for cyc in (int(x) for x in a.cycles.split(",")):
        # from the plan checker's limit down: the first N with 0 missed cycles is the answer
        best, row = 0, (0, 0, 0, 0.0, 0.0)
        for n in range(min(a.start or checker_limit(cyc), checker_limit(cyc)), 0, -1):
            t0 = time.perf_counter()
            cycles, missed, late, cpu = run(n, cyc, a.seconds, a.clock, a.transport)
            wall = time.perf_counter() - t0
            print(f"  SYNC {cyc} ms, {n} axes: {cycles} cycles, {missed} missed, {late} late "
                  f"SYNC, {wall:.0f} s wall, {cpu:.0f} s CPU", file=sys.stderr, flush=True)
            if not missed and not late:
                best, row = n, (cycles, missed, late, cpu, wall)
                break
        rows.append((cyc, best, row))
    print(f"{'SYNC':>6} {'wire limit':>10} {'checker':>8} {'carried':>8} {'missed':>7} "
          f"{'late':>5} {'cycles':>8} {'µs CPU / axis-cycle':>20} {'bench time / wall':>18}")
    for cyc, best, (cycles, missed, late, cpu, wall) in rows:
        per = cpu / max(1, cycles * best) * 1e6
        speed = cycles * cyc / 1000 / wall if wall else 0.0
        print(f"{cyc:>4}ms {exact_limit(cyc):>10} {checker_limit(cyc):>8} {best:>8} "
              f"{missed:>7} {late:>5} {cycles:>8} {per:>20.1f} {speed:>17.2f}x")
    print(f"peak RSS: {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss // 1024} MB")


if __name__ == "__main__":
    main()
