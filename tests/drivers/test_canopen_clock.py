"""canopen's own waits on a virtual bench (hil.drivers.canopen_clock): a heartbeat, a boot-up,
an EMCY, a PDO and an LSS reply are waited for in bench time. Before, each waited on a
`threading.Condition`, a `queue.Queue` or `time.time()`: a wall second passed, no bench time,
and nothing the drive sent could arrive."""

from __future__ import annotations

import time

import can
import canopen
import pytest

from hil import clock
from hil.clock import VirtualClock
from hil.drivers.canopen_clock import ClockNetwork, node_on_clock
from hil.drivers.cia402 import EDS_PATH, object_dictionary
from hil.transport.can_bus import open_can
from hil.transport.sim import ListenerPump, frame_bits

MS = 1_000_000


@pytest.fixture
def bench():
    """A harness network with node 5 on it, and a raw bus the test sends the node's frames on,
    on a virtual clock starting at 0."""
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        bus, dev = open_can("virtual:cc"), open_can("virtual:cc")
        net = ClockNetwork(bus)  # what a virtual session opens
        net.notifier = ListenerPump(bus, net.listeners)
        node = canopen.RemoteNode(5, object_dictionary(EDS_PATH, 5))  # the A3's EDS: 4 TPDOs
        node.associate_network(net)  # as a test might, not through add_node
        wall = time.monotonic()
        yield c, net, node, dev
        assert time.monotonic() - wall < 5  # every wait was bench time, not wall time
        bus.shutdown()
        dev.shutdown()


def _later(dev, at_ns: int, cob: int, data: bytes) -> can.Message:
    msg = can.Message(arbitration_id=cob, data=data, is_extended_id=False)
    clock.call_later(at_ns / 1e9, dev.send, msg)
    return msg


def _arrival(at_ns: int, msg: can.Message) -> int:
    return at_ns + frame_bits(msg) * 1000  # 1 Mbit/s


def test_heartbeat_and_bootup(bench) -> None:
    c, _net, node, dev = bench
    hb = _later(dev, 30 * MS, 0x705, b"\x7f")  # pre-operational (7Fh)
    assert node.nmt.wait_for_heartbeat(1.0) == "PRE-OPERATIONAL"
    assert c.time_ns() == _arrival(30 * MS, hb)  # when it arrived, not a poll later
    t0 = c.time_ns()
    with pytest.raises(canopen.nmt.NmtError):
        node.nmt.wait_for_heartbeat(0.25)
    assert c.time_ns() - t0 == 250 * MS
    t0 = c.time_ns()
    boot = _later(dev, 120 * MS, 0x705, b"\x00")
    node.nmt.wait_for_bootup(1.0)
    assert c.time_ns() == _arrival(t0 + 120 * MS, boot)
    t0 = c.time_ns()
    with pytest.raises(canopen.nmt.NmtError, match="boot-up"):
        node.nmt.wait_for_bootup(0.3)
    assert c.time_ns() - t0 == 400 * MS  # canopen's own takes one up to 0.1 s late
    t0 = c.time_ns()
    late = _later(dev, 350 * MS, 0x705, b"\x00")
    node.nmt.wait_for_bootup(0.3)  # as a real bench's canopen accepts it
    assert c.time_ns() == _arrival(t0 + 350 * MS, late)


def test_emcy_wait_skips_other_codes(bench) -> None:
    c, _net, node, dev = bench
    _later(dev, 10 * MS, 0x85, bytes([0x10, 0x50, 0, 0, 0, 0, 0, 0]))  # 5010h: not this one
    want = _later(dev, 40 * MS, 0x85, bytes([0x10, 0x23, 0, 0, 0, 0, 0, 0]))  # 2310h
    err = node.emcy.wait(0x2310, 1.0)
    assert err is not None and err.code == 0x2310
    assert c.time_ns() == _arrival(40 * MS, want)
    t0 = c.time_ns()
    assert node.emcy.wait(0x2310, 0.2) is None
    assert c.time_ns() - t0 == 200 * MS


def test_pdo_wait_for_reception(bench) -> None:
    c, _net, node, dev = bench
    tpdo = node.tpdo[1]
    tpdo.cob_id, tpdo.enabled = 0x185, True
    tpdo.subscribe()
    pdo = _later(dev, 25 * MS, 0x185, b"\x37\x02")
    assert tpdo.wait_for_reception(1.0) is not None
    assert c.time_ns() == _arrival(25 * MS, pdo) and bytes(tpdo.data) == b"\x37\x02"
    t0 = c.time_ns()
    assert tpdo.wait_for_reception(0.1) is None
    assert c.time_ns() - t0 == 100 * MS


def test_lss_reply_timeout_is_bench_time(bench) -> None:
    c, net, _node, _dev = bench
    t0 = c.time_ns()
    with pytest.raises(canopen.lss.LssError):
        net.lss.inquire_node_id()  # no LSS slave answers
    request = can.Message(arbitration_id=0x7E5, data=bytes([0x5E] + [0] * 7),
                          is_extended_id=False)  # inquire node-ID, on the wire first
    assert c.time_ns() - t0 == _arrival(round(net.lss.RESPONSE_TIMEOUT * 1e9), request)
    net.lss.responses = None  # canopen's own reset after a stale reply keeps the clock queue
    assert isinstance(net.lss.responses, clock.ClockQueue)


def test_node_on_clock_on_a_plain_network() -> None:
    """A node on a network that is not a `ClockNetwork` (a test's own): `node_on_clock`."""
    c = VirtualClock(epoch_ns=0)
    with clock.use(c):
        bus, dev = open_can("virtual:cc2"), open_can("virtual:cc2")
        net = canopen.Network(bus)
        net.notifier = ListenerPump(bus, net.listeners)
        node = node_on_clock(net.add_node(5, object_dictionary(EDS_PATH, 5)))
        hb = _later(dev, 20 * MS, 0x705, b"\x05")
        assert node.nmt.wait_for_heartbeat(1.0) == "OPERATIONAL"
        assert c.time_ns() == _arrival(20 * MS, hb)
        bus.shutdown()
        dev.shutdown()


def test_the_time_producer_sends_bench_time() -> None:
    """canopen's TIME producer (`net.time.transmit()`) on a virtual bench: the bench's time of
    day (days since 1984-01-01, ms after midnight; CiA 301 TIME_OF_DAY), not the host's."""
    c = VirtualClock()  # bench time starts at 2000-01-01T00:00:00Z
    with clock.use(c):
        bus, dev = open_can("virtual:cc3"), open_can("virtual:cc3")
        net = ClockNetwork(bus)
        net.notifier = ListenerPump(bus, net.listeners)
        got: list[bytes] = []
        from hil.transport.sim import pump

        pump(dev, lambda m: got.append(bytes(m.data)))
        clock.sleep(1.5)
        net.time.transmit()
        days_1984_2000 = 16 * 365 + 4  # 1984, 1988, 1992 and 1996 are leap years
        assert got == [(1500).to_bytes(4, "little") + days_1984_2000.to_bytes(2, "little")]
        bus.shutdown()
        dev.shutdown()
