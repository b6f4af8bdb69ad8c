"""The Modbus face against ch.9's rules, written from the manual (an outside review found
these departures): framing by silence, the P2.008 keys, the P3.001 digits and the
parameters communication may not write."""

from __future__ import annotations

import pytest

from hil.faces.modbus_slave import ModbusFaceOptions, ModbusSlave
from hil.model.drive import Drive
from hil.model.params import ParameterStore
from hil.protocol import modbus as mb

S = 1_000_000_000
MS = 1_000_000
OWN = 0x7F  # P3.000 default (L10496)


def rtu(*b: int) -> bytes:
    return mb.rtu_encode(b[0], bytes(b[1:]))


def face(store=None, **kw):
    store = store if store is not None else ParameterStore(autosave=False)
    out: list[bytes] = []
    return ModbusSlave(store, send=out.append, **kw), out, store


def ask(slave, out, adu: bytes, t: int) -> list[bytes]:
    """One burst at `t`, then a long silence: what the face sent."""
    out.clear()
    slave.feed(adu, t)
    slave.tick(t + 100 * MS)
    return list(out)


@pytest.mark.parametrize("resync", [True, False])
def test_a_request_inside_another_stations_reply_is_not_executed(resync):
    """A frame runs from one silence to the next (L15621, L15628, L15703) and a frame for
    another station gets no answer (L10507): station 1's reply whose data holds a valid
    06h write to this drive must change nothing and send nothing."""
    slave, out, store = face(options=ModbusFaceOptions(resync=resync))
    before = store.read("P2.000")
    inner = rtu(OWN, 0x06, 0x02, 0x00, 0x00, 0x05)  # P2.000 = 5 (0200H)
    reply = rtu(0x01, 0x03, 16, *inner, *bytes(8))  # 03h reply: byte count 16
    assert ask(slave, out, reply, S) == []
    assert store.read("P2.000") == before != 5


@pytest.mark.parametrize("resync", [True, False])
def test_a_write_to_us_whose_data_holds_a_frame_is_one_frame(resync):
    """A 10h write of 8 words to this drive, whose data happen to hold a valid 03h request
    to station 1: the whole frame is executed and answered (its length is its byte count)."""
    slave, out, store = face(options=ModbusFaceOptions(resync=resync))
    words = list(rtu(0x01, 0x03, 0x00, 0x00, 0x00, 0x01)) + [0] * 8  # 16 bytes = 8 words
    req = rtu(OWN, 0x10, 0x06, 0x00, 0x00, 0x08, 16, *words)  # P6.000.. (0600H), 8 words
    got = ask(slave, out, req, S)
    assert got == [rtu(OWN, 0x10, 0x06, 0x00, 0x00, 0x08)]
    assert store.modbus_read(0x0600, 8) == [words[2 * i] << 8 | words[2 * i + 1]
                                              for i in range(8)]


def test_garbage_before_a_request_in_one_burst_is_skipped_with_resync_only():
    """Leading noise then a whole request, one burst: with `resync` (the default) the request
    that ends the burst is answered; without it the burst is one bad frame (silence)."""
    req = rtu(OWN, 0x03, 0x02, 0x00, 0x00, 0x02)
    for resync, n in ((True, 1), (False, 0)):
        slave, out, _ = face(options=ModbusFaceOptions(resync=resync))
        assert len(ask(slave, out, b"\x00\xff\x13" + req, S)) == n


def test_p4010_and_p4011_p4021_need_their_p2008_keys():
    """P4.010 is writable only after P2.008 = 20, P4.011-P4.021 only after P2.008 = 22
    (L9212-L9227, L10938, L10947, L16043, L16045). Over Modbus a refused write is an
    exception response and the value stays."""
    slave, out, store = face()
    p4010 = rtu(OWN, 0x06, 0x04, 0x14, 0x00, 0x01)  # 0414H (L10926)
    p4011 = rtu(OWN, 0x06, 0x04, 0x16, 0x00, 0x05)  # 0416H
    p4021 = rtu(OWN, 0x06, 0x04, 0x2A, 0x00, 0x05)  # 042AH (L11032)
    for t, req in enumerate((p4010, p4011, p4021), 1):
        got = ask(slave, out, req, t * S)
        assert len(got) == 1 and got[0][1] == 0x86, got  # an exception, not the echo
    assert (store.read("P4.010"), store.read("P4.021")) == (0, 0)
    ask(slave, out, rtu(OWN, 0x06, 0x02, 0x10, 0x00, 20), 5 * S)  # P2.008 (0210H) = 20
    assert ask(slave, out, p4010, 6 * S) == [p4010]
    assert ask(slave, out, p4011, 7 * S)[0][1] == 0x86  # 20 opens P4.010 only
    ask(slave, out, rtu(OWN, 0x06, 0x02, 0x10, 0x00, 22), 8 * S)
    assert ask(slave, out, p4011, 9 * S) == [p4011]
    assert ask(slave, out, p4021, 10 * S) == [p4021]
    assert (store.read("P4.011"), store.read("P4.021")) == (5, 5)


