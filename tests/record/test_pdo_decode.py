"""PDO payloads decoded with the mapping the bus configured (CiA 301 7.5.2.35-38): the
recorder learns 1A00h/1600h and 1800h/1400h from the SDO downloads it records, and a
reviewer then sees statusword, position and velocity, not hex. Frames written fresh from CiA
301: expedited download 23h/2Bh/2Fh + index (LE) + sub + data, answered by 60h."""

from __future__ import annotations

import json
import struct

import can
from mcap.reader import make_reader

from hil.protocol.canopen import PdoMaps
from hil.record.recorder import Recorder
from hil.record.schemas import message_problems

NODE = 1


def _download(index: int, sub: int, value: int, size: int) -> tuple[can.Message, can.Message]:
    cs = {1: 0x2F, 2: 0x2B, 4: 0x23}[size]
    req = struct.pack("<BHB", cs, index, sub) + value.to_bytes(size, "little").ljust(4, b"\0")
    resp = struct.pack("<BHB", 0x60, index, sub) + bytes(4)
    return (can.Message(arbitration_id=0x600 + NODE, data=req, is_extended_id=False),
            can.Message(arbitration_id=0x580 + NODE, data=resp, is_extended_id=False))


def test_pdo_maps_follow_the_bus() -> None:
    m = PdoMaps()
    assert m.decode(0x181, bytes(6)) is None  # the A3 ships no mapping (L17980-18024)
    m.sdo_download(NODE, 0x1A00, 0, 0)
    m.sdo_download(NODE, 0x1A00, 1, 0x60410010)  # 6041h sub 0, 16 bits
    m.sdo_download(NODE, 0x1A00, 2, 0x60640020)  # 6064h sub 0, 32 bits
    m.sdo_download(NODE, 0x1A00, 0, 2)
    frame = struct.pack("<Hi", 0x1637, -123456)
    d = m.decode(0x181, frame)
    assert d == {"pdo": "TPDO1", "objects": {"6041h:00": 0x1637, "6064h:00": -123456},
                 "statusword": 0x1637, "position_actual": -123456}
    # a COB-ID moved by 1800h sub 1; bit 31 set makes it invalid
    m.sdo_download(NODE, 0x1800, 1, 0x1F0)
    assert m.decode(0x1F0, frame)["pdo"] == "TPDO1"
    assert m.decode(0x181, frame) is None
    m.sdo_download(NODE, 0x1800, 1, 0x800001F0)
    assert m.decode(0x1F0, frame) is None
    m.nmt_reset(NODE)  # reset communication: back to the defaults
    assert m.decode(0x181, frame) is None
    # a mapping longer than the frame is named, never a crash
    m.sdo_download(NODE, 0x1600, 1, 0x60400010)
    m.sdo_download(NODE, 0x1600, 2, 0x607A0020)
    m.sdo_download(NODE, 0x1600, 0, 2)
    assert "longer than" in m.decode(0x201, b"\x0f\x00")["error"]


def test_recorded_pdos_carry_their_objects_and_fit_the_schema(tmp_path) -> None:
    path = tmp_path / "pdo.mcap"
    t = 1_000_000_000
    with Recorder(path) as rec:
        for index, sub, value, size in ((0x1A00, 0, 0, 1), (0x1A00, 1, 0x60410010, 4),
                                        (0x1A00, 2, 0x606C0020, 4), (0x1A00, 0, 2, 1)):
            req, resp = _download(index, sub, value, size)
            rec.can("can0", req, "tx", t, None)
            rec.can("can0", resp, "rx", t + 200_000, None)
            t += 1_000_000
        tpdo = can.Message(arbitration_id=0x181, data=struct.pack("<Hi", 0x0637, 3000),
                           is_extended_id=False)
        rec.can("can0", tpdo, "rx", t, None)
        rec.can("can0", can.Message(arbitration_id=0, data=b"\x82\x01", is_extended_id=False),
                "tx", t + 1, None)  # NMT reset communication of node 1
        rec.can("can0", tpdo, "rx", t + 2, None)
    with open(path, "rb") as f:
        msgs = [(sch.name, json.loads(m.data)) for sch, ch, m in
                make_reader(f).iter_messages(topics=["/canopen/can0"])]
    pdos = [m for _, m in msgs if m.get("kind") == "tpdo1"]
    assert pdos[0]["statusword"] == 0x0637 and pdos[0]["velocity_actual"] == 3000
    assert pdos[0]["objects"] == {"6041h:00": 0x0637, "606Ch:00": 3000}
    assert "statusword" not in pdos[1] and pdos[1]["data"]  # after the reset: hex again
    for schema, m in msgs:
        assert message_problems(schema, m) == [], m
