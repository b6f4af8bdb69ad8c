"""The CiA 402 driver on a drive that answers SDOs with frames the client cannot take (an
outside review found them escaping as struct.error / ObjectDictionaryError): each is an
SdoError naming the node, the object and what was wrong, and the driver works afterwards."""

from __future__ import annotations

import itertools
import threading
import time

import can
import canopen
import pytest

from hil.drivers.cia402 import Cia402Driver, SdoError

NODE = 7
_ch = itertools.count()


class RawSdoServer:
    """Raw SDO answers on an in-process python-can virtual channel."""

    def __init__(self, responder) -> None:
        self.channel = f"sdo-malformed-{time.monotonic_ns()}-{next(_ch)}"
        self.bus = can.Bus(interface="virtual", channel=self.channel)
        self.responder = responder
        self._stop = False
        self.thread = threading.Thread(target=self._loop, daemon=True)
        self.thread.start()

    def _loop(self) -> None:
        while not self._stop:
            m = self.bus.recv(0.01)
            if m is None or m.arbitration_id != 0x600 + NODE:
                continue
            for data in self.responder(bytes(m.data)):
                self.bus.send(can.Message(arbitration_id=0x580 + NODE, data=data,
                                          is_extended_id=False))

    def close(self) -> None:
        self._stop = True
        self.thread.join()
        self.bus.shutdown()


def _normal(req: bytes) -> list[bytes]:
    if req[0] & 0xE0 == 0x40:  # upload 6041h: 0x0250 in 2 bytes
        return [bytes([0x4B]) + req[1:4] + (0x0250).to_bytes(4, "little")]
    return [bytes([0x60]) + req[1:4] + bytes(4)]


@pytest.mark.parametrize("bad", [b"", b"\x4f\x41", b"\x80\x41\x60\x00",
                                 b"\x4f\x41\x60\x00\x37\x00\x00\x00"])
def test_a_malformed_sdo_answer_is_an_sdo_error_naming_the_object(bad):
    """DLC 0, an upload answer of 2 bytes, an abort of 4 bytes, a 1-byte expedited answer
    for the UNSIGNED16 6041h."""
    first = [True]

    def respond(req: bytes) -> list[bytes]:
        if first[0]:
            first[0] = False
            return [bad]
        return _normal(req)

    srv = RawSdoServer(respond)
    net = canopen.Network()
    try:
        net.connect(interface="virtual", channel=srv.channel)
        drv = Cia402Driver(net, NODE, timeouts={"sdo": 0.2, "state": 0.3})
        with pytest.raises(SdoError, match=r"node 7: SDO upload 6041h sub 0: malformed answer"):
            drv.read(0x6041)
        assert drv.read(0x6041) == 0x0250  # usable afterwards
    finally:
        net.disconnect()
        srv.close()
