"""The virtual A3's Modbus face, fed bytes with injected times (manual ch. 9)."""

from __future__ import annotations

import random

import pytest

from hil.faces.modbus_slave import ModbusFaceOptions, ModbusSlave
from hil.model import errors
from hil.protocol import modbus as mb

H = bytes.fromhex
MS = 1_000_000
S = 1_000_000_000
T35_38400 = 1_750_000  # default 38400 baud (P3.001 = 0x0203, L10510): fixed t3.5
CHAR = mb.char_time_ns(38400, 11)  # 8N2 (P3.002 = 6, L10557)


class FakeStore:
    """Word-level stand-in for hil.model.params.ParameterStore (32-bit: low word first)."""

    def __init__(self, words=None, *, read_only=(), locked=(), protected=(), limits=None):
        self.words: dict[int, int] = {
            0x0200: 0x00B1, 0x0201: 0x1F40,  # example 1 reply data, L15696-L15699
            0x0112: 0, 0x0113: 0,  # P1.009 (32-bit), example 3, L15781
            0x0300: 0x01, 0x0301: 0, 0x0302: 0x0203, 0x0303: 0,  # P3.000, P3.001
            0x0304: 6, 0x0305: 0, 0x0308: 0, 0x0309: 0, 0x030E: 0, 0x030F: 0,
            0x05C4: 0x1234, 0x05C5: 0,  # P5.098, LRC example L15873
            0x0101: 0x1042, 0x0102: 0, 0x0103: 0,  # CRC example reads 0101H, L15913
            0x0000: 0, 0x0001: 0,
        }  # fmt: skip
        self.words.update(words or {})
        self.read_only = set(read_only)
        self.locked = set(locked)
        self.protected = set(protected)
        self.limits = dict(limits or {})
        self.writes: list[tuple[int, list[int]]] = []

    def modbus_read(self, address, count):
        out = []
        for a in range(address, address + count):
            if a not in self.words:
                raise errors.UnknownParameter(f"address 0x{a:04X}", "no parameter word")
            out.append(self.words[a])
        return out

    def modbus_write(self, address, words):
        words = list(words)
        for i, w in enumerate(words):
            a = address + i
            name = f"address 0x{a:04X}"
            if a not in self.words:
                raise errors.UnknownParameter(name, "no parameter word")
            if a in self.read_only:
                raise errors.ReadOnly(name, "read-only")
            if a in self.locked:
                raise errors.ServoOnLocked(name, "servo on")
            if a in self.protected:
                raise errors.ProtectedParameter(name, "needs P2.008 key")
            lo, hi = self.limits.get(a, (0, 0xFFFF))
            if not lo <= w <= hi:
                raise errors.OutOfRange(name, f"{w} not in {lo}..{hi}")
        for i, w in enumerate(words):
            self.words[address + i] = w
        self.writes.append((address, words))

    def value32(self, address):
        return self.words[address] | self.words[address + 1] << 16


def make(store=None, **kw):
    out: list[bytes] = []
    slave = ModbusSlave(store or FakeStore(), send=out.append, **kw)
    return slave, out


def ask(slave, out, adu, t=0):
    """Feed a request at `t`, advance past the reply time, return what was sent."""
    out.clear()
    slave.feed(adu, t)
    slave.tick(t + 100 * MS)
    return list(out)


def rtu(station, pdu):
    return mb.rtu_encode(station, pdu)


# ---------------------------------------------------------------- the manual's frames

RTU_EXAMPLES = [
    (H("01 03 02 00 00 02 C5 B3"), H("01 03 04 00 B1 1F 40 A3 D4")),  # L15680-L15701
    (H("01 06 02 00 00 64 89 99"), H("01 06 02 00 00 64 89 99")),  # L15755-L15775
    (H("01 10 01 12 00 02 04 0B B8 00 00 FC EB"), H("01 10 01 12 00 02 E0 31")),  # L15838-63
]
ASCII_EXAMPLES = [
    (b":010302000002F8\r\n", b":01030400B11F40E8\r\n"),  # L15638-L15676 (LRC E8 [calc])
    (b":01060200006493\r\n", b":01060200006493\r\n"),  # L15713-L15751
    (b":011001120002040BB8000013\r\n", b":011001120002DA\r\n"),  # L15785-L15832
]


