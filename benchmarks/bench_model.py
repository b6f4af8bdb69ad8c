"""Speed of the motion model: 60 s of repeated PP moves in 1 ms substeps (prints, no asserts).

    .venv/bin/python benchmarks/bench_model.py

Prints simulated-time / wall-time ratios for (a) an empty baseline loop calling a no-op
60000 times, (b) the bare `Axis` doing back-and-forth trapezoidal moves, (c) the same moves
driven through `Cia402` (controlword set-points + `after_step()` every substep).
"""

from __future__ import annotations

import time

from hil.model.cia402 import Cia402
from hil.model.mechanics import COUNTS_PER_REV
from hil.model.motion import Axis
from hil.units import MS

SIM_S = 60
STEPS = SIM_S * 1000


def _noop(dt_ns: int) -> None:
    return None


def baseline() -> float:
    t0 = time.perf_counter()
    for _ in range(STEPS):
        _noop(MS)
    return time.perf_counter() - t0


def bare_axis() -> tuple[float, int]:
    axis = Axis()
    axis.set_power(True)
    targets = (0.0, 5.0 * COUNTS_PER_REV)
    moves = 0
    t0 = time.perf_counter()
    for _ in range(STEPS):
        if not axis.moving:
            moves += 1
            axis.move_to(targets[moves % 2], 3000, 200, 200)
        axis.step(MS)
    return time.perf_counter() - t0, moves


def through_cia402() -> tuple[float, int]:
    now = [0]
    axis = Axis()
    cia = Cia402(axis, clock=lambda: now[0])
    cia.power_on()
    cia.write(0x6060, 0, 1)
    cia.write(0x6081, 0, 5_000_000)  # with 6093h = 16777216/100000: 3000 rpm
    cia.write(0x6093, 1, 16777216)
    cia.write(0x6093, 2, 100000)
    for cw in (0x06, 0x07, 0x0F):
        cia.write(0x6040, 0, cw)
    moves = 0
    t0 = time.perf_counter()
    for _ in range(STEPS):
        if not axis.moving:
            moves += 1
            cia.write(0x607A, 0, 500000 * (moves % 2))
            cia.write(0x6040, 0, 0x1F)
            cia.write(0x6040, 0, 0x0F)
        now[0] += MS
        axis.step(MS)
        cia.after_step()
    return time.perf_counter() - t0, moves


def whole_drive() -> tuple[float, int]:
    """The composed `Drive` (DI/DO, brake, STO, alarms, absolute encoder, CiA 402, axis)."""
    from hil.model.drive import Drive

    drive = Drive(inputs={8: True})
    drive.write_object(0x6060, 0, 1)
    drive.write_object(0x6081, 0, 5_000_000)
    for cw in (0x06, 0x07, 0x0F):
        drive.write_object(0x6040, 0, cw)
    moves = 0
    t0 = time.perf_counter()
    end = SIM_S * 1000 * MS
    while drive.now < end:
        if not drive.axis.moving:
            moves += 1
            drive.write_object(0x607A, 0, 500000 * (moves % 2))
            drive.write_object(0x6040, 0, 0x1F)
            drive.write_object(0x6040, 0, 0x0F)
        drive.advance(10 * MS)
    return time.perf_counter() - t0, moves


def main() -> None:
    base = baseline()
    print(f"baseline: {STEPS} no-op calls in {base * 1e3:.1f} ms")
    for name, fn in (("axis", bare_axis), ("axis+cia402", through_cia402),
                     ("whole Drive", whole_drive)):
        wall, moves = fn()
        print(
            f"{name:12s}: {SIM_S} s simulated ({moves} moves) in {wall * 1e3:.1f} ms wall; "
            f"sim/wall = {SIM_S / wall:.0f}x; cost = {wall / base:.1f}x the baseline loop; "
            f"{wall / STEPS * 1e6:.2f} us per substep"
        )


if __name__ == "__main__":
    main()
