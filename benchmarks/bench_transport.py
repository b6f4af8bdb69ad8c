"""CAN transport benchmark: python-can `virtual` (in-process, echo thread) vs `zenoh`
(2 processes, peer, tcp/127.0.0.1), measured in the same run; prints ratios to virtual.

    .venv/bin/python benchmarks/bench_transport.py [--rtt 2000] [--frames 20000]

RTT: ping id 0x100, the echo answers 0x101, sequential. Throughput: frames sent as fast
as send() allows, counted by the echo side, which reports (count, first..last seconds).
"""

from __future__ import annotations

import argparse
import socket
import statistics
import struct
import subprocess
import sys
import threading
import time

import can

THROUGHPUT_ID, REPORT_ID, DONE_ID = 0x300, 0x301, 0x7FF


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def echo_loop(bus: can.BusABC, stop: threading.Event) -> None:
    """Answer pings, count throughput frames, report on DONE_ID."""
    count, first, last = 0, 0.0, 0.0
    while not stop.is_set():
        msg = bus.recv(0.05)
        if msg is None:
            continue
        if msg.arbitration_id == 0x100:
            bus.send(can.Message(arbitration_id=0x101, data=msg.data, is_extended_id=False))
        elif msg.arbitration_id == THROUGHPUT_ID:
            now = time.perf_counter()
            first = first or now
            last, count = now, count + 1
        elif msg.arbitration_id == DONE_ID:
            bus.send(can.Message(arbitration_id=REPORT_ID, is_extended_id=False,
                                 data=struct.pack("<If", count, last - first)))
            count, first, last = 0, 0.0, 0.0


def measure(bus: can.BusABC, n_rtt: int, n_frames: int) -> dict[str, float]:
    rtts = []
    for i in range(n_rtt):
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
    data = bytes(8)
    for _ in range(n_frames):
        bus.send(can.Message(arbitration_id=THROUGHPUT_ID, data=data, is_extended_id=False))
    bus.send(can.Message(arbitration_id=DONE_ID, is_extended_id=False))
    while True:
        msg = bus.recv(10.0)
        if msg is None:
            raise RuntimeError("no throughput report within 10 s")
        if msg.arbitration_id == REPORT_ID:
            count, span = struct.unpack("<If", msg.data)
            break
    q = statistics.quantiles(rtts, n=100)
    return {"p50_us": q[49] * 1e6, "p99_us": q[98] * 1e6, "frames_s": count / max(span, 1e-9),
            "lost": n_frames - count}


def run_virtual(n_rtt: int, n_frames: int) -> dict[str, float]:
    a = can.Bus(interface="virtual", channel="bench", ignore_config=True)
    b = can.Bus(interface="virtual", channel="bench", ignore_config=True)
    stop = threading.Event()
    t = threading.Thread(target=echo_loop, args=(b, stop))
    t.start()
    try:
        return measure(a, n_rtt, n_frames)
    finally:
        stop.set()
        t.join(5)
        a.shutdown()
        b.shutdown()


def run_zenoh(n_rtt: int, n_frames: int) -> dict[str, float]:
    ep = f"tcp/127.0.0.1:{free_port()}"
    child = subprocess.Popen([sys.executable, __file__, "--echo", ep], stdin=subprocess.PIPE,
                             stdout=subprocess.PIPE, text=True)
    try:
        if "ready" not in (child.stdout.readline() or ""):
            raise RuntimeError("zenoh echo process did not start")
        bus = can.Bus(interface="zenoh", channel="bench/can", connect=[ep])
        try:
            return measure(bus, n_rtt, n_frames)
        finally:
            bus.shutdown()
    finally:
        child.stdin.close()
        try:
            child.wait(10)
        except subprocess.TimeoutExpired:
            child.kill()
            child.wait(5)
        child.stdout.close()


def echo_process(ep: str) -> None:
    bus = can.Bus(interface="zenoh", channel="bench/can", listen=[ep])
    stop = threading.Event()
    t = threading.Thread(target=echo_loop, args=(bus, stop))
    t.start()
    print("ready", flush=True)
    sys.stdin.read()
    stop.set()
    t.join(5)
    bus.shutdown()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rtt", type=int, default=2000)
    ap.add_argument("--frames", type=int, default=20000)
    ap.add_argument("--echo", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.echo:
        echo_process(args.echo)
        return
    results = {}
    for name, fn in (("virtual", run_virtual), ("zenoh 2 proc", run_zenoh)):
        print(f"running {name} ...", file=sys.stderr, flush=True)
        results[name] = fn(args.rtt, args.frames)
    base = results["virtual"]
    print(f"{'transport':<14}{'RTT p50 µs':>12}{'p99 µs':>10}{'frames/s':>11}{'lost':>6}"
          f"{'p50 x':>8}{'p99 x':>8}{'rate x':>8}")
    for name, r in results.items():
        print(f"{name:<14}{r['p50_us']:>12.0f}{r['p99_us']:>10.0f}{r['frames_s']:>11.0f}"
              f"{r['lost']:>6.0f}{r['p50_us'] / base['p50_us']:>8.2f}"
              f"{r['p99_us'] / base['p99_us']:>8.2f}{r['frames_s'] / base['frames_s']:>8.2f}")


if __name__ == "__main__":
    main()