def test_rtu_examples_answered_byte_for_byte():
    slave, out = make(station=1)
    for req, rsp in RTU_EXAMPLES:
        assert ask(slave, out, req) == [rsp]


def test_ascii_examples_answered_byte_for_byte():
    slave, out = make(station=1, mode="ascii")
    for req, rsp in ASCII_EXAMPLES:
        assert ask(slave, out, req) == [rsp]


def test_lrc_and_crc_examples_are_answered():
    # LRC example: station 7FH reads 1 word at 05C4H (L15873-L15895).
    slave, out = make(station=0x7F, mode="ascii")
    assert ask(slave, out, b":7F0305C40001B4\r\n") == [
        mb.ascii_encode(0x7F, mb.read_response([0x1234]))
    ]
    # CRC example: station 1 reads 2 words at 0101H, CRC 3794H sent 94 37 (L15911-L15920).
    slave, out = make(station=1)
    assert ask(slave, out, H("01 03 01 01 00 02 94 37")) == [rtu(1, mb.read_response([0x1042, 0]))]


def test_32bit_parameter_low_word_first():
    # Example 3 writes P1.009 = 0BB8H at 0112H, 0000H at 0113H: value 3000 (L15781, L7156).
    store = FakeStore()
    slave, out = make(store, station=1)
    ask(slave, out, RTU_EXAMPLES[2][0])
    assert store.writes == [(0x0112, [0x0BB8, 0x0000])]
    assert store.value32(0x0112) == 3000


def test_station_defaults_to_p3000_low_byte():
    store = FakeStore({0x0300: 0xAB05})  # UZ reserved, YX = station (L10504)
    slave, out = make(store)
    assert slave.station == 5
    assert ask(slave, out, rtu(5, mb.read_request(0x0200, 1))) != []


# ---------------------------------------------------------------- limits and exceptions


def test_read_limit_10_words_write_limit_8_words():
    store = FakeStore({0x0400 + i: i for i in range(12)})
    slave, out = make(store, station=1)
    assert ask(slave, out, rtu(1, mb.read_request(0x0400, 10))) == [
        rtu(1, mb.read_response(list(range(10))))
    ]  # L15634: at most 10
    assert ask(slave, out, rtu(1, mb.read_request(0x0400, 11))) == [
        rtu(1, mb.exception_response(0x03, mb.ILLEGAL_DATA_VALUE))
    ]
    assert ask(slave, out, rtu(1, mb.write_multiple_request(0x0400, [7] * 8))) == [
        rtu(1, mb.write_multiple_response(0x0400, 8))
    ]  # L15781: at most 8
    assert ask(slave, out, rtu(1, mb.write_multiple_request(0x0400, [7] * 9))) == [
        rtu(1, mb.exception_response(0x10, mb.ILLEGAL_DATA_VALUE))
    ]
    assert store.words[0x0408] == 8  # the refused 9-word write changed nothing


@pytest.mark.parametrize(
    "pdu,code",
    [
        (b"\x08\x00\x00\x00\x00", mb.ILLEGAL_FUNCTION),  # only 03h/06h/10h (L15568)
        (b"\x04\x02\x00\x00\x01", mb.ILLEGAL_FUNCTION),
        (mb.read_request(0x0204, 1), mb.ILLEGAL_DATA_ADDRESS),  # unknown parameter
        (mb.write_single_request(0x0200, 5000), mb.ILLEGAL_DATA_VALUE),  # out of range
        (mb.write_single_request(0x0000, 1), mb.ILLEGAL_DATA_ADDRESS),  # read-only
        (mb.write_single_request(0x0112, 1), mb.SERVER_DEVICE_FAILURE),  # servo on
        (mb.write_single_request(0x0101, 1), mb.SERVER_DEVICE_FAILURE),  # protected
        (b"\x10\x02\x00\x00\x02\x03\x00\x00\x00", mb.ILLEGAL_DATA_VALUE),  # bad byte count
    ],
)
def test_exception_responses(pdu, code):
    store = FakeStore(read_only={0x0000}, locked={0x0112}, protected={0x0101},
                      limits={0x0200: (0, 2047)})  # fmt: skip
    seen = []
    slave, out = make(store, station=1, on_comm_error=lambda c, m: seen.append((c, m)))
    assert ask(slave, out, rtu(1, pdu)) == [rtu(1, mb.exception_response(pdu[0], code))]
    assert seen and seen[0][0] == code


