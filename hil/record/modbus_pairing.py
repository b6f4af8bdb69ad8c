"""Pair Modbus RTU/ASCII requests with their responses (round-trip time, exception code).

Needs no knowledge of who is master: the first ADU is a request; an ADU in the other
direction with the same unit and function (or function | 0x80) answers it. A request that
is followed by another request first is reported as unanswered. Broadcasts (unit 0) expect
no answer.
"""

from __future__ import annotations

from dataclasses import dataclass


def crc16(data: bytes) -> int:
    """CRC-16/MODBUS (polynomial 0xA001 reflected, init 0xFFFF)."""
    crc = 0xFFFF
    for b in data:
        crc ^= b
        for _ in range(8):
            crc = (crc >> 1) ^ 0xA001 if crc & 1 else crc >> 1
    return crc


def guess_mode(data: bytes) -> str:
    """`ascii` for `:...CRLF` frames, else `rtu`."""
    return "ascii" if data[:1] == b":" and data.endswith(b"\r\n") else "rtu"


def pdu_of(data: bytes, mode: str) -> bytes:
    """Unit + PDU of an ADU (checksum verified and removed). Raises ValueError with the rule."""
    if mode == "ascii":
        if data[:1] != b":" or not data.endswith(b"\r\n"):
            raise ValueError("Modbus ASCII frame must start with ':' and end with CR LF")
        try:
            body = bytes.fromhex(data[1:-2].decode("ascii"))
        except (UnicodeDecodeError, ValueError):
            raise ValueError("Modbus ASCII frame holds non-hex characters")
        if len(body) < 3:
            raise ValueError(f"Modbus ASCII frame too short ({len(body)} bytes)")
        if (-sum(body[:-1])) & 0xFF != body[-1]:
            raise ValueError("Modbus ASCII LRC mismatch")
        return body[:-1]
    if mode != "rtu":
        raise ValueError(f"Modbus mode {mode!r}: must be 'rtu' or 'ascii'")
    if len(data) < 4:
        raise ValueError(f"Modbus RTU frame too short ({len(data)} bytes, minimum 4)")
    if crc16(data[:-2]) != int.from_bytes(data[-2:], "little"):
        raise ValueError("Modbus RTU CRC mismatch")
    return data[:-2]


@dataclass
class _Pending:
    t: int
    direction: str
    unit: int
    function: int


class ModbusPairing:
    """Stateful pairer for one port. `feed()` describes one ADU's place in a transaction."""

    def __init__(self) -> None:
        self._pending: _Pending | None = None

    def feed(self, data: bytes, mode: str, direction: str, t: int) -> tuple[dict, list[dict]]:
        """Return (fields for this ADU, records of requests left unanswered)."""
        unanswered: list[dict] = []
        try:
            pdu = pdu_of(bytes(data), mode)
        except ValueError as exc:
            return {"role": "unknown", "error": str(exc)}, unanswered
        unit, fc = pdu[0], pdu[1]
        p = self._pending
        if (
            p is not None
            and direction != p.direction
            and unit == p.unit
            and (fc & 0x7F) == p.function
        ):
            self._pending = None
            rtt = t - p.t
            info = {
                "role": "exception" if fc & 0x80 else "response",
                "unit": unit,
                "function": fc,
                "exception_code": pdu[2] if fc & 0x80 and len(pdu) > 2 else None,
                "rtt_ns": rtt,
                "rtt_us": rtt / 1000.0,
                "t_request": p.t,
            }
            return info, unanswered
        if p is not None:
            unanswered.append(self._unanswered(p))
        self._pending = _Pending(t, direction, unit, fc) if unit != 0 else None
        return {"role": "request", "unit": unit, "function": fc}, unanswered

    def pending(self) -> list[dict]:
        """Report a still-open request as unanswered (end of recording)."""
        p, self._pending = self._pending, None
        return [] if p is None else [self._unanswered(p)]

    @staticmethod
    def _unanswered(p: _Pending) -> dict:
        return {
            "role": "request",
            "unit": p.unit,
            "function": p.function,
            "unanswered": True,
            "t_request": p.t,
            "dir": p.direction,
        }


class AduAssembler:
    """Rebuild ADUs from serial chunks (a read may return part of a frame).

    RTU: chunks of one direction accumulate until the CRC checks; ASCII: until CR LF.
    A chunk from the other direction, a pause over `max_gap_ns` or 256+ bytes close an
    unfinished buffer, which is then returned as incomplete (decoded as an error).
    """

    MAX_ADU = 256  # Modbus RTU ADU limit (ASCII: 513 chars)

    def __init__(self, max_gap_ns: int = 50_000_000) -> None:
        self.max_gap_ns = max_gap_ns
        self._buf = bytearray()
        self._dir = ""
        self._t0 = 0
        self._t_last = 0

    def feed(self, data: bytes, direction: str, mode: str, t: int) -> list[tuple[bytes, str, int]]:
        """Return finished (adu, direction, t_first_chunk) in order."""
        out: list[tuple[bytes, str, int]] = []
        if self._buf and (direction != self._dir or t - self._t_last > self.max_gap_ns):
            out.append(self._take())
        if not self._buf:
            self._dir, self._t0 = direction, t
        self._buf += data
        self._t_last = t
        if mode == "ascii":
            limit = 2 * self.MAX_ADU + 3
            while b"\r\n" in self._buf:
                end = self._buf.index(b"\r\n") + 2
                out.append((bytes(self._buf[:end]), self._dir, self._t0))
                del self._buf[:end]
                self._t0 = t
        else:
            limit = self.MAX_ADU
            if len(self._buf) >= 4 and crc16(self._buf[:-2]) == int.from_bytes(
                self._buf[-2:], "little"
            ):
                out.append(self._take())
        if len(self._buf) >= limit:
            out.append(self._take())
        return out

    def pending(self) -> list[tuple[bytes, str, int]]:
        return [self._take()] if self._buf else []

    def _take(self) -> tuple[bytes, str, int]:
        adu = (bytes(self._buf), self._dir, self._t0)
        self._buf.clear()
        return adu
