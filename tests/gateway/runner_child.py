"""A runner in its own process: `python runner_child.py LAB BENCH ENDPOINT HOLDER`.

Takes the bench lease, puts drive node 1 into Ready to switch on (controlword Shutdown
0x0006 over SDO, CiA 402 transition 2, manual L18272-18281), prints `ready` and holds the
lease until its stdin closes (or it is killed, which is the point of the test).
"""

from __future__ import annotations

import sys
import time


def main(lab: str, bench: str, endpoint: str, holder: str) -> int:
    import can

    from hil.gateway.client import LeaseRefused, acquire
    from hil.transport.can_bus import open_can

    try:
        lease = acquire(lab, bench, holder=holder, connect=[endpoint])
    except LeaseRefused as e:
        print(f"refused {e.holder} {e.since_ns}", flush=True)
        return 3
    bus = open_can(lease.can_url("can0"))
    try:
        bus.send(can.Message(arbitration_id=0x601, is_extended_id=False,
                             data=bytes([0x2B, 0x40, 0x60, 0, 0x06, 0, 0, 0])))
        end = time.monotonic() + 5
        while time.monotonic() < end:
            msg = bus.recv(0.05)
            if msg is not None and msg.arbitration_id == 0x581 and msg.data[0] == 0x60:
                break
        else:
            print("error: no SDO answer", flush=True)
            return 1
        print("ready", flush=True)
        sys.stdin.read()
    finally:
        bus.shutdown()
        lease.release()
    return 0


if __name__ == "__main__":
    sys.exit(main(*sys.argv[1:5]))
