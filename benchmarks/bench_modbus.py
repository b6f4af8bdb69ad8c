"""Round trip of 10-word Modbus RTU reads: DeltaModbus -> pty -> ModbusSlave, beside line time.

    .venv/bin/python benchmarks/bench_modbus.py [-n 2000]

The baseline is computed in the same run from the frame sizes: request (8 bytes) and
response (25 bytes) at 115200 8N1 plus the slave's turnaround t3.5 (fixed 1.75 ms above
19200 baud, Modbus over serial line v1.02 §2.5.1.1; the face waits that long on purpose).
A pty has no baud rate, so the measured time is turnaround + host overhead; the ratio shows
how far a pty bench is from a real line (and that the face never answers early).
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import tty

from hil.drivers.delta_modbus import DeltaModbus
from hil.faces.modbus_slave import FdLine, ModbusSlave, ModbusSlaveRunner
from hil.protocol import modbus as mb

BAUD = 115200
FMT = mb.CharFormat(8, "N", 1)


class Words:
    def __init__(self) -> None:
        self.words = {0x0100 + i: i for i in range(10)}

    def modbus_read(self, address: int, count: int) -> list[int]:
        return [self.words[a] for a in range(address, address + count)]

    def modbus_write(self, address: int, words: list[int]) -> None:
        for i, w in enumerate(words):
            self.words[address + i] = w


def pct(values: list[float], p: float) -> float:
    values = sorted(values)
    return values[min(len(values) - 1, round(p / 100 * (len(values) - 1)))]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-n", type=int, default=2000, help="reads to time")
    args = ap.parse_args()

    req = len(mb.rtu_encode(1, mb.read_request(0x0100, 10)))
    rsp = len(mb.rtu_encode(1, mb.read_response([0] * 10)))
    wire = mb.frame_time_ns(req + rsp, BAUD, FMT) / 1e6
    t35_fixed = mb.silent_intervals_ns(BAUD, FMT)[1] / 1e6
    t35_chars = mb.silent_intervals_ns(BAUD, FMT, fixed_above_19200=False)[1] / 1e6
    line_ms = wire + t35_fixed

    master, slave_fd = os.openpty()
    tty.setraw(master)
    tty.setraw(slave_fd)
    face = ModbusSlave(Words(), station=1, baud=BAUD, char_format=FMT)
    runner = ModbusSlaveRunner(face, FdLine(master), poll_s=0.002).start()
    rtts: list[float] = []
    try:
        with DeltaModbus(os.ttyname(slave_fd), station=1, baud=BAUD, char_format=FMT,
                         timeout_s=1.0, silence_s=0) as drive:  # fmt: skip
            for _ in range(50):
                drive.read_registers(0x0100, 10)
            for _ in range(args.n):
                t0 = time.perf_counter_ns()
                drive.read_registers(0x0100, 10)
                rtts.append((time.perf_counter_ns() - t0) / 1e6)
    finally:
        runner.stop()
        os.close(slave_fd)
        os.close(master)

    p50, p99 = pct(rtts, 50), pct(rtts, 99)
    print(f"10-word read, RTU, {args.n} round trips over a pty (DeltaModbus <-> ModbusSlave)")
    print(f"  frames: request {req} B, response {rsp} B; 115200 {FMT}: wire {wire:.3f} ms")
    print(f"  line-time baseline: wire + t3.5 turnaround ({t35_fixed:.3f} ms) = {line_ms:.3f} ms"
          f"  (with 3.5 char times {t35_chars:.3f} ms: {wire + t35_chars:.3f} ms)")  # fmt: skip
    print(f"  measured: p50 {p50:.3f} ms  p99 {p99:.3f} ms  max {max(rtts):.3f} ms"
          f"  mean {statistics.fmean(rtts):.3f} ms")  # fmt: skip
    print(f"  ratio measured/line: p50 {p50 / line_ms:.2f}  p99 {p99 / line_ms:.2f}")
    print(f"  face stats: {face.stats}")


if __name__ == "__main__":
    main()
