"""NMT, SYNC supervision, bus errors and the heartbeat consumer against CiA 301 and the
manual, written from them (an outside review found these departures). A face on a drive's
injected clock, frames fed with their times."""

from __future__ import annotations

import can
import pytest

from hil.faces.canopen_slave import CanopenSlave
from hil.model.drive import Drive
from hil.units import MS

NODE = 5


class _Bus:
    def __init__(self) -> None:
        self.sent: list[can.Message] = []

    def send(self, m: can.Message, timeout: float | None = None) -> None:
        self.sent.append(m)


class Rig:
    def __init__(self) -> None:
        self.d = Drive(inputs={8: True})
        self.bus = _Bus()
        self.s = CanopenSlave(self.bus, self.d, node_id=NODE, own_timer=False,
                              clock=lambda: self.d.now)
        self.s.start(thread=False)

    def feed(self, cid: int, data: bytes = b"", **kw) -> None:
        self.s.feed(can.Message(arbitration_id=cid, data=data, is_extended_id=False,
                                timestamp=self.d.now / 1e9, **kw))

    def run(self, ms: int) -> None:
        for _ in range(ms):
            self.d.advance(MS)
            self.s.tick(self.d.now)

    def nmt(self, cs: int) -> None:
        self.feed(0x000, bytes([cs, NODE]))

    def sdo_write(self, index: int, sub: int, value: int) -> bytes:
        self.bus.sent.clear()
        self.feed(0x600 + NODE, bytes([0x23, index & 0xFF, index >> 8, sub])
                  + value.to_bytes(4, "little"))
        self.run(2)
        return bytes(next(m.data for m in self.bus.sent if m.arbitration_id == 0x580 + NODE))


def ip_rig() -> Rig:
    """IP mode (6060h = 7) with 1006h = 10 ms, OPERATIONAL, enabled."""
    r = Rig()
    r.sdo_write(0x1006, 0, 10_000)
    r.d.write_object(0x6060, 0, 7)
    r.nmt(0x01)
    for cw in (6, 7, 15):
        r.d.write_object(0x6040, 0, cw)
        r.run(10)
    return r


@pytest.mark.parametrize("start_after", [5, 2])
def test_sync_running_through_pre_operational_raises_nothing(start_after):
    """SYNC is a Pre-Operational object too (L17089-L17095); a master that keeps its SYNC
    every 10 ms while it takes the node to PRE-OPERATIONAL and back misses no SYNC, so no
    AL3E3 (timeout, L20165) and no AL301 (cycle off, L20123) may follow."""
    r = ip_rig()
    for k in range(20):
        r.feed(0x80)
        if k == 8:
            r.nmt(0x80)  # enter PRE-OPERATIONAL
        if k == 8 + start_after:
            r.run(3)
            r.nmt(0x01)  # start again, 3 ms after a SYNC
            r.run(7)
        else:
            r.run(10)
    assert not {"AL3E3", "AL301", "AL3E2"} & set(r.d.alarms.active)


def test_an_rtr_on_the_sync_cob_id_is_no_sync():
    """A SYNC is a data frame of length 0 (L17046): a remote frame on 080h 2 ms after a SYNC
    is not an early SYNC (no AL3E2, L20159)."""
    r = ip_rig()
    for _ in range(4):
        r.feed(0x80)
        r.run(10)
    r.feed(0x80)
    r.run(2)
    r.feed(0x80, is_remote_frame=True)
    r.run(1)
    assert "AL3E2" not in r.d.alarms.active


def test_al185_comes_again_after_its_clear_while_errors_go_on():
    """AL185: the error counter above 128 (L20029), cleared by an NMT reset (L20031); error
    frames that keep the counter above 128 after the clear raise it again."""
    r = Rig()
    r.nmt(0x01)
    for _ in range(17):
        r.feed(0, is_error_frame=True)
    assert "AL185" in r.d.alarms.active
    r.nmt(0x82)  # reset communication
    r.run(2)
    assert "AL185" not in r.d.alarms.active
    for _ in range(3):
        r.feed(0, is_error_frame=True)
    assert "AL185" in r.d.alarms.active


def test_a_valid_frame_brings_an_error_passive_counter_back_below_128():
    """ISO 11898-1 fault confinement: a successful reception takes a receive error counter
    above 127 to 119..127, not down by one."""
    r = Rig()
    r.nmt(0x01)
    for _ in range(20):
        r.feed(0, is_error_frame=True)
    assert r.s.comm.rx_error_counter > 128
    r.feed(0x77F, b"\x05")  # any valid frame on the bus
    assert 119 <= r.s.comm.rx_error_counter <= 127


@pytest.mark.parametrize("node", [0x80, 0xFF])
def test_1016h_refuses_a_node_id_above_127(node):
    """1016h bits 23..16 are the watched node's ID (L17742), 1..127 in CiA 301: 0x80-0xFF
    is refused (SDO abort 0609 0030) rather than masked to another node."""
    r = Rig()
    answer = r.sdo_write(0x1016, 1, node << 16 | 100)
    assert answer[0] == 0x80 and int.from_bytes(answer[4:8], "little") == 0x06090030
    r.feed(0x700 + (node & 0x7F), b"\x05")
    r.run(150)
    assert "AL180" not in r.d.alarms.active
