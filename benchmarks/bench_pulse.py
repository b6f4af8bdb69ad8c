"""Cost of the PT input: 60 s of model time of a 500 kHz pulse command against the same
motion in PP mode (issue 26's goal: PT costs no more than 1.2x PP). Prints, no asserts.

    .venv/bin/python benchmarks/bench_pulse.py [--seconds 60]

Both drives are the pure model (`hil.model.drive.Drive`) on the injected clock, servo on:
(a) PT: P1.001 = 0, one continuous segment of 500 kHz pulses (A3 default gear 16777216 /
100000: 100000 pulses per revolution, so 300 rpm); (b) PP over CiA 402 (6060h = 1): one
move to the same end position at the same speed. The model is advanced in 1 ms calls, as
the virtual bench's host does. The ratio is (a) / (b), measured in the same run.
"""

from __future__ import annotations

import argparse
import time

from hil.model.drive import Drive
from hil.model.mechanics import Mechanics
from hil.units import MS

FREQ = 500_000  # pulses/s
PULSES_PER_REV = 100_000  # P1.044 / P1.045 = 16777216 / 100000


def _drive() -> Drive:
    # a long axis: 300 rpm for 60 s is 300 revolutions, past the bench's switches at 45
    mech = Mechanics(nl_rev=-1e6, pl_rev=1e6, hard_stop_neg_rev=None, hard_stop_pos_rev=None)
    return Drive(inputs={8: True}, params={"P2.041": 0x0108}, mechanics=mech)


def run_pt(seconds: int) -> tuple[float, int]:
    d = _drive()
    d.set_di(1, True)  # SON
    d.advance(10 * MS)
    d.pulse.segment(FREQ, 1, FREQ * seconds)
    t0 = time.perf_counter()
    for _ in range(seconds * 1000):
        d.advance(MS)
    return time.perf_counter() - t0, round(d.axis.position)


def run_pp(seconds: int) -> tuple[float, int]:
    d = _drive()
    d.write_object(0x6060, 0, 1)  # PP
    for cw in (0x06, 0x07, 0x0F):
        d.write_object(0x6040, 0, cw)
    d.advance(10 * MS)
    rpm = FREQ / PULSES_PER_REV * 60
    d.write_object(0x6081, 0, FREQ)  # PUU/s: 1 pulse = 1 PUU with the default gear
    d.write_object(0x6083, 0, 1)
    d.write_object(0x6084, 0, 1)
    d.write_object(0x607A, 0, FREQ * seconds)
    d.write_object(0x6040, 0, 0x1F)  # new set-point
    t0 = time.perf_counter()
    for _ in range(seconds * 1000):
        d.advance(MS)
    _ = rpm
    return time.perf_counter() - t0, round(d.axis.position)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=int, default=60)
    a = ap.parse_args()
    pp, pos_pp = run_pp(a.seconds)
    pt, pos_pt = run_pt(a.seconds)
    print(f"model time {a.seconds} s, 500 kHz PT vs PP at the same speed")
    per_rev = 16777216
    print(f"  PP (baseline): {pp:7.3f} s wall, end position {pos_pp / per_rev:.2f} rev")
    print(f"  PT           : {pt:7.3f} s wall, end position {pos_pt / per_rev:.2f} rev")
    print(f"  ratio PT / PP: {pt / pp:.2f}x (goal <= 1.2x)")


if __name__ == "__main__":
    main()
