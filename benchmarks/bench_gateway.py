"""The cost of the gateway hop, beside the direct transport, in one run (loopback only).

    .venv/bin/python benchmarks/bench_gateway.py [--n 300] [--frames 5000]

direct : runner --zenoh--> virtual drive (the drive's own zenoh CAN bus / zenoh RS-485 line)
gateway: runner --zenoh--> hil gateway --virtual CAN / pty RS-485--> virtual drive
Prints CAN SDO round trip (median, p99), CAN frames/s both ways, Modbus RTU round trip at
115200 bit/s, and gateway/direct ratios. Everything runs in this process (one GIL), so the
absolute numbers are pessimistic; the ratios are the point.
"""

from __future__ import annotations

import argparse
import socket
import statistics
import sys
import tempfile
import time
import uuid
from pathlib import Path

import can

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from hil.bench.bench import loads_bench
from hil.gateway.client import acquire
from hil.gateway.gateway import Gateway, GatewayConfig
from hil.protocol.modbus import read_request, rtu_encode
from hil.transport.can_bus import open_can
from hil.transport.serial_line import open_serial
from hil.virtual.stack import DriveSpec, VirtualDriveStack

SDO_UPLOAD_6041 = bytes([0x40, 0x41, 0x60, 0x00, 0, 0, 0, 0])
BAUD = 115200


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def sdo_rtts(bus: can.BusABC, n: int) -> list[float]:
    out = []
    req = can.Message(arbitration_id=0x601, data=SDO_UPLOAD_6041, is_extended_id=False)
    for _ in range(n):
        t0 = time.perf_counter()
        bus.send(req)
        while True:
            m = bus.recv(2.0)
            if m is None:
                raise RuntimeError("no SDO answer")
            if m.arbitration_id == 0x581:
                break
        out.append(time.perf_counter() - t0)
    return out


def modbus_rtts(line, n: int) -> list[float]:
    out = []
    req = rtu_encode(1, read_request(0x0000, 2))
    for _ in range(n):
        t0 = time.perf_counter()
        line.write(req)
        if line.read_frame(timeout=2.0) is None:
            raise RuntimeError("no Modbus answer")
        out.append(time.perf_counter() - t0)
        time.sleep(0.002)  # > t3.5 between transactions
    return out


def throughput(tx: can.BusABC, rx: can.BusABC, n: int) -> float:
    """Frames/s that arrive at `rx` while `tx` sends `n` frames back to back."""
    msg = can.Message(arbitration_id=0x7E5, data=bytes(8), is_extended_id=False)  # no node
    got = 0
    t0 = time.perf_counter()
    for _ in range(n):
        tx.send(msg)
    deadline = time.perf_counter() + 10
    while got < n and time.perf_counter() < deadline:
        m = rx.recv(0.5)
        if m is None:
            break
        if m.arbitration_id == 0x7E5:
            got += 1
    return got / (time.perf_counter() - t0)


def stats(xs: list[float]) -> tuple[float, float]:
    xs = sorted(xs)
    return statistics.median(xs) * 1e3, xs[int(0.99 * (len(xs) - 1))] * 1e3


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=300, help="SDO round trips per path")
    ap.add_argument("--modbus", type=int, default=100, help="Modbus round trips per path")
    ap.add_argument("--frames", type=int, default=5000, help="frames per throughput run")
    a = ap.parse_args()
    tmp = Path(tempfile.mkdtemp(prefix="bench-gw-"))
    tag = uuid.uuid4().hex[:6]
    results: dict[str, dict[str, float]] = {"direct": {}, "gateway": {}}

    # -- direct: the drive on its own zenoh CAN bus and zenoh RS-485 line ----------------------
    ep = f"tcp/127.0.0.1:{free_port()}"
    sep = f"tcp/127.0.0.1:{free_port()}"
    direct = VirtualDriveStack(DriveSpec(
        name="d", node_id=1, station=1, can=f"zenoh:direct/can0?listen={ep}",
        rs485=f"zenoh:direct/rs485?listen={sep}&role=slave&baud={BAUD}")).start()
    try:
        bus = open_can(f"zenoh:direct/can0?connect={ep}")
        tep = f"tcp/127.0.0.1:{free_port()}"  # throughput: a bench-side bus of its own
        sink = open_can(f"zenoh:direct/tput?listen={tep}")
        runner = open_can(f"zenoh:direct/tput?connect={tep}")
        line = open_serial(f"zenoh:direct/rs485?connect={sep}&role=master&baud={BAUD}")
        try:
            sdo_rtts(bus, 20)
            results["direct"]["sdo"] = sdo_rtts(bus, a.n)
            results["direct"]["modbus"] = modbus_rtts(line, a.modbus)
            results["direct"]["to_bench"] = throughput(runner, sink, a.frames)
            results["direct"]["from_bench"] = throughput(sink, runner, a.frames)
        finally:
            bus.shutdown()
            sink.shutdown()
            runner.shutdown()
            line.close()
    finally:
        direct.stop()

    # -- gateway: the drive on a virtual bus and a pty behind a gateway -------------------------
    link = tmp / "ttyA3"
    bench = loads_bench(
        f"name: b1\nvirtual: false\ncan:\n  can0: \"virtual:bgw-{tag}\"\n"
        f"rs485:\n  rs485: \"serial:{link}?baud={BAUD}\"\n"
        "drives:\n  d:\n    can: can0\n    node_id: 1\n    rs485: rs485\n    station: 1\n")
    stack = VirtualDriveStack(DriveSpec(name="d", node_id=1, station=1,
                                        can=f"virtual:bgw-{tag}",
                                        rs485=f"pty:{link}?baud={BAUD}")).start()
    gep = f"tcp/127.0.0.1:{free_port()}"
    gw = Gateway(bench, GatewayConfig(lab="bench", listen=[gep], record=None)).start()
    try:
        gw.wait_ready(5)
        with acquire("bench", "b1", holder="bench_gateway", connect=[gep]) as lease:
            bus = open_can(lease.can_url("can0"))
            local = open_can(f"virtual:bgw-{tag}")  # a listener on the bench bus
            line = open_serial(lease.serial_url("rs485", BAUD))
            try:
                sdo_rtts(bus, 20)
                results["gateway"]["sdo"] = sdo_rtts(bus, a.n)
                results["gateway"]["modbus"] = modbus_rtts(line, a.modbus)
                results["gateway"]["to_bench"] = throughput(bus, local, a.frames)
                results["gateway"]["from_bench"] = throughput(local, bus, a.frames)
            finally:
                bus.shutdown()
                local.shutdown()
                line.close()
    finally:
        gw.stop()
        stack.stop()

    d, g = results["direct"], results["gateway"]
    print(f"{'':28}{'direct':>14}{'gateway':>14}{'ratio':>8}")
    for label, key in (("CAN SDO round trip", "sdo"), ("Modbus RTU round trip", "modbus")):
        (dm, dp), (gm, gp) = stats(d[key]), stats(g[key])
        print(f"{label + ' median ms':28}{dm:14.3f}{gm:14.3f}{gm / dm:8.2f}")
        print(f"{label + ' p99 ms':28}{dp:14.3f}{gp:14.3f}{gp / dp:8.2f}")
        print(f"{'  added by the hop, ms':28}{'':14}{gm - dm:14.3f}")
    for label, key in (("CAN frames/s runner->bench", "to_bench"),
                       ("CAN frames/s bench->runner", "from_bench")):
        ratio = g[key] / d[key] if d[key] else float("nan")
        print(f"{label:28}{d[key]:14.0f}{g[key]:14.0f}{ratio:8.2f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