@pytest.mark.parametrize("value", [0x0006, 0x000F, 0x0013, 0x0503, 0x4203])
def test_p3001_digits_outside_their_ranges_are_refused(value):
    """P3.001: U 0-3, Z 0-4, Y 0, X 0-5 (L10519-L10522); a value inside the table's range
    0x0000-0x3405 with a digit outside its own is refused (03h), and the line keeps its
    38400 baud."""
    slave, out, store = face()
    got = ask(slave, out, rtu(OWN, 0x06, 0x03, 0x02, value >> 8, value & 0xFF), S)
    assert len(got) == 1 and got[0][1] == 0x86, got
    assert store.read("P3.001") == 0x0203 and slave.line.baud == 38400


@pytest.mark.parametrize("value", [0x0000, 0x0105, 0x3405, 0x3400])
def test_p3001_digits_inside_their_ranges_are_taken(value):
    slave, out, store = face()
    req = rtu(OWN, 0x06, 0x03, 0x02, value >> 8, value & 0xFF)
    assert ask(slave, out, req, S) == [req]
    assert store.read("P3.001") == value


@pytest.mark.parametrize("name,address", [("P5.016", 0x0520), ("P5.076", 0x0598)])
def test_p5016_and_p5076_are_not_written_by_communication(name, address):
    """Ch.9.4 lists group 5 as writable by communication except P5.010, P5.016 and P5.076
    (L16025): a write of either word, single or multiple, is refused with 02h. The model
    itself (panel side) still takes it (the capture example sets P5.076, L5174)."""
    drive = Drive()
    slave, out, store = face(drive.params)
    before = store.read(name)
    for t, req in enumerate((rtu(OWN, 0x06, address >> 8, address & 0xFF, 0, 7),
                             rtu(OWN, 0x06, address >> 8, (address + 1) & 0xFF, 0, 7),
                             rtu(OWN, 0x10, address >> 8, (address - 2) & 0xFF, 0, 4, 8,
                                 *bytes(8))), 1):
        got = ask(slave, out, req, t * S)
        assert got == [rtu(OWN, req[1] | 0x80, 0x02)], (req.hex(" "), got)
    assert store.read(name) == before
    assert ask(slave, out, rtu(OWN, 0x03, address >> 8, address & 0xFF, 0, 2), 9 * S)[0][1] == 3
    drive.params.write(name, 7)
    assert drive.params.read(name) == 7


def test_the_pm_group_answers_no_parameter_without_tripping_al019():
    """PM.000-PM.053 sit at FD00H-FD6BH (PM.004 at FD08H, L14637) and are readable and
    writable by communication (L16031, L16049). The virtual drive does not model them: a read
    or write answers exception 02h, but it is no bad address of AL019's kind (L19592-19596),
    which would take the servo off; an address the drive has not still raises it (helper-90)."""
    d = Drive(params={"P3.000": 1})
    d.advance(10 * MS)
    slave, out, _ = face(d.params, on_comm_error=lambda code, _m: d.modbus_comm_error(code))
    assert ask(slave, out, rtu(1, 0x03, 0xFD, 0x08, 0x00, 0x02), S) == [rtu(1, 0x83, 0x02)]
    assert ask(slave, out, rtu(1, 0x06, 0xFD, 0x00, 0x00, 0x01), 2 * S) == [rtu(1, 0x86, 0x02)]
    assert "AL019" not in d.alarms.active
    # running past PM.053 (FD6BH) into the reserved PM.054 is an address the drive has not
    assert ask(slave, out, rtu(1, 0x03, 0xFD, 0x6A, 0x00, 0x04), 3 * S) == [rtu(1, 0x83, 0x02)]
    assert "AL019" in d.alarms.active
