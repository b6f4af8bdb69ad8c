"""Cost of the passive fault layer: CAN round trip through `FaultyCanBus` with nothing
injected vs the bare bus, interleaved in the same run; prints the ratio (target <= 1.05).

    .venv/bin/python benchmarks/bench_faults.py [--rtt 2000] [--rounds 15]

RTT: ping id 0x100 from the harness side (wrapped or bare), the echo answers 0x101 on the
other end of a python-can `virtual` bus, sequential (as in bench_transport.py). Both sides
of the wrapper are exercised: send() and recv().
"""

from __future__ import annotations

import argparse
import statistics
import struct
import sys
import threading
import time

import can

sys.path.insert(0, __file__.rsplit("/", 1)[0])
from bench_transport import echo_loop

from hil.transport.faults import FaultyCanBus


def rtt_median_us(bus: can.BusABC, n: int) -> float:
    rtts = []
    for i in range(n):
        t0 = time.perf_counter()
        bus.send(can.Message(arbitration_id=0x100, data=struct.pack("<I", i),
                             is_extended_id=False))
        while True:
            msg = bus.recv(2.0)
            if msg is None:
                raise RuntimeError(f"ping {i}: no answer within 2 s")
            if msg.arbitration_id == 0x101:
                break
        rtts.append(time.perf_counter() - t0)
    return statistics.median(rtts) * 1e6


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rtt", type=int, default=2000, help="round trips per measurement")
    ap.add_argument("--rounds", type=int, default=15,
                    help="interleaved bare/wrapped rounds (one round's median varies ~10 %%)")
    a = ap.parse_args()
    ch = "bench-faults"
    bare = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    wrapped_inner = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    wrapped = FaultyCanBus(wrapped_inner, "bench")
    echo = can.Bus(interface="virtual", channel=ch, ignore_config=True)
    stop = threading.Event()
    t = threading.Thread(target=echo_loop, args=(echo, stop), daemon=True)
    t.start()
    base, layer = [], []
    try:
        rtt_median_us(bare, 200)  # warm up
        for _ in range(a.rounds):
            # the other harness-side bus also sees every frame: drain it between runs
            base.append(rtt_median_us(bare, a.rtt))
            while wrapped.recv(0) is not None:
                pass
            layer.append(rtt_median_us(wrapped, a.rtt))
            while bare.recv(0) is not None:
                pass
    finally:
        stop.set()
        t.join(5)
        for b in (bare, wrapped, echo):
            b.shutdown()
    b_us, l_us = statistics.median(base), statistics.median(layer)
    ratio = l_us / b_us
    print(f"CAN round trip, virtual bus, median of {a.rounds} x {a.rtt}:")
    print(f"  bare bus            {b_us:8.1f} us")
    print(f"  passive fault layer {l_us:8.1f} us")
    print(f"  ratio               {ratio:8.3f}  ({'ok' if ratio <= 1.05 else 'OVER'} <= 1.05)")
    return 0 if ratio <= 1.05 else 1


if __name__ == "__main__":
    sys.exit(main())
