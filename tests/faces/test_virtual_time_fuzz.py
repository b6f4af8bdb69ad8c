"""Hostile frames and bytes on the virtual-time bus and line (docs/clock.md), as a stranger
sends them: random CAN frames of every shape (standard, extended, remote, error, DLC 0-8) and
random RS-485 bytes into a whole virtual drive stack on the virtual clock. Nothing escapes
the clock's events, time never runs backwards, and the drive still answers an SDO upload and
a Modbus read afterwards."""

from __future__ import annotations

import random
import struct

import can
import pytest

from hil import clock
from hil.clock import VirtualClock
from hil.protocol import modbus as mb
from hil.transport.can_bus import open_can
from hil.transport.serial_line import open_serial
from hil.transport.sim import pump
from hil.virtual.stack import DriveSpec, VirtualDriveStack


@pytest.mark.parametrize("seed", [1, 2])
def test_random_frames_and_bytes_never_stop_the_virtual_drive(seed, tmp_path) -> None:
    rng = random.Random(seed)
    clk = VirtualClock()
    with clock.use(clk):
        stack = VirtualDriveStack(DriveSpec(can="virtual:fz", rs485=f"pty:{tmp_path}/l",
                                            node_id=1, station=1)).start()
        try:
            bus = open_can("virtual:fz")
            got: list[can.Message] = []
            stop = pump(bus, got.append)
            line = open_serial(f"serial:{tmp_path}/l")
            last = clk.time_ns()
            for _ in range(1500):
                ext = rng.random() < 0.1
                msg = can.Message(
                    arbitration_id=rng.randrange(1 << (29 if ext else 11)),
                    data=bytes(rng.randrange(256) for _ in range(rng.randrange(9))),
                    is_extended_id=ext, is_remote_frame=rng.random() < 0.05,
                    is_error_frame=rng.random() < 0.02)
                bus.send(msg)
                if rng.random() < 0.2:
                    line.write(bytes(rng.randrange(256) for _ in range(rng.randrange(1, 40))))
                clk.sleep(rng.random() * 0.003)
                assert clk.time_ns() >= last
                last = clk.time_ns()
            clk.sleep(0.2)  # let any half frame on the line time out (t3.5)
            assert not stack.host.errors, stack.host.errors[:3]
            # still a drive: NMT reset (a fuzz frame may have stopped it), then SDO 1000h
            bus.send(can.Message(arbitration_id=0, data=b"\x81\x01", is_extended_id=False))
            clk.sleep(0.05)
            got.clear()
            bus.send(can.Message(arbitration_id=0x601, data=b"\x40\x00\x10\x00\0\0\0\0",
                                 is_extended_id=False))
            clk.sleep(0.01)
            answers = [m for m in got if m.arbitration_id == 0x581]
            assert answers and answers[-1].data[0] in (0x43, 0x80), answers
            line.reset_input_buffer()
            line.write(mb.encode_adu(1, struct.pack(">BHH", 0x03, 0x0000, 1), "rtu"))
            reply = line.read_frame(timeout=0.5)
            assert reply is not None and reply.data[:2] in (b"\x01\x03", b"\x01\x83")
            stop()
            bus.shutdown()
            line.close()
        finally:
            stack.stop()
