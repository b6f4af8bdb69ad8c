"""hil.protocol.modbus against the manual's own frames (ch. 9, L15632-L15946)."""

from __future__ import annotations

import random

import pytest

from hil.protocol import modbus as mb

H = bytes.fromhex

# (request, response) pairs printed in chapter 9; ASCII LRC E8 of example 1's reply is
# recomputed (the print at L15667-L15674 lost characters), example 3's request regains the
# '0' lost at L15802-L15808 (spec/a3-comms.md §1.6).
RTU_EXAMPLES = [
    (H("01 03 02 00 00 02 C5 B3"), H("01 03 04 00 B1 1F 40 A3 D4")),  # L15680-L15701
    (H("01 06 02 00 00 64 89 99"), H("01 06 02 00 00 64 89 99")),  # L15755-L15775
    (H("01 10 01 12 00 02 04 0B B8 00 00 FC EB"), H("01 10 01 12 00 02 E0 31")),  # L15838-63
]
ASCII_EXAMPLES = [
    (b":010302000002F8\r\n", b":01030400B11F40E8\r\n"),  # L15638-L15676, L15971
    (b":01060200006493\r\n", b":01060200006493\r\n"),  # L15713-L15751
    (b":011001120002040BB8000013\r\n", b":011001120002DA\r\n"),  # L15785-L15832
]


def test_crc_example_3794h_sent_low_byte_first():
    # L15911-L15920: CRC of 01 03 01 01 00 02 is 3794H, sent as 94H then 37H.
    assert mb.crc16(H("01 03 01 01 00 02")) == 0x3794
    assert mb.rtu_encode(1, mb.read_request(0x0101, 2)) == H("01 03 01 01 00 02 94 37")


def test_lrc_example_b4h():
    # L15891-L15895: 7F+03+05+C4+00+01 = 14CH, drop carry 4CH, two's complement B4H.
    assert mb.lrc(H("7F 03 05 C4 00 01")) == 0xB4
    assert mb.ascii_encode(0x7F, mb.read_request(0x05C4, 1)) == b":7F0305C40001B4\r\n"


def test_rtu_examples_encode_byte_for_byte():
    (r1, a1), (r2, a2), (r3, a3) = RTU_EXAMPLES
    assert mb.rtu_encode(1, mb.read_request(0x0200, 2)) == r1
    assert mb.rtu_encode(1, mb.read_response([0x00B1, 0x1F40])) == a1
    assert mb.rtu_encode(1, mb.write_single_request(0x0200, 0x0064)) == r2 == a2
    assert mb.rtu_encode(1, mb.write_multiple_request(0x0112, [0x0BB8, 0x0000])) == r3
    assert mb.rtu_encode(1, mb.write_multiple_response(0x0112, 2)) == a3


def test_ascii_examples_encode_byte_for_byte():
    (r1, a1), (r2, a2), (r3, a3) = ASCII_EXAMPLES
    assert mb.ascii_encode(1, mb.read_request(0x0200, 2)) == r1
    assert mb.ascii_encode(1, mb.read_response([0x00B1, 0x1F40])) == a1
    assert mb.ascii_encode(1, mb.write_single_request(0x0200, 0x0064)) == r2 == a2
    assert mb.ascii_encode(1, mb.write_multiple_request(0x0112, [0x0BB8, 0])) == r3
    assert mb.ascii_encode(1, mb.write_multiple_response(0x0112, 2)) == a3


@pytest.mark.parametrize("mode,pairs", [("rtu", RTU_EXAMPLES), ("ascii", ASCII_EXAMPLES)])
def test_decode_examples(mode, pairs):
    for req, rsp in pairs:
        st, pdu = mb.decode_adu(req, mode)
        assert st == 1
        assert mb.decode_request(pdu).encode() == pdu
        st, pdu = mb.decode_adu(rsp, mode)
        assert mb.decode_response(pdu).exception is None
    _, pdu = mb.decode_adu(pairs[0][1], mode)
    assert mb.decode_response(pdu).values == (0x00B1, 0x1F40)


def test_bad_checks_and_framing_raise_frame_error():
    with pytest.raises(mb.FrameError, match="CRC"):
        mb.rtu_decode(H("01 03 02 00 00 02 C5 B4"))
    with pytest.raises(mb.FrameError, match="LRC"):
        mb.ascii_decode(b":010302000002F9\r\n")
    with pytest.raises(mb.FrameError, match="':'"):
        mb.ascii_decode(b"010302000002F8\r\n")
    with pytest.raises(mb.FrameError, match="shorter"):
        mb.rtu_decode(b"\x01\x03")


