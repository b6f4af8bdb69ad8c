"""The CiA 402 driver's SDO transfers against a server that answers late, for another object,
or without end (an outside review found canopen's client taking a late acknowledgement of an
earlier write as success, and reading an endless segmented upload for ever). CiA 301
§7.2.4.3: an initiate answer and an abort carry the transfer's index and sub-index."""

from __future__ import annotations

import canopen
import pytest

from hil.drivers.cia402 import Cia402Driver, SdoError
from hil.drivers.sdo_transfer import MAX_UPLOAD
from tests.drivers.test_sdo_malformed_answers import NODE, RawSdoServer


def _ack(req: bytes) -> bytes:
    return bytes([0x60]) + req[1:4] + bytes(4)


def _abort(mux: bytes, code: int) -> bytes:
    return bytes([0x80]) + mux + code.to_bytes(4, "little")


class Seen:
    def __init__(self) -> None:
        self.requests: list[bytes] = []


def _driver(respond, seen: Seen | None = None):
    def log(req: bytes) -> list[bytes]:
        if seen is not None:
            seen.requests.append(req)
        return respond(req)

    srv = RawSdoServer(log)
    net = canopen.Network()
    net.connect(interface="virtual", channel=srv.channel)
    drv = Cia402Driver(net, NODE, timeouts={"sdo": 0.2, "state": 0.3})
    return srv, net, drv


def _close(srv, net) -> None:
    net.disconnect()
    srv.close()


def test_a_late_ack_of_an_earlier_write_is_not_this_writes_answer():
    """The server acknowledges the first write (6060h) only after the client timed out, just
    ahead of its answer to the next write (607Ah): the late 6060h ack is not taken for 607Ah;
    when 607Ah is never acknowledged the write fails."""
    state = {"first": None}

    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x80:
            return []  # the client's abort after its timeout
        if state["first"] is None:
            state["first"] = req
            return []  # silent: the client times out
        return [_ack(state["first"])]  # only the late ack of 6060h, never 607Ah's

    srv, net, drv = _driver(respond)
    try:
        with pytest.raises(SdoError, match="6060h sub 0: no answer"):
            drv.write(0x6060, 0, 1)
        with pytest.raises(SdoError, match="607Ah sub 0: no answer"):
            drv.write(0x607A, 0, 1000)
    finally:
        _close(srv, net)


def test_a_late_ack_ahead_of_the_real_one_is_dropped():
    state = {"first": None}

    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x80:
            return []
        if state["first"] is None:
            state["first"] = req
            return []
        return [_ack(state["first"]), _ack(req)]

    srv, net, drv = _driver(respond)
    try:
        with pytest.raises(SdoError):
            drv.write(0x6060, 0, 1)
        drv.write(0x607A, 0, 1000)  # its own ack, behind the late one
    finally:
        _close(srv, net)


def test_an_abort_for_another_object_is_not_this_objects_abort():
    """An abort naming 6060h while 6041h is read is dropped; 6041h's own answer is taken. An
    abort naming 6041h (or no object, 0000h sub 0) is 6041h's abort."""
    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x40 and req[1:3] == (0x6041).to_bytes(2, "little"):
            return [_abort(b"\x60\x60\x00", 0x06020000),
                    bytes([0x4B]) + req[1:4] + (0x0237).to_bytes(4, "little")]
        if req[0] == 0x40:
            return [_abort(req[1:4], 0x06090011)]
        return [_abort(b"\x00\x00\x00", 0x08000022)]

    srv, net, drv = _driver(respond)
    try:
        assert drv.read(0x6041) == 0x0237
        with pytest.raises(SdoError, match=r"6061h sub 0: abort 0x06090011"):
            drv.read(0x6061)
        with pytest.raises(SdoError, match=r"6060h sub 0: abort 0x08000022"):
            drv.write(0x6060, 0, 1)
    finally:
        _close(srv, net)


def test_an_endless_segmented_upload_is_ended_with_an_abort():
    """The server opens a segmented upload of unstated size and never sets the last-segment
    bit: the driver stops past MAX_UPLOAD bytes with abort 0504 0005h (out of memory) and an
    SdoError, and works afterwards."""
    toggle = {"t": 0}

    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x40 and req[1:3] == (0x1008).to_bytes(2, "little"):
            toggle["t"] = 0
            return [bytes([0x40]) + req[1:4] + bytes(4)]  # segmented, no size
        if req[0] & 0xE0 == 0x60:  # upload segment request
            t = req[0] & 0x10
            return [bytes([t]) + b"ABCDEFG"]  # 7 bytes, never the last
        if req[0] == 0x40:
            return [bytes([0x4B]) + req[1:4] + (0x0250).to_bytes(4, "little")]
        return []

    seen = Seen()
    srv, net, drv = _driver(respond, seen)
    try:
        with pytest.raises(SdoError, match=rf"1008h sub 0: malformed answer .*{MAX_UPLOAD}"):
            drv.read(0x1008)
        segments = [r for r in seen.requests if r[0] & 0xE0 == 0x60]
        assert MAX_UPLOAD // 7 <= len(segments) <= MAX_UPLOAD // 7 + 2
        assert [r[0] & 0x10 for r in segments[:4]] == [0x00, 0x10, 0x00, 0x10]
        assert drv.read(0x6041) == 0x0250  # the server has seen the abort by now
        assert any(r[0] == 0x80 and r[4:8] == (0x05040005).to_bytes(4, "little")
                   for r in seen.requests)
    finally:
        _close(srv, net)


def test_a_segmented_upload_is_read_whole_and_a_declared_size_too_big_is_refused():
    text = b"ASDA-A3 servo drive"

    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x40 and req[1:3] == (0x1008).to_bytes(2, "little"):
            return [bytes([0x41]) + req[1:4] + len(text).to_bytes(4, "little")]
        if req[0] == 0x40 and req[1:3] == (0x1009).to_bytes(2, "little"):
            return [bytes([0x41]) + req[1:4] + (MAX_UPLOAD + 1).to_bytes(4, "little")]
        if req[0] & 0xE0 == 0x60:
            respond.pos = getattr(respond, "pos", 0)
            chunk = text[respond.pos:respond.pos + 7]
            respond.pos += 7
            last = 0x01 if respond.pos >= len(text) else 0
            return [bytes([(req[0] & 0x10) | ((7 - len(chunk)) << 1) | last])
                    + chunk.ljust(7, b"\0")]
        return []

    srv, net, drv = _driver(respond)
    try:
        assert drv.read(0x1008) == int.from_bytes(text, "little")  # not in the EDS: raw
        with pytest.raises(SdoError, match=r"1009h sub 0: malformed answer .*above"):
            drv.read(0x1009)
    finally:
        _close(srv, net)


def test_a_late_download_ack_of_the_same_object_while_uploading_is_dropped():
    """An outside review: a late `60h` ack for 6040h arriving while 6040h is uploaded raised
    a malformed answer; it is of another transfer and is dropped. A `61h` ack (the x bits
    set) is a download's answer, as canopen takes it."""
    def respond(req: bytes) -> list[bytes]:
        if req[0] == 0x40:
            return [_ack(req), bytes([0x4B]) + req[1:4] + (0x000F).to_bytes(4, "little")]
        if req[0] == 0x80:
            return []
        return [bytes([0x61]) + req[1:4] + bytes(4)]

    srv, net, drv = _driver(respond)
    try:
        assert drv.read(0x6040) == 0x000F
        drv.write(0x6040, 0, 0x0F)
    finally:
        _close(srv, net)
