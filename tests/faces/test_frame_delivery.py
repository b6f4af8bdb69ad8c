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
            held = threading.Event()

            def busy() -> None:  # the model is busy (a loaded host) for 20 ms
                with stack.host.lock:
                    held.set()
                    time.sleep(0.02)

            worker = threading.Thread(target=busy)
            worker.start()
            held.wait(2)
            # handed to the face in this thread (hil.transport.inline), behind the lock
            master.send(can.Message(arbitration_id=0x080, data=b"", is_extended_id=False))
            worker.join(2)
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


def test_an_in_process_drive_answers_in_the_senders_thread():
    """On an in-process `virtual:` bus in real time the drive's CANopen face has no receive
    thread: an SDO request is answered, and the answer reaches an inline receiver, before the
    request's `send` returns (hil.transport.inline; docs/clock.md, "The real-time path")."""
    from hil.transport.can_bus import open_can
    from hil.transport.inline import inline_pump

    chan = f"inline-{uuid.uuid4().hex}"
    with VirtualDriveStack(DriveSpec(name="d1", can=f"virtual:{chan}", node_id=1)):
        assert not [t.name for t in threading.enumerate() if t.name.startswith("canopen-")]
        master = open_can(f"virtual:{chan}")
        got: list[tuple[int, bytes, int]] = []
        stop = inline_pump(master, lambda m: got.append(
            (m.arbitration_id, bytes(m.data), threading.get_ident())))
        try:
            # SDO upload of 1000h (device type): initiate upload request, CiA 301 7.2.4.3.6
            master.send(can.Message(arbitration_id=0x601, is_extended_id=False,
                                    data=bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])))
            answers = [g for g in got if g[0] == 0x581]
        finally:
            stop()
            master.shutdown()
    assert len(answers) == 1, got
    _cob, data, ident = answers[0]
    assert data[0] & 0xE0 == 0x40 and data[1:4] == bytes([0x00, 0x10, 0x00])  # upload response
    assert ident == threading.get_ident()
