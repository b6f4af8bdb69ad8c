"""SDO expedited upload round trip: our CanopenSlave vs canopen.LocalNode (baseline).

Same run, same in-process python-can `virtual` bus, 1000 uploads of 1000h each.
Usage: .venv/bin/python benchmarks/bench_sdo.py [N]
"""

from __future__ import annotations

import statistics
import sys
import threading
import time
import uuid
from pathlib import Path

import can
import canopen

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "faces"))
from fake_drive import FakeDrive

from hil.faces.canopen_slave import CanopenSlave
from hil.profile.od import EDS_PATH

canopen.Network.NOTIFIER_CYCLE = 0.05
NODE = 5


def measure(channel: str, n: int) -> list[float]:
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    try:
        node = net.add_node(NODE, canopen.ObjectDictionary())
        node.sdo.upload(0x1000, 0)  # warm-up
        out = []
        for _ in range(n):
            t0 = time.perf_counter_ns()
            node.sdo.upload(0x1000, 0)
            out.append((time.perf_counter_ns() - t0) / 1000)
        return out
    finally:
        net.disconnect()


def ours(n: int) -> list[float]:
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    bus = can.Bus(interface="virtual", channel=channel)
    slave = CanopenSlave(bus, FakeDrive(node_id=NODE), lock=threading.RLock()).start()
    try:
        return measure(channel, n)
    finally:
        slave.close()
        bus.shutdown()


def local_node(n: int) -> list[float]:
    channel = f"bench-{uuid.uuid4().hex[:8]}"
    net = canopen.Network()
    net.connect(interface="virtual", channel=channel)
    try:
        net.add_node(canopen.LocalNode(NODE, str(EDS_PATH)))
        return measure(channel, n)
    finally:
        net.disconnect()


def pct(xs: list[float], p: float) -> float:
    return statistics.quantiles(xs, n=100)[int(p) - 1]


def main() -> None:
    n = int(sys.argv[1]) if len(sys.argv) > 1 else 1000
    a, b = ours(n), local_node(n)
    for name, xs in (("CanopenSlave", a), ("LocalNode", b)):
        print(
            f"{name:13s} expedited upload 1000h: p50 {pct(xs, 50):7.1f} us  "
            f"p99 {pct(xs, 99):7.1f} us  (n={n})"
        )
    print(
        f"ratio ours/LocalNode: p50 {pct(a, 50) / pct(b, 50):.2f}  "
        f"p99 {pct(a, 99) / pct(b, 99):.2f}"
    )


if __name__ == "__main__":
    main()
