"""Deterministic Modbus RTU traffic for the face fuzz tests (tests/faces/test_modbus_fuzz.py).

`units(rng, params)` yields `Unit`s: one burst of bytes the master puts on the line between
two silences of at least t3.5, and what the face must answer to it:

- `replies`: the functions of the answers it owes, in order (a valid request addressed to
  this station or to 0xFF: a normal reply or an exception response, never silence);
- `silent`: True when the protocol forbids any answer (foreign station, broadcast,
  truncated or corrupted frame, zero-filled overlong burst);
- neither (random noise): anything the face sends must still be a well-formed reply.
"""

from __future__ import annotations

import random
from collections.abc import Iterator
from dataclasses import dataclass

from hil.protocol import modbus as mb

STATION = 1
# P3.001 / P3.002 (0302H-0305H) change the line itself (baud, RTU/ASCII, L16035-L16037):
# a master that writes them must reconfigure too, so the fuzz leaves them alone.
LINE_SETTINGS = range(0x0302, 0x0306)


@dataclass(frozen=True)
class Unit:
    kind: str
    data: bytes
    frames: int  # requests (or bursts) in `data`
    replies: tuple[int, ...] = ()  # request function codes owed an answer, in order
    silent: bool = False


class Traffic:
    """Request generator over a drive's parameter table (addresses and ranges)."""

    def __init__(self, rng: random.Random, specs: list) -> None:
        self.rng = rng
        self.specs = [s for s in specs if s.modbus_address not in LINE_SETTINGS]
        self.addresses = [s.modbus_address + w for s in self.specs for w in (0, 1)]

    def address(self) -> int:
        rng = self.rng
        return rng.choice(self.addresses) if rng.random() < 0.9 else rng.randrange(0x10000)

    def write_address(self, count: int) -> int:
        """A first address for `count` words that leaves P3.001 / P3.002 alone."""
        while True:
            address = self.address()
            if address + count <= LINE_SETTINGS.start or address >= LINE_SETTINGS.stop:
                return address

    def words(self, count: int) -> list[int]:
        rng = self.rng
        if rng.random() < 0.5:  # an in-range value of a real parameter, split in words
            spec = rng.choice(self.specs)
            value = rng.randint(spec.min, spec.max) & 0xFFFFFFFF
            return [(value >> (16 * (i % 2))) & 0xFFFF for i in range(count)]
        return [rng.randrange(0x10000) for _ in range(count)]

    def request(self) -> bytes:
        """A request PDU: mostly 03h/06h/10h, some that the face must refuse."""
        rng = self.rng
        r = rng.random()
        if r < 0.35:
            return mb.read_request(self.address(), rng.randint(1, mb.MAX_READ_WORDS))
        if r < 0.65:
            return mb.write_single_request(self.write_address(1), self.words(1)[0])
        if r < 0.9:
            count = rng.randint(1, 8)
            return mb.write_multiple_request(self.write_address(count), self.words(count))
        if r < 0.94:  # a function the A3 lacks (L15568): exception 01h
            fn = rng.choice([0x01, 0x02, 0x04, 0x05, 0x0F, 0x17, 0x2B, 0x41])
            return bytes([fn]) + bytes(rng.randrange(256) for _ in range(4))
        if r < 0.97:  # 03h over 10 words (L15634) or 0: exception 03h
            return mb.read_request(self.address(), rng.choice([0, 11, 125, 0xFFFF]))
        # 10h over 8 words (L15781) or a byte count that lies
        count = rng.randint(9, 20)
        pdu = bytearray(mb.write_multiple_request(self.write_address(count), self.words(count)))
        if rng.random() < 0.5:
            pdu[5] = (pdu[5] + rng.randint(1, 9)) & 0xFF
        return bytes(pdu)

    def valid(self, station: int = STATION, *, glueable: bool = False) -> tuple[bytes, int]:
        """A request ADU and its function. `glueable`: only requests whose length the
        function and byte count give (an unknown function or a lying byte count is found
        only by the silence after it, so it cannot be split from a glued-on frame)."""
        while True:
            pdu = self.request()
            known = pdu[0] in (mb.READ_HOLDING, mb.WRITE_SINGLE) or (
                pdu[0] == mb.WRITE_MULTIPLE and pdu[5] == len(pdu) - 6
            )
            if known or not glueable:
                return mb.rtu_encode(station, pdu), pdu[0]

    def unit(self) -> Unit:
        rng = self.rng
        r = rng.random()
        if r < 0.40:
            adu, fn = self.valid(STATION if rng.random() < 0.9 else mb.AUTO_REPLY)
            return Unit("valid", adu, 1, (fn,))
        if r < 0.48:  # requests glued without a silence: found by length + CRC (resync)
            parts = [self.valid(glueable=True) for _ in range(rng.randint(2, 3))]
            return Unit("glued", b"".join(a for a, _ in parts), len(parts),
                        tuple(fn for _, fn in parts))
        if r < 0.58:
            adu, _ = self.valid(rng.choice([2, 3, 0x7F, 0xF7, 0xFE, rng.randrange(2, 0xFF)]))
            return Unit("foreign", adu, 1, silent=True)
        if r < 0.63:  # station 0: executed, never answered
            return Unit("broadcast", mb.rtu_encode(0, self.request()), 1, silent=True)
        if r < 0.73:
            adu, fn = self.valid()
            cut = adu[: rng.randrange(1, len(adu))]
            if len(cut) >= 4 and mb.crc16(cut[:-2]) == cut[-2] | cut[-1] << 8:
                # Not rare: cut one byte short, the CRC checks whenever the last data byte
                # equals the low byte of the CRC before it (1 in 256). A well-formed
                # (short) request then, and owed an answer (an exception).
                return Unit("truncated", cut, 1, (fn,))
            return Unit("truncated", cut, 1, silent=True)
        if r < 0.78:
            adu = bytearray(self.valid()[0])
            adu[rng.randrange(len(adu))] ^= 1 << rng.randrange(8)  # CRC-16 sees every 1-bit error
            return Unit("corrupted", bytes(adu), 1, silent=True)
        if r < 0.83:
            n = rng.choice([257, 514, 515, 771, rng.randint(257, 1100)])
            if rng.random() < 0.5:
                return Unit("oversized", bytes(n), 1, silent=True)
            return Unit("oversized", rng.randbytes(n), 1)
        return Unit("random", rng.randbytes(rng.randint(1, 60)), 1)


def units(rng: random.Random, specs: list, frames: int) -> Iterator[Unit]:
    """Units until `frames` frames have been generated."""
    traffic = Traffic(rng, specs)
    total = 0
    while total < frames:
        unit = traffic.unit()
        total += unit.frames
        yield unit


def check_replies(unit: Unit, sent: list[bytes]) -> str | None:
    """None if `sent` (ADUs the face sent for `unit`) is what the unit owes, else why not."""
    for adu in sent:
        try:
            station, _pdu = mb.rtu_decode(adu)
        except mb.FrameError as exc:
            return f"malformed reply {adu.hex()}: {exc}"
        if station != STATION:
            return f"reply from station {station}"
    if unit.silent and sent:
        return f"{unit.kind}: answered {[a.hex() for a in sent]}"
    if unit.replies:
        got = tuple(mb.rtu_decode(a)[1][0] & 0x7F for a in sent)
        if got != unit.replies:
            return f"{unit.kind}: owed answers to {unit.replies}, got functions {got}"
    return None