def test_store_bug_answers_device_failure_not_crash():
    class Broken(FakeStore):
        def modbus_read(self, address, count):
            raise KeyError("bug")

    slave, out = make(Broken(), station=1)
    assert ask(slave, out, RTU_EXAMPLES[0][0]) == [
        rtu(1, mb.exception_response(3, mb.SERVER_DEVICE_FAILURE))
    ]


def test_exception_codes_are_an_option():
    opts = ModbusFaceOptions()
    opts.exception_codes[errors.ServoOnLocked] = mb.SERVER_DEVICE_BUSY
    slave, out = make(FakeStore(locked={0x0112}), station=1, options=opts)
    assert ask(slave, out, rtu(1, mb.write_single_request(0x0112, 1))) == [
        rtu(1, mb.exception_response(6, mb.SERVER_DEVICE_BUSY))
    ]


# ---------------------------------------------------------------- silence and addressing


def test_silence_on_bad_crc_and_foreign_station_then_recovers():
    slave, out = make(station=1)
    bad = bytearray(RTU_EXAMPLES[0][0])
    bad[-1] ^= 0xFF
    assert ask(slave, out, bytes(bad)) == []
    assert slave.stats["bad_check"] == 1
    assert ask(slave, out, rtu(2, mb.read_request(0x0200, 2)), t=S) == []
    assert slave.stats["foreign"] == 1
    assert ask(slave, out, RTU_EXAMPLES[0][0], t=2 * S) == [RTU_EXAMPLES[0][1]]


def test_silence_on_bad_lrc_and_foreign_station_ascii():
    slave, out = make(station=1, mode="ascii")
    assert ask(slave, out, b":010302000002F9\r\n") == []
    assert ask(slave, out, b":7F0305C40001B4\r\n") == []
    assert ask(slave, out, b":01030200000G02F8\r\n") == []  # non-hex
    assert ask(slave, out, b"xx:01:010302000002F8\r\n") == [ASCII_EXAMPLES[0][1]]


def test_broadcast_executes_writes_without_reply():
    store = FakeStore()
    slave, out = make(store, station=1)
    assert ask(slave, out, rtu(0, mb.write_single_request(0x0200, 0x0064))) == []
    assert store.words[0x0200] == 0x0064
    assert ask(slave, out, rtu(0, mb.read_request(0x0200, 1)), t=S) == []
    assert ask(slave, out, rtu(0, mb.write_single_request(0x0200, 9999)), t=2 * S) == []
    store = FakeStore()
    slave, out = make(store, station=1, options=ModbusFaceOptions(broadcast="ignore"))
    assert ask(slave, out, rtu(0, mb.write_single_request(0x0200, 0x0064))) == []
    assert store.words[0x0200] == 0x00B1


def test_auto_reply_station_ff():
    # L10507: station 0xFF is accepted and answered whatever P3.000 is.
    slave, out = make(station=1)
    assert ask(slave, out, rtu(0xFF, mb.read_request(0x0200, 2))) == [RTU_EXAMPLES[0][1]]
    slave, out = make(station=1, options=ModbusFaceOptions(auto_reply_station="echo"))
    assert ask(slave, out, rtu(0xFF, mb.read_request(0x0200, 2))) == [
        rtu(0xFF, mb.read_response([0xB1, 0x1F40]))
    ]


# ---------------------------------------------------------------- framing and timing


def test_reply_waits_t35_after_last_byte():
    slave, out = make(station=1)
    slave.feed(RTU_EXAMPLES[0][0], 0)
    assert slave.tick(T35_38400 - 1) == [] and out == []
    assert slave.next_deadline() == T35_38400
    assert slave.tick(T35_38400) == [RTU_EXAMPLES[0][1]]