def test_request_limits_10_read_8_write():
    assert mb.decode_request(mb.read_request(0x0200, 10)).count == 10
    with pytest.raises(mb.PduError) as e:
        mb.decode_request(mb.read_request(0x0200, 11))  # > 10 words, L15634
    assert e.value.code == mb.ILLEGAL_DATA_VALUE
    assert mb.decode_request(mb.write_multiple_request(0x0200, [0] * 8)).count == 8
    with pytest.raises(mb.PduError) as e:
        mb.decode_request(mb.write_multiple_request(0x0200, [0] * 9))  # > 8 words, L15781
    assert e.value.code == mb.ILLEGAL_DATA_VALUE
    with pytest.raises(mb.PduError) as e:
        mb.decode_request(b"\x08\x00\x00\x00\x00")
    assert e.value.code == mb.ILLEGAL_FUNCTION
    with pytest.raises(mb.PduError) as e:
        mb.decode_request(b"\x03\xff\xff\x00\x02")
    assert e.value.code == mb.ILLEGAL_DATA_ADDRESS


def test_p3002_and_p3001_tables():
    # L10553-L10557, L10524-L10527
    assert mb.protocol_from_p3002(6) == ("rtu", mb.CharFormat(8, "N", 2))
    assert mb.protocol_from_p3002(0) == ("ascii", mb.CharFormat(7, "N", 2))
    assert mb.protocol_from_p3002(1)[1].bits == 10  # 10-bit frame for 7-bit chars, L15589
    assert mb.protocol_from_p3002(7)[1].bits == 11  # 11-bit frame for 8-bit chars, L15593
    with pytest.raises(ValueError, match=r"P3\.002"):
        mb.protocol_from_p3002(9)
    assert mb.baud_from_p3001(0x0203) == 38400  # default 0x0203, L10510
    assert mb.baud_from_p3001(0x0005) == 115200
    with pytest.raises(ValueError, match="digit X"):
        mb.baud_from_p3001(0x0006)


def test_timing():
    assert mb.char_time_ns(115200, mb.CharFormat(8, "N", 2)) == 95_486
    assert mb.char_time_ns(9600, 11) == 1_145_833
    assert mb.silent_intervals_ns(9600, 11) == (1_718_750, 4_010_417)
    assert mb.silent_intervals_ns(115200) == (750_000, 1_750_000)  # fixed above 19200
    t15, t35 = mb.silent_intervals_ns(115200, fixed_above_19200=False)
    assert (t15, t35) == (143_229, 334_201)
    assert mb.MANUAL_SILENCE_NS == 10_000_000  # L15703
    assert mb.frame_time_ns(25, 115200, mb.CharFormat(8, "N", 1)) == 25 * 86_806


def test_describe_adu_examples():
    d = mb.describe_adu(RTU_EXAMPLES[2][0], "rtu")
    assert (d["kind"], d["station"], d["function"], d["address"], d["count"]) == (
        "request", 1, 0x10, 0x0112, 2)  # fmt: skip
    assert d["values"] == [0x0BB8, 0] and d["check_ok"] and d["error"] is None
    d = mb.describe_adu(RTU_EXAMPLES[0][1], "rtu")
    assert d["kind"] == "response" and d["values"] == [0xB1, 0x1F40]
    d = mb.describe_adu(ASCII_EXAMPLES[1][0], "ascii")
    assert d["kind"] == "request_or_echo" and d["values"] == [0x64]
    d = mb.describe_adu(ASCII_EXAMPLES[1][0], "ascii", direction="rx")
    assert d["kind"] == "response"
    d = mb.describe_adu(mb.rtu_encode(1, mb.exception_response(3, 2)), "rtu")
    assert d["kind"] == "exception" and d["exception_name"] == "illegal data address"


def test_describe_adu_never_raises():
    d = mb.describe_adu(H("01 03 02 00 00 02 C5 B4"), "rtu")
    assert not d["check_ok"] and "CRC" in d["error"] and d["station"] == 1
    assert mb.describe_adu(b"", "ascii")["error"]
    assert mb.describe_adu(b"\x00", "bogus")["error"]
    assert mb.describe_adu(None, "rtu")["error"]  # type: ignore[arg-type]
    rng = random.Random(7)
    for _ in range(3000):
        data = bytes(rng.randrange(256) for _ in range(rng.randrange(40)))
        if rng.random() < 0.3 and len(data) >= 2:
            data = mb.rtu_encode(data[0], data[1:])
        mb.describe_adu(data, rng.choice(["rtu", "ascii"]))
        mb.describe_adu(b":" + data.hex().encode() + b"\r\n", "ascii")
