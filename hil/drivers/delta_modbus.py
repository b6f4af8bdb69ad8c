"""Harness-side Modbus master for Delta ASDA-A3 parameter access (manual ch. 9).

    with DeltaModbus("/dev/ttyUSB0", station=1, baud=38400) as drive:
        drive.write_param("P1.042", 100)
        drive.read_param("P1.042")            # -> 100

The same code drives a real RS-485 adapter and the virtual drive's pty: it needs only a
pyserial-like object (`write`, `read`, optional `reset_input_buffer`, `timeout`) or a line
with `read(n, timeout)`. It uses `hil.protocol.modbus`, not pymodbus: pymodbus's serial
client polls with a >= 1 ms sleep (docs/dev/feasibility.md §4: p50 2.4 ms on a pty), gives no
control of the inter-frame silence the A3 asks for (10 ms, L15703) and hides the raw frames the
recorder wants.

Parameter size and signedness come from `hil.profile.params.ParamTable`
(fixtures/drive/a3_parameters.csv), loaded on first use; a name not in it is an error.
32-bit values go low word first (L7156; example 3, L15781: P1.009 = 3000 as 0BB8h, 0000h).
"""

from __future__ import annotations

import inspect
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import serial

from hil import clock
from hil.profile.errors import UnknownParameter
from hil.profile.params import ParamTable
from hil.protocol import modbus as mb

# After a failed transaction its reply may still come for this many `timeout_s`: until then a
# frame followed by another within the RTU silence is taken as that late reply (_more_follows)
LATE_REPLIES = 3

_NAME_RE = re.compile(r"^\s*P([0-7M])[.\-]([0-9]{1,3})\s*\Z", re.IGNORECASE)


class ModbusError(Exception):
    """Base of the errors this driver raises."""


class ModbusExceptionError(ModbusError):
    """The drive answered with an exception response."""

    def __init__(self, function: int, address: int | None, code: int, what: str = "") -> None:
        where = f" at {address:04X}h" if address is not None else ""
        about = f" ({what})" if what else ""
        super().__init__(
            f"{mb.function_name(function)}{where}{about}: exception {code:02X}h "
            f"{mb.exception_name(code)}"
        )
        self.function = function
        self.address = address
        self.code = code
        self.meaning = mb.exception_name(code)


class ModbusTimeoutError(ModbusError, TimeoutError):
    """No (complete) reply within the timeout; names what was sent and what came back."""

    def __init__(self, sent: bytes, received: bytes, timeout_s: float, mode: str) -> None:
        shown = (lambda b: b.hex(" ")) if mode == "rtu" else (lambda b: repr(b))
        super().__init__(
            f"no complete reply within {timeout_s * 1000:.0f} ms to {shown(sent)}"
            f" (received {shown(received) if received else 'nothing'})"
        )
        self.sent = sent
        self.received = received


class UnknownParameterError(ModbusError):
    """A parameter name the A3 table does not list (its width and sign are unknown)."""


class ModbusReplyError(ModbusError):
    """A reply that is malformed (CRC/LRC, length) or does not match the request."""


@dataclass(frozen=True)
class ParamInfo:
    """What the driver needs to know about a parameter."""

    name: str
    address: int
    size: int = 16  # bits
    signed: bool = False


def param_address(name: str) -> int:
    """Modbus address of the low word: (group << 8) + 2 n, PM group = FDh (L6697, L14637)."""
    m = _NAME_RE.match(name) if isinstance(name, str) else None
    if not m:
        raise ValueError(f"{name!r}: not a parameter name (expected e.g. P1.042 or PM.004)")
    g = m.group(1).upper()
    group = 0xFD if g == "M" else int(g)
    return (group << 8) + 2 * int(m.group(2))


