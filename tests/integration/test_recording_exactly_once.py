"""Every CAN frame and Modbus byte the harness sees appears in the recording exactly once."""

from __future__ import annotations

import time
from collections import Counter
from pathlib import Path

import can
import canopen
import pytest

from hil.drivers.delta_modbus import DeltaModbus
from hil.record import topics
from hil.record.reader import Recording
from hil.record.recorder import Recorder
from hil.transport.can_bus import open_can
from hil.transport.serial_line import open_serial
from hil.virtual.stack import DriveSpec, VirtualDriveStack

pytestmark = pytest.mark.integration
EDS = str(Path(__file__).parents[2] / "fixtures" / "drive" / "a3.eds")


def test_can_frames_and_modbus_bytes_recorded_exactly_once(tmp_path: Path, free_port_factory):
    chan = f"exact-{free_port_factory()}"
    link = tmp_path / "tty"
    stack = VirtualDriveStack(
        DriveSpec(can=f"virtual:{chan}", rs485=f"pty:{link}?baud=115200", node_id=4,
                  inputs={8: True})
    ).start()
    sniffer = can.Bus(interface="virtual", channel=chan, receive_own_messages=False)
    rec_path = tmp_path / "run.mcap"
    rec = Recorder(rec_path)
    bus = open_can(f"virtual:{chan}", tap=rec, name="can0")
    net = canopen.Network(bus)
    canopen.Network.NOTIFIER_CYCLE = 0.05
    net.connect()
    line = open_serial(f"serial:{link}?baud=115200&stopbits=2", tap=rec, name="rs485")
    sent_bytes = bytearray()
    got_bytes = bytearray()
    try:
        node = net.add_node(4, EDS)
        for _ in range(20):
            assert node.sdo[0x1018][1].raw == 0x1DD
        node.sdo[0x6040].raw = 0x06
        mb = DeltaModbus(line, station=4, baud=115200)
        orig_write, orig_read = line.write, line.read

        def write(data, **kw):
            sent_bytes.extend(data)
            return orig_write(data, **kw)

        def read(n=1, timeout=None):
            data = orig_read(n, timeout)
            got_bytes.extend(data)
            return data

        line.write, line.read = write, read  # type: ignore[method-assign]
        for value in (10, 20, 30):
            mb.write_param("P1.042", value)
            assert mb.read_param("P1.042") == value
        time.sleep(0.2)
    finally:
        net.disconnect()
        line.close()
        rec.close()
    seen = []
    while (msg := sniffer.recv(0)) is not None:
        seen.append((msg.arbitration_id, bytes(msg.data)))
    sniffer.shutdown()
    stack.stop()

    recording = Recording.open(rec_path)
    frames = [m for t, _lt, _pt, m in recording.messages([topics.can_raw("can0")])]
    recorded = Counter((f["id"], bytes.fromhex(f["data"])) for f in frames)
    assert recorded == Counter(seen)  # same multiset: nothing lost, nothing doubled
    assert len(frames) >= 40
    raw = list(recording.messages([topics.rs485_raw("rs485")]))
    tx = b"".join(bytes.fromhex(m["data"]) for _t, _l, _p, m in raw if m["dir"] == "tx")
    rx = b"".join(bytes.fromhex(m["data"]) for _t, _l, _p, m in raw if m["dir"] == "rx")
    assert tx == bytes(sent_bytes)
    assert rx == bytes(got_bytes)
    modbus = [m for _t, _l, _p, m in recording.messages([topics.modbus("rs485")])]
    roles = Counter(m["role"] for m in modbus)
    assert roles == {"request": 6, "response": 6}  # three writes, three reads
    assert all(m["rtt_us"] > 0 for m in modbus if m["role"] == "response")