def test_reply_waits_35_chars_at_9600():
    store = FakeStore({0x0302: 0x0201})  # X = 1: 9600 (L10526)
    slave, _out = make(store, station=1)
    char = mb.char_time_ns(9600, 11)
    t = 0
    for byte in RTU_EXAMPLES[0][0]:  # byte by byte, back to back on the wire
        t += char
        slave.feed(bytes([byte]), t)
    t35 = mb.silent_intervals_ns(9600, 11)[1]
    assert slave.tick(t + t35 - 1) == []
    assert slave.tick(t + t35) == [RTU_EXAMPLES[0][1]]


def test_manual_10ms_silence_option():
    slave, _out = make(station=1, options=ModbusFaceOptions(silence="manual"))
    slave.feed(RTU_EXAMPLES[0][0], 0)
    assert slave.tick(10 * MS - 1) == []
    assert slave.tick(10 * MS) == [RTU_EXAMPLES[0][1]]  # L15703


@pytest.mark.parametrize("p3007,unit,delay", [(10, None, 5 * MS), (10, 1_000_000, 10 * MS)])
def test_p3007_response_delay(p3007, unit, delay):
    # P3.007 unit 0.5 ms (L10612) by default; 1 ms (L7020) as an option.
    opts = ModbusFaceOptions() if unit is None else ModbusFaceOptions(p3007_unit_ns=unit)
    slave, _out = make(FakeStore({0x030E: p3007}), station=1, options=opts)
    slave.feed(RTU_EXAMPLES[0][0], 0)
    assert slave.tick(T35_38400 + delay - 1) == []
    assert slave.tick(T35_38400 + delay) == [RTU_EXAMPLES[0][1]]


def test_gap_longer_than_t35_splits_frame():
    slave, out = make(station=1)
    req = RTU_EXAMPLES[0][0]
    slave.feed(req[:4], 0)
    slave.feed(req[4:], 5 * MS + 4 * CHAR)  # 5 ms silence > t3.5: two invalid fragments
    slave.tick(50 * MS)
    assert out == [] and slave.stats["bad_check"] == 2
    slave.feed(req[:4], S)
    slave.feed(req[4:], S + 1 * MS + 4 * CHAR)  # 1 ms < t3.5 (1.75 ms): one frame
    slave.tick(S + 50 * MS)
    assert out == [RTU_EXAMPLES[0][1]]


def test_t15_enforced_as_option():
    req = RTU_EXAMPLES[0][0]
    for enforce, expect in ((False, 1), (True, 0)):
        slave, out = make(station=1, options=ModbusFaceOptions(enforce_t15=enforce))
        slave.feed(req[:4], 0)
        slave.feed(req[4:], 1 * MS + 4 * CHAR)  # 1 ms silence: between t1.5 and t3.5
        slave.tick(50 * MS)
        assert len(out) == expect


def test_unknown_function_ends_on_silence():
    slave, _out = make(station=1)
    slave.feed(rtu(1, b"\x2b\x0e\x01\x00"), 0)  # 2Bh read device id: not supported
    assert slave.tick(T35_38400 - 1) == []
    assert slave.tick(T35_38400) == [rtu(1, mb.exception_response(0x2B, 1))]


def test_back_to_back_requests_and_garbage_before_frame():
    slave, out = make(station=1)
    a, b = RTU_EXAMPLES[0][0], RTU_EXAMPLES[2][0]
    assert ask(slave, out, a + b) == [RTU_EXAMPLES[0][1], RTU_EXAMPLES[2][1]]
    assert ask(slave, out, b"\x00\xff\x13\x37\x99" + a, t=S) == [RTU_EXAMPLES[0][1]]
    slave, out = make(station=1, options=ModbusFaceOptions(resync=False))
    assert ask(slave, out, b"\x00\xff\x13\x37\x99" + a) == []
    assert ask(slave, out, a, t=S) == [RTU_EXAMPLES[0][1]]


