"""The Modbus face on the real ParameterStore (hil.model.params, chapter 8 table)."""

from __future__ import annotations

import pytest

from hil.faces.modbus_slave import ModbusSlave
from hil.model import params
from hil.protocol import modbus as mb

H = bytes.fromhex
MS = 1_000_000


@pytest.fixture
def face():
    store = params.ParameterStore(autosave=False)
    out: list[bytes] = []
    slave = ModbusSlave(store, send=out.append)

    def ask(adu, t=[0]):  # noqa: B006 - a running clock
        t[0] += 1000 * MS
        out.clear()
        slave.feed(adu, t[0])
        slave.tick(t[0] + 100 * MS)
        return list(out)

    return slave, store, ask


def exc(fn, code, station=0x7F):
    return mb.rtu_encode(station, mb.exception_response(fn, code))


def test_defaults_from_the_store(face):
    slave, _, _ = face
    assert slave.station == 0x7F  # P3.000 default (L10496)
    assert (slave.line.mode, slave.line.baud) == ("rtu", 38400)  # P3.002 = 6, P3.001 = 0x0203
    assert slave.line.char_format == mb.CharFormat(8, "N", 2)


def test_example_3_writes_p1009_3000_low_word_first(face):
    _, store, ask = face
    req = mb.rtu_encode(0x7F, H("10 01 12 00 02 04 0B B8 00 00"))  # example 3 body, L15838
    assert ask(req) == [mb.rtu_encode(0x7F, mb.write_multiple_response(0x0112, 2))]
    assert store.read("P1.009") == 3000
    assert ask(mb.rtu_encode(0x7F, mb.read_request(0x0112, 2))) == [
        mb.rtu_encode(0x7F, mb.read_response([0x0BB8, 0]))
    ]


def test_refusals_map_to_exceptions(face):
    _, store, ask = face
    # P2.000 is 0..2047 (L9138): out of range -> 03
    assert ask(mb.rtu_encode(0x7F, mb.write_single_request(0x0200, 5000))) == [exc(6, 3)]
    # P0.000 firmware version is ★ read-only (L6720) -> 02
    assert ask(mb.rtu_encode(0x7F, mb.write_single_request(0x0000, 1))) == [exc(6, 2)]
    # P3.005 is reserved (L10580) -> 02
    assert ask(mb.rtu_encode(0x7F, mb.read_request(0x030A, 1))) == [exc(3, 2)]
    # P1.000 is ▲ (not while Servo On, L6721) -> 04
    store.servo_on = lambda: True
    assert ask(mb.rtu_encode(0x7F, mb.write_single_request(0x0100, 0x0002))) == [exc(6, 4)]
    # P2.071 needs the key P2.008 = 271 (L16454) -> 04
    assert ask(mb.rtu_encode(0x7F, mb.write_single_request(0x028E, 1))) == [exc(6, 4)]


def test_p3007_and_p3004_read_live_from_the_store(face):
    slave, store, ask = face
    fired = []
    slave.on_timeout = fired.append
    store.write("P3.007", 4)  # 4 x 0.5 ms (L10612)
    assert slave.response_delay_ns() == 2 * MS
    store.write("P3.004", 1)
    ask(mb.rtu_encode(0x7F, mb.read_request(0x0200, 1)))
    slave.tick(10_000 * MS)
    assert len(fired) == 1
