"""How late a virtual drive's DO edge reaches its faces on the real-time path (prints, no asserts).

    .venv/bin/python benchmarks/bench_edges.py [--seconds 10] [--fifo 10]

A `Drive` runs under a real-time `DriveHost`. The harness toggles DI1 (SON) every 20-40 ms;
each toggle passes the P2.009 input filter (a model timer) and switches the servo, so DO
edges (SON, SRDY, BRKR ...) fall at timer times between two host ticks. A subscriber measures,
for every DO edge, the host's model clock when the edge reaches it minus the edge's model time:
the delivery lateness a DI/DO face adds on top. Baseline in the same run: the plain 1 ms
ticker (`timer_wakeups=False`), which delivers an edge at the next tick; the new host wakes at
the model's next timer and on the model's 1 ms grid.
"""

from __future__ import annotations

import argparse
import random
import statistics
import time

from hil.model.drive import Drive
from hil.model.events import DoChanged
from hil.virtual.host import DriveHost


def run(seconds: float, timer_wakeups: bool, rt_priority: int | None = None, seed: int = 1
        ) -> list[float]:
    # a 3 ms DI filter (P2.009): the edge falls between two ticks; DO2 = SON (table 8.2)
    drive = Drive(inputs={8: True}, params={"P2.009": 3, "P2.019": 0x0102})
    host = DriveHost(drive, timer_wakeups=timer_wakeups, rt_priority=rt_priority or 0)
    late: list[float] = []

    def on_event(ev: object) -> None:
        if isinstance(ev, DoChanged):
            late.append((host.model_now() - ev.t) / 1e3)  # µs

    drive.subscribe(on_event)
    rng = random.Random(seed)
    host.start()
    try:
        level = False
        end = time.monotonic() + seconds
        while time.monotonic() < end:
            time.sleep(rng.uniform(0.020, 0.040))
            level = not level
            host.call(drive.set_di, 1, level)
    finally:
        host.stop()
    return late


def _q(xs: list[float], p: float) -> float:
    xs = sorted(xs)
    return xs[min(len(xs) - 1, int(p / 100 * len(xs)))] if xs else float("nan")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=10.0)
    ap.add_argument("--fifo", type=int, default=0, metavar="PRIO",
                    help="also run with the ticker at SCHED_FIFO PRIO (1-99), if allowed")
    args = ap.parse_args()
    base = run(args.seconds, timer_wakeups=False)
    rows = [("1 ms ticker (baseline)", base),
            ("timer wake-ups", run(args.seconds, timer_wakeups=True))]
    if args.fifo:
        rows.append((f"timer wake-ups, FIFO {args.fifo}",
                     run(args.seconds, timer_wakeups=True, rt_priority=args.fifo)))
    print(f"DO edges per run: {', '.join(str(len(xs)) for _, xs in rows)} in "
          f"{args.seconds:g} s each")
    print(f"{'host':<30}{'p50 µs':>9}{'p99 µs':>9}{'max µs':>9}{'mean µs':>9}"
          f"{'p50 x':>8}{'p99 x':>8}")
    for name, xs in rows:
        print(f"{name:<30}{_q(xs, 50):>9.0f}{_q(xs, 99):>9.0f}{max(xs):>9.0f}"
              f"{statistics.fmean(xs):>9.0f}{_q(xs, 50) / _q(base, 50):>8.2f}"
              f"{_q(xs, 99) / _q(base, 99):>8.2f}")


if __name__ == "__main__":
    main()