def test_overlong_burst_is_dropped_then_recovers():
    slave, out = make(station=1)
    assert ask(slave, out, bytes(300)) == []
    assert slave.stats["dropped"] >= 1
    assert ask(slave, out, RTU_EXAMPLES[0][0], t=S) == [RTU_EXAMPLES[0][1]]
    slave, out = make(station=1, mode="ascii")
    assert ask(slave, out, b":" + b"0" * 600) == []
    assert ask(slave, out, ASCII_EXAMPLES[0][0], t=S) == [ASCII_EXAMPLES[0][1]]


def test_foreign_response_on_the_bus_is_ignored():
    # Another drive's reply passes by on the shared RS-485 pair.
    slave, out = make(station=1)
    assert ask(slave, out, rtu(2, mb.read_response([1, 2, 3]))) == []
    assert ask(slave, out, rtu(2, mb.exception_response(3, 2)), t=S) == []


# ---------------------------------------------------------------- P3.004 timeout


def test_p3004_timeout_calls_on_timeout_once_and_rearms():
    fired = []
    store = FakeStore({0x0308: 2})  # 2 s (L10571-L10578)
    slave, out = make(store, station=1, on_timeout=fired.append)
    slave.tick(0)
    assert ask(slave, out, RTU_EXAMPLES[0][0], t=1 * S) != []
    slave.tick(3 * S - 1)
    assert fired == []
    assert slave.next_deadline() == 3 * S
    slave.tick(3 * S)
    assert fired == [3 * S]
    slave.tick(10 * S)
    assert fired == [3 * S]  # once
    ask(slave, out, rtu(2, mb.read_request(0x0200, 1)), t=11 * S)  # foreign: no re-arm
    assert fired == [3 * S]
    ask(slave, out, RTU_EXAMPLES[0][0], t=12 * S)
    slave.tick(14 * S)
    assert fired == [3 * S, 14 * S]


def test_p3004_zero_is_off_and_enabling_starts_now():
    fired = []
    store = FakeStore()
    slave, _out = make(store, station=1, on_timeout=fired.append)
    slave.tick(100 * S)
    assert fired == []
    store.words[0x0308] = 1  # "non-zero enables the timeout at once" (L10578)
    slave.tick(200 * S)
    slave.tick(201 * S - 1)
    assert fired == []
    slave.tick(201 * S)
    assert fired == [201 * S]


# ---------------------------------------------------------------- comm settings changes


def test_p3002_protocol_change_applies_from_next_frame():
    # L16037: after a new P3.002 is written, the next frame uses the new protocol.
    store = FakeStore()
    changes = []
    slave, out = make(store, station=1, on_line_settings=changes.append)
    write = rtu(1, mb.write_single_request(0x0304, 1))  # 1 = ASCII 7,E,1
    assert ask(slave, out, write) == [write]  # the reply still in RTU
    assert slave.mode == "ascii" and slave.line.char_format == mb.CharFormat(7, "E", 1)
    assert changes and changes[-1].mode == "ascii"
    assert ask(slave, out, RTU_EXAMPLES[0][0], t=S) == []
    assert ask(slave, out, ASCII_EXAMPLES[0][0], t=2 * S) == [ASCII_EXAMPLES[0][1]]


def test_p3001_baud_change_applies_from_next_frame():
    # L16035: the next frame uses the new baud; digit Z (CAN) needs a power cycle (L10544).
    store = FakeStore()
    slave, out = make(store, station=1)
    assert slave.line.baud == 38400
    ask(slave, out, rtu(1, mb.write_single_request(0x0302, 0x0201)))
    assert slave.line.baud == 9600


def test_p3000_station_change_needs_power_cycle():
    # P3.000 is ● (L7014, L6722): the new station answers only after a power cycle.
    store = FakeStore()
    slave, out = make(store)
    assert ask(slave, out, rtu(1, mb.write_single_request(0x0300, 5))) != []
    assert ask(slave, out, rtu(5, mb.read_request(0x0200, 1)), t=S) == []
    assert ask(slave, out, rtu(1, mb.read_request(0x0200, 1)), t=2 * S) != []
    slave.power_cycle()
    assert ask(slave, out, rtu(5, mb.read_request(0x0200, 1)), t=3 * S) != []
    assert ask(slave, out, rtu(1, mb.read_request(0x0200, 1)), t=4 * S) == []