class DeltaModbus:
    """Modbus RTU/ASCII master for one A3 station on a serial line."""

    def __init__(
        self,
        line_or_port: Any,
        station: int = 0x7F,
        mode: mb.Mode = "rtu",
        timeout_s: float = 0.5,
        *,
        baud: int = 38400,
        char_format: mb.CharFormat | None = None,
        silence_s: float | None = None,
        param_info: Callable[[str], ParamInfo] | None = None,
        tap: Any = None,
        port_name: str = "rs485",
    ) -> None:
        """`line_or_port`: a device path (opened with pyserial at `baud`/`char_format`) or
        an open pyserial-like object. Defaults follow the drive: station 0x7F (P3.000,
        L10496), 38400 baud (P3.001 = 0x0203, L10510), 8N2 RTU (P3.002 = 6, L10547).
        `silence_s`: silence kept before every request; default the manual's 10 ms (L15703)."""
        if mode not in ("rtu", "ascii"):
            raise ValueError(f"mode {mode!r}: must be 'rtu' or 'ascii' (P3.002, L10553)")
        if not 0 <= station <= 0xFF:
            raise ValueError(f"station {station}: must be 0..255 (P3.000 1..127, 0xFF auto)")
        self.station = station
        self.mode: mb.Mode = mode
        self.timeout_s = timeout_s
        self.baud = baud
        self.char_format = char_format or (
            mb.CharFormat(8, "N", 2) if mode == "rtu" else mb.CharFormat(7, "N", 2)
        )
        self.silence_s = mb.MANUAL_SILENCE_NS / 1e9 if silence_s is None else silence_s
        self.tap = tap
        self.port_name = port_name
        self._param_info = param_info
        self._table: Any = None
        self._owns_port = isinstance(line_or_port, str)
        self.port = self._open(line_or_port) if self._owns_port else line_or_port
        self._line_style = _takes_timeout(self.port)
        self._last_io = 0.0
        self._drain_next = False  # the last transaction failed: drain before the next
        self._late_until = 0.0  # a failed request's reply may still come until then
        self._pushback = bytearray()  # bytes read ahead by _more_follows
        self.last_round_trip_s: float | None = None

    # ------------------------------------------------------------------ port

    def _open(self, path: str) -> Any:
        fmt = self.char_format
        parity = {"N": serial.PARITY_NONE, "E": serial.PARITY_EVEN, "O": serial.PARITY_ODD}
        return serial.Serial(
            path,
            baudrate=self.baud,
            bytesize=fmt.data_bits,
            parity=parity[fmt.parity],
            stopbits=fmt.stop_bits,
            timeout=self.timeout_s,
        )

    def close(self) -> None:
        if self._owns_port:
            self.port.close()

    def __enter__(self) -> DeltaModbus:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _read(self, n: int, deadline: float) -> bytes:
        if self._pushback:
            out = bytes(self._pushback[:n])
            del self._pushback[:n]
            return out
        remaining = deadline - clock.monotonic()
        if remaining <= 0:
            return b""
        if self._line_style:
            data = self.port.read(n, remaining)
        else:
            if self.port.timeout is None or self.port.timeout > remaining:
                self.port.timeout = remaining  # pyserial reconfigures the port: only shrink it
            data = self.port.read(n)
        if not data and getattr(self.port, "closed", False) is True:
            # a closed line reads nothing at once: waiting for the deadline would spin (and
            # on a virtual clock never reach it, no time passing)
            raise ModbusError(f"Modbus {self.port_name}: the line was closed while waiting "
                              "for a reply")
        return data

    def _read_exact(self, n: int, deadline: float, got: bytearray) -> bool:
        while len(got) < n:
            chunk = self._read(n - len(got), deadline)
            if not chunk and clock.monotonic() >= deadline:
                return False
            got += chunk
        return True

    def _record(self, data: bytes, direction: str) -> None:
        if self.tap is not None:
            self.tap.serial(self.port_name, data, direction, clock.time_ns(), None)

    # ------------------------------------------------------------------ transactions

    def transact(self, pdu: bytes, station: int | None = None) -> mb.Response | None:
        """Send one request PDU, return the decoded reply (None for broadcast, station 0).

        Raises ModbusExceptionError on an exception reply, ModbusTimeoutError, or
        ModbusReplyError on a bad CRC/LRC or a reply that does not match the request."""
        station = self.station if station is None else station
        adu = mb.encode_adu(station, pdu, self.mode)
        if self._drain_next:
            self._drain()
        wait = self._last_io + self.silence_s - clock.monotonic()
        if wait > 0:
            clock.sleep(wait)
        if not self._line_style and self.port.timeout != self.timeout_s:
            self.port.timeout = self.timeout_s
        reset = getattr(self.port, "reset_input_buffer", None)
        if reset is not None:
            reset()
        self._pushback.clear()
        t0 = clock.monotonic()
        sent = self.port.write(adu)
        flush = getattr(self.port, "flush", None)
        if flush is not None and not self._line_style:
            flush()
        self._record(adu, "tx")
        if station == mb.BROADCAST:
            self._last_io = clock.monotonic()
            return None
        # the reply timeout counts from the request's last character on the wire (a line
        # returns its schedule; a pyserial port was flushed above): a long request at a low
        # baud rate used its own wire time up (51 characters at 4800 baud: 106 ms)
        end_ns = getattr(sent, "t_end_ns", None)
        t_sent = max(t0, end_ns / 1e9) if isinstance(end_ns, int) else clock.monotonic()
        deadline = t_sent + self.timeout_s
        raw = self._read_frame(deadline)
        suspect = t0 < self._late_until
        last = t_sent + 2 * self.timeout_s  # late replies may stretch the wait this far
        while suspect and isinstance(raw, bytes) and self._more_follows(last, station):
            self._record(raw, "rx")  # a late reply to the failed request: not this answer
            deadline = min(last, max(deadline, clock.monotonic() + self.timeout_s))
            raw = self._read_frame(deadline)
        self._last_io = clock.monotonic()
        self.last_round_trip_s = self._last_io - t0
        if raw is None or isinstance(raw, bytearray):
            got = bytes(raw or b"")
            if got:
                self._record(got, "rx")
            self._failed()
            raise ModbusTimeoutError(adu, got, self.timeout_s, self.mode)
        self._record(raw, "rx")
        try:
            reply = self._check_reply(pdu, station, raw)
        except ModbusReplyError:
            self._failed()  # the rest of a garbled reply may still be on the line
            raise
        return reply

    def _failed(self) -> None:
        self._drain_next = True
        self._late_until = clock.monotonic() + LATE_REPLIES * self.timeout_s

    def _read_frame(self, deadline: float) -> bytes | bytearray:
        return self._read_rtu(deadline) if self.mode == "rtu" else self._read_ascii(deadline)

    def _drain(self) -> None:
        """After a failed transaction: drop what the line still carries (the rest of a garbled
        reply) until it has been quiet for the RTU silence (L15703), at most `timeout_s`, so it
        is not read as the next answer. Short, so the drive still hears the master well
        within P3.004 (a long wait here raised AL020 in fault_rs485_line)."""
        self._drain_next = False
        end = clock.monotonic() + self.timeout_s
        while True:
            now = clock.monotonic()
            if now >= end:
                return
            dropped = self._read(mb.MAX_RTU_ADU, min(end, now + self.silence_s))
            if not dropped:
                return
            self._record(dropped, "rx")
            self._last_io = clock.monotonic()

    def _more_follows(self, deadline: float, station: int) -> bool:
        """Within `LATE_REPLIES` x `timeout_s` of a failed transaction, a complete frame
        followed by more bytes within the silence that ends a frame (L15703) was a late reply
        to the failed request, with this request's answer behind it. The bytes read are put
        back for the next frame."""
        # only a frame's start counts (the station's address, ":" in ASCII): a stray byte
        # (a transceiver's glitch as it turns off) is dropped and does not make the answer
        # a late one
        start = b":" if self.mode == "ascii" else bytes([station & 0xFF])
        while True:
            nxt = self._read(1, min(deadline, clock.monotonic() + self.silence_s))
            if not nxt:
                return False
            if station == mb.AUTO_REPLY or nxt == start:
                self._pushback += nxt
                return True
            self._record(nxt, "rx")

    def _read_rtu(self, deadline: float) -> bytes | bytearray:
        got = bytearray()
        if not self._read_exact(2, deadline, got):
            return got
        if got[1] & 0x80:
            n = 5
        elif got[1] == mb.READ_HOLDING:
            if not self._read_exact(3, deadline, got):
                return got
            n = 5 + got[2]
        elif got[1] in (mb.WRITE_SINGLE, mb.WRITE_MULTIPLE):
            n = 8
        else:
            self._read_exact(mb.MAX_RTU_ADU, min(deadline, clock.monotonic() + 0.02), got)
            return bytes(got)  # unknown function: let the checks name it
        if not self._read_exact(n, deadline, got):
            return got
        return bytes(got)

    def _read_ascii(self, deadline: float) -> bytes | bytearray:
        got = bytearray()
        while True:
            chunk = self._read(1, deadline)
            if not chunk:
                if clock.monotonic() >= deadline:
                    return got
                continue
            if chunk == b":":
                got[:] = b":"
            elif got:
                got += chunk
                if got.endswith(b"\r\n"):
                    return bytes(got)
                if len(got) > mb.MAX_ASCII_ADU:
                    return got

    def _check_reply(self, pdu: bytes, station: int, raw: bytes) -> mb.Response:
        try:
            rst, rpdu = mb.decode_adu(raw, self.mode)
            rsp = mb.decode_response(rpdu)
        except mb.FrameError as exc:
            raise ModbusReplyError(f"reply {raw!r} to {mb.function_name(pdu[0])}: {exc}")
        if station != mb.AUTO_REPLY and rst != station:
            raise ModbusReplyError(f"reply from station {rst}, request was to {station}")
        if rsp.function != pdu[0]:
            raise ModbusReplyError(f"reply function {rsp.function:02X}h to a {pdu[0]:02X}h")
        if rsp.exception is not None:
            address = int.from_bytes(pdu[1:3], "big") if len(pdu) >= 3 else None
            raise ModbusExceptionError(pdu[0], address, rsp.exception)
        return rsp

    # ------------------------------------------------------------------ registers

    def read_registers(self, address: int, count: int, station: int | None = None) -> list[int]:
        """03h: `count` words from `address` (the A3 answers at most 10, L15634)."""
        rsp = self.transact(mb.read_request(address, count), station)
        assert rsp is not None
        if len(rsp.values) != count:
            raise ModbusReplyError(f"03h at {address:04X}h: asked {count}, got {rsp.count}")
        return list(rsp.values)

    def write_register(self, address: int, value: int, station: int | None = None) -> None:
        """06h: one word. The reply must echo the request (L15766-L15775)."""
        pdu = mb.write_single_request(address, value)
        rsp = self.transact(pdu, station)
        if rsp is not None and (rsp.address, rsp.values) != (address, (value,)):
            raise ModbusReplyError(f"06h at {address:04X}h: echo {rsp} does not match")

    def write_registers(
        self, address: int, values: Sequence[int], station: int | None = None
    ) -> None:
        """10h: several words (the A3 takes at most 8, L15781)."""
        rsp = self.transact(mb.write_multiple_request(address, list(values)), station)
        if rsp is not None and (rsp.address, rsp.count) != (address, len(values)):
            raise ModbusReplyError(f"10h at {address:04X}h: ack {rsp} does not match")

    # ------------------------------------------------------------------ parameters

    def param(self, name: str) -> ParamInfo:
        """Address, size and signedness of a parameter (`param_info`, else the A3 table)."""
        if self._param_info is not None:
            return self._param_info(name)
        if self._table is None:
            self._table = ParamTable.load()  # no fallback: a wrong width would corrupt values
        try:
            spec = self._table.spec(name)
        except UnknownParameter as exc:
            raise UnknownParameterError(
                f"{exc} (fixtures/drive/a3_parameters.csv); pass param_info= for others"
            ) from exc
        return ParamInfo(spec.param, spec.modbus_address, spec.size, spec.signed)

    def read_param(self, name: str) -> int:
        """Read a parameter by name: 32-bit ones as two words, low word first (L7156)."""
        info = self.param(name)
        try:
            words = self.read_registers(info.address, 2 if info.size == 32 else 1)
        except ModbusExceptionError as exc:
            raise ModbusExceptionError(exc.function, exc.address, exc.code, info.name) from exc
        raw = words[0] | (words[1] << 16 if info.size == 32 else 0)
        if info.signed and raw >> (info.size - 1):
            raw -= 1 << info.size
        return raw

    def write_param(self, name: str, value: int) -> None:
        """Write a parameter by name (06h for 16-bit, 10h low+high word for 32-bit)."""
        info = self.param(name)
        lo, hi = (-(1 << (info.size - 1)), (1 << (info.size - 1)) - 1)
        if not info.signed:
            lo, hi = 0, (1 << info.size) - 1
        if not lo <= value <= hi:
            raise ValueError(f"{info.name}: {value} does not fit {info.size}-bit ({lo}..{hi})")
        raw = value & ((1 << info.size) - 1)
        try:
            if info.size == 32:
                self.write_registers(info.address, [raw & 0xFFFF, raw >> 16])
            else:
                self.write_register(info.address, raw)
        except ModbusExceptionError as exc:
            raise ModbusExceptionError(exc.function, exc.address, exc.code, info.name) from exc


def _takes_timeout(port: Any) -> bool:
    """True for lines with `read(n, timeout)`; False for pyserial's `read(n)` + `.timeout`."""
    try:
        params = inspect.signature(port.read).parameters
    except (TypeError, ValueError, AttributeError):
        return False
    return len(params) >= 2
