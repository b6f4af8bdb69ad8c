"""A CAN frame the virtual drive got late is reported like a late input edge
(`CAN 080h`, docs/timing.md "Under load"): the stack's CANopen face measures each frame
from its sender stamp to the model time it acted; 0.5 ms or more is reported, less is not."""

from __future__ import annotations

import threading
import time
import uuid

import can
import pytest

from hil.record.topics import CAN_LATE_NS, can_line
from hil.virtual.stack import DriveSpec, VirtualDriveStack

pytestmark = pytest.mark.integration  # a real host ticking in real time


def test_a_frame_held_back_by_a_busy_model_is_reported_with_its_delay():
    chan = f"late-{uuid.uuid4().hex}"
    reports: list[tuple[str, bool, int, int]] = []
    got = threading.Event()
    with VirtualDriveStack(DriveSpec(name="d1", can=f"virtual:{chan}", node_id=1)) as stack:
        def on_input(line, level, sent_ns, model_t):
            reports.append((line, level, sent_ns, stack.host.wall_ns(model_t)))
            got.set()

        stack.on_input = on_input
        master = can.Bus(interface="virtual", channel=chan, ignore_config=True)
        try:
            nmt = can.Message(arbitration_id=0x000, data=b"\x80\x01", is_extended_id=False)
            master.send(nmt)  # pre-operational: a frame handled at once, under 0.5 ms
            time.sleep(0.2)
            quick = list(reports)
            with stack.host.lock:  # the model is busy (a loaded host) for 20 ms
                master.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
                time.sleep(0.02)
            deadline = time.monotonic() + 2.0  # the 080h frame's own report, not the NMT's
            while time.monotonic() < deadline and not any(
                    r[0] == can_line(0x080) for r in list(reports)):
                got.wait(0.05)
                got.clear()
        finally:
            master.shutdown()
    assert quick == [] or all(r[3] - r[2] >= CAN_LATE_NS for r in quick)
    late = [r for r in reports if r[0] == can_line(0x080)]
    assert len(late) == 1, reports
    _line, level, sent, applied = late[0]
    assert level is True and applied - sent >= 19_000_000  # held 20 ms behind the lock