def test_bad_station_argument():
    with pytest.raises(ValueError, match=r"P3\.000"):
        ModbusSlave(FakeStore(), station=0xFF)


# ---------------------------------------------------------------- fuzz


@pytest.mark.parametrize("mode", ["rtu", "ascii"])
def test_fuzz_random_bytes_never_raise(mode):
    rng = random.Random(20240611)
    store = FakeStore({0x0400 + i: 0 for i in range(16)})
    slave, out = make(store, station=1, mode=mode)
    valid = [r for r, _ in (RTU_EXAMPLES if mode == "rtu" else ASCII_EXAMPLES)]
    t = 0
    for _ in range(2000):
        kind = rng.random()
        if kind < 0.2:
            data = rng.choice(valid)
        elif kind < 0.4:  # a well-framed request with random content
            body = bytes(rng.randrange(256) for _ in range(rng.randrange(1, 20)))
            data = mb.encode_adu(rng.choice([0, 1, 2, 0xFF]), body, mode)
        elif kind < 0.5:  # truncated / corrupted valid frame
            data = bytearray(rng.choice(valid))
            data[rng.randrange(len(data))] ^= 1 << rng.randrange(8)
            data = bytes(data[: rng.randrange(1, len(data) + 1)])
        else:
            alphabet = b":\r\n0123456789ABCDEF" if mode == "ascii" and rng.random() < 0.5 else None
            n = rng.randrange(1, 60)
            data = bytes(rng.choice(alphabet) if alphabet else rng.randrange(256) for _ in range(n))
        t += rng.choice([0, 10_000, 500_000, 2 * MS, 20 * MS])
        slave.feed(data, t)
        if rng.random() < 0.3:
            t += rng.randrange(5 * MS)
            slave.tick(t)
    slave.tick(t + S)
    assert slave.stats["replies"] > 0
    # a valid request after all that garbage is answered
    out.clear()
    slave.feed(valid[0], t + 2 * S)
    slave.tick(t + 3 * S)
    assert len(out) == 1 and mb.decode_adu(out[0], mode)[0] == 1


# ---------------------------------------------------------------- the line against the UART


def test_a_line_the_uart_is_not_set_for_gets_no_answer():
    """The drive's UART runs at P3.001 X and P3.002 (L10509-L10557); a request sent on a line
    of another baud, data bits or parity is garbled there and never answered. The stop bits
    aside (a receiver checks the first only): an 8N1 sender is read at 8N2."""
    req, reply = RTU_EXAMPLES[0]
    for wire, answered in [((38400, mb.CharFormat(8, "N", 2)), True),
                           ((38400, mb.CharFormat(8, "N", 1)), True),
                           ((9600, mb.CharFormat(8, "N", 2)), False),
                           ((38400, mb.CharFormat(8, "E", 1)), False),
                           ((38400, mb.CharFormat(7, "N", 2)), False)]:
        slave, out = make(station=1, wire=wire)  # P3.001 = 0x0203, P3.002 = 6: 38400 8N2
        got = ask(slave, out, req)
        assert got == ([reply] if answered else []), wire
        if not answered:
            assert slave.stats["dropped"] == 1 and "every character garbled" in slave.errors[-1]


def test_a_new_p3001_or_p3002_leaves_the_line_from_the_next_frame():
    """A write of P3.001 (9600) or P3.002 (8E1 RTU) is answered in the old settings, and the
    next request on the unchanged line (38400 8N2) is not (L16035, L16037)."""
    wire = (38400, mb.CharFormat(8, "N", 2))
    for address, value in [(0x0302, 0x0201), (0x0304, 7)]:
        slave, out = make(FakeStore(), station=1, wire=wire)
        write = rtu(1, mb.write_single_request(address, value))
        assert ask(slave, out, write) == [write]
        assert ask(slave, out, RTU_EXAMPLES[0][0], t=S) == []
        assert "every character garbled" in slave.errors[-1]
