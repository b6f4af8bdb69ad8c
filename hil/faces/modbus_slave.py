"""The virtual ASDA-A3's Modbus RTU/ASCII face (manual ch. 9, L15525-L16049; P3 group).

Byte-level, clock-injected and independent of pymodbus's server (which answers unknown
stations, loses back-to-back requests and ignores timing: docs/dev/feasibility.md §4).

    slave = ModbusSlave(store, station=1, send=line.write)
    slave.feed(chunk, t_ns)   # bytes as they arrive; t_ns = arrival of the chunk's last byte
    slave.tick(t_ns)          # ends RTU frames on silence, sends due replies, P3.004 timeout

`store` is the drive's parameter store: `modbus_read(address, count) -> list[int]` and
`modbus_write(address, words)`, raising `hil.model.errors.ParamError` subclasses. The face
maps those to exception responses and decides no drive behaviour: the comm-timeout alarm
(AL020) and any comm-error alarm (AL019) are the drive's, reached through `on_timeout` and
`on_comm_error`. Every ambiguous choice is a field of `ModbusFaceOptions`, documented in
docs/manual-choices.md#modbus.

`ModbusSlaveRunner(slave, line)` pumps a line object (`read(n, timeout)`, `write(data)`)
in a thread; `FdLine(fd)` adapts a raw pty file descriptor to that interface.
"""

from __future__ import annotations

import contextlib
import logging
import os
import select
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field, fields
from typing import Any, Literal, Protocol, get_args, get_origin, get_type_hints

from hil.faces import ERRORS_KEPT
from hil.faces.last_resort import LastResort
from hil.model import errors
from hil.profile.errors import UnknownParameter
from hil.profile.params import ParamTable
from hil.protocol import modbus as mb
from hil.units import S

log = logging.getLogger(__name__)

# Parameter addresses the face itself reads (address = (group << 8) + 2 n, L6697).
P3_000 = 0x0300  # station, low byte YX (L10495-L10507); ● power cycle (L7014)
P3_001 = 0x0302  # baud, digit X = RS-485 (L10509-L10527); next frame (L16035)
P3_002 = 0x0304  # protocol 0..8 (L10546-L10557); next frame (L16037)
P3_004 = 0x0308  # comm timeout, s, 0 = off, "immediately" (L10571-L10578)
P3_007 = 0x030E  # response delay (L10610-L10617); unit 0.5 ms (L10612) ⚠ 1 ms (L7020)
# the motor parameters PM.000-PM.053 at FD00H-FD6BH (L14544-L15058), two words each
PM_ADDRESSES = range(0xFD00, 0xFD00 + 2 * 54)


class RegisterStore(Protocol):
    def modbus_read(self, address: int, count: int) -> list[int]: ...

    def modbus_write(self, address: int, words: list[int]) -> None: ...


def _default_exception_codes() -> dict[type, int]:
    return {
        errors.UnknownParameter: mb.ILLEGAL_DATA_ADDRESS,
        errors.OutOfRange: mb.ILLEGAL_DATA_VALUE,
        errors.ReadOnly: mb.ILLEGAL_DATA_ADDRESS,
        errors.ServoOnLocked: mb.SERVER_DEVICE_FAILURE,
        errors.ProtectedParameter: mb.SERVER_DEVICE_FAILURE,
        errors.UnknownFunction: mb.ILLEGAL_DATA_VALUE,  # e.g. P2.010 = 0x0007 (table 8.1)
        errors.ModelError: mb.SERVER_DEVICE_FAILURE,
    }


@dataclass
class ModbusFaceOptions:
    """Choices where the manual is silent or ambiguous (docs/manual-choices.md#modbus)."""

    # Frame-end silence and earliest reply: "t3.5" (Modbus serial spec, 1.75 ms fixed above
    # 19200 baud) or "manual" (10 ms before and after a frame, L15703).
    silence: Literal["t3.5", "manual"] = "t3.5"
    fixed_t35_above_19200: bool = True
    # Discard an RTU frame with an inter-character gap > t1.5 (std). Off: the manual does
    # not state it and host jitter on a pty exceeds 750 µs.
    enforce_t15: bool = False
    # At a burst's silence, find the valid request it ends with after leading garbage (by
    # function length and CRC). Frames glued without a silence are split by the first one's
    # length either way; bytes inside a frame are never taken for one (L15621, L15703). Off:
    # strictly one frame per silence-delimited burst.
    resync: bool = True
    # Station 0 (not in the manual): "execute" writes silently (std Modbus) or "ignore".
    broadcast: Literal["execute", "ignore"] = "execute"
    # Station in the reply to a request sent to 0xFF (L10507 says only "answers").
    auto_reply_station: Literal["own", "echo"] = "own"
    # P3.007 unit, ns: 0.5 ms (L10612) vs 1 ms (summary table L7020).
    p3007_unit_ns: int = 500_000
    # Exception code per refusal (the manual documents none); most specific class wins.
    # An exception that is no ModelError is a model bug: 04h, and `last_resort` counts it.
    exception_codes: dict[type, int] = field(default_factory=_default_exception_codes)
    max_read_words: int = mb.MAX_READ_WORDS  # L15634
    max_write_words: int = mb.MAX_WRITE_WORDS  # L15781
    # Parameters communication may not write although chapter 8 lets them be set: ch.9.4
    # excludes P5.010, P5.016 and P5.076 from "writable by communication" (L16025), while
    # P5.016's own entry says any value may be written (L11286). The comms chapter is
    # followed: a write is refused with exception 02h, as a read-only parameter's.
    comm_write_refused: frozenset[str] = frozenset({"P5.016", "P5.076"})

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> ModbusFaceOptions:
        """From a bench file's `options.extra.modbus` mapping, each choice checked by its
        field: a `Literal` one of its values, a flag true/false, a count a whole number up to
        its limit, `comm_write_refused` parameter names (`exception_codes` stays a
        Python-only field: its keys are exception classes)."""
        data = dict(data or {})
        hints = get_type_hints(cls)
        defaults = cls()
        # a 03h reply holds 125 words, a 10h request 123 (one byte counts the bytes)
        limits = {"max_read_words": 125, "max_write_words": 123}
        known = {f.name for f in fields(cls)} - {"exception_codes"}
        bad = sorted(set(data) - known)
        if bad:
            raise ValueError(f"modbus options: unknown {', '.join(map(str, bad))}; known: "
                             f"{', '.join(sorted(known))}")
        for k, v in data.items():
            default = getattr(defaults, k)
            if get_origin(hints[k]) is Literal:
                if v not in get_args(hints[k]):
                    raise ValueError(f"modbus options: {k} must be one of "
                                     f"{', '.join(get_args(hints[k]))}, not {v!r}")
            elif type(default) is bool:
                if type(v) is not bool:
                    raise ValueError(f"modbus options: {k} must be true or false, not {v!r}")
            elif type(default) is int:
                top = limits.get(k, 10**9)
                if type(v) is not int or not 0 < v <= top:
                    raise ValueError(f"modbus options: {k} must be a whole number 1-{top}, "
                                     f"not {v!r}")
            else:  # comm_write_refused
                if not isinstance(v, list | tuple) or not all(type(n) is str for n in v):
                    raise ValueError(f"modbus options: {k} must be a list of parameter "
                                     f"names, not {v!r}")
                table, names = ParamTable.load(), set()
                for n in v:
                    try:
                        names.add(table.spec(n).param)
                    except UnknownParameter as e:
                        raise ValueError(f"modbus options: {k}: {e}") from None
                data[k] = frozenset(names)
        return cls(**data)


@dataclass(frozen=True)
class LineSettings:
    mode: mb.Mode
    baud: int
    char_format: mb.CharFormat

    @property
    def char_time_ns(self) -> int:
        return mb.char_time_ns(self.baud, self.char_format)


class ModbusSlave:
    """A Delta A3 Modbus slave fed byte by byte with injected time (integer ns)."""

    def __init__(
        self,
        registers: RegisterStore,
        *,
        station: int | None = None,
        mode: mb.Mode | None = None,
        baud: int | None = None,
        char_format: mb.CharFormat | None = None,
        send: Callable[[bytes], Any] | None = None,
        on_timeout: Callable[[int], Any] | None = None,
        on_comm_error: Callable[[int, str], Any] | None = None,
        on_line_settings: Callable[[LineSettings], Any] | None = None,
        lock: Any = None,
        options: ModbusFaceOptions | None = None,
        t0: int = 0,
        wire: tuple[int, mb.CharFormat] | None = None,
    ) -> None:
        """Unset `station`/`mode`/`baud`/`char_format` come from P3.000/P3.002/P3.001 in
        `registers` (defaults 0x7F, 8N2 RTU, 38400 if unreadable: L10496, L10547, L10510).
        `lock` (e.g. `DriveHost.lock`) is held around every store access. `wire`: the line's
        own baud and character format (the bench's URL); where the drive's UART differs in
        baud, data bits or parity (P3.001 X, P3.002, L10509-L10557), every character it
        receives is garbled and no request is read (None: never)."""
        self.registers = registers
        self.options = options or ModbusFaceOptions()
        # the low-word address of each parameter communication may not write (L16025), worked
        # out once: every write request is checked against them
        table = ParamTable.load()
        self._refused_at = {table.spec(n).modbus_address: n
                            for n in self.options.comm_write_refused}
        self.send = send
        self.on_timeout = on_timeout
        self.on_comm_error = on_comm_error
        self.on_line_settings = on_line_settings
        self._lock = lock if lock is not None else contextlib.nullcontext()
        self._explicit_station = station
        self.station = self._load_station()
        self._explicit_line = (mode, baud, char_format)
        self.line = self._load_line()
        self._next_line: LineSettings | None = None
        self.wire = wire
        self._garbled = self._wire_mismatch()  # why every character is garbled (None: not)
        self._garble_noted = False
        self._reread = False  # P3.001 / P3.002 written another way (`params_written`)
        self.stats: dict[str, int] = dict.fromkeys(
            ("bytes", "frames", "replies", "exceptions", "foreign", "broadcast", "bad_check",
             "dropped", "timeouts"), 0,
        )  # fmt: skip
        self.errors: list[str] = []  # last few reasons a frame was dropped (for debugging)
        # anything no protocol rule answers (a model bug, a failing callback): counted, logged
        # once per kind, and the face keeps serving (hil.faces.last_resort)
        self.last_resort = LastResort(log, "Modbus")
        self._buf = bytearray()
        self._last_t: int | None = None
        self._broken = False
        self._in_ascii = False
        self._outbox: list[tuple[int, bytes]] = []
        self._now = t0
        self._timeout_ref = t0
        self._timeout_fired = False
        self._timeout_enabled = False

    # ------------------------------------------------------------------ config

    def _param(self, address: int) -> int | None:
        try:
            with self._lock:
                return self.registers.modbus_read(address, 1)[0] & 0xFFFF
        except Exception:
            return None

    def _load_station(self) -> int:
        if self._explicit_station is not None:
            if not 1 <= self._explicit_station <= 0x7F:
                raise ValueError(f"station {self._explicit_station}: P3.000 is 1..127 (L10497)")
            return self._explicit_station
        value = self._param(P3_000)
        return (value & 0xFF) if value else 0x7F  # only the low byte YX (L10504)

    def _load_line(self) -> LineSettings:
        """The line P3.002 (protocol) and P3.001 digit X (baud) set, where the face was not
        given them explicitly."""
        mode, baud, char_format = self._explicit_line
        p3002 = self._param(P3_002)
        st_mode, st_fmt = mb.P3002_PROTOCOLS.get(p3002 if p3002 is not None else 6, ("rtu", None))
        p3001 = self._param(P3_001)
        st_baud = mb.P3001_BAUD.get((p3001 if p3001 is not None else 3) & 0xF, 38400)
        return LineSettings(mode or st_mode, baud or st_baud,
                            char_format or st_fmt or mb.CharFormat())

    def _wire_mismatch(self) -> str | None:
        """Why the UART cannot read the line (None: it can; `mb.uart_mismatch`)."""
        if self.wire is None:
            return None
        why = mb.uart_mismatch(*self.wire, self.line.baud, self.line.char_format)
        return None if why is None else (f"{why} (P3.001 X / P3.002, L10509-L10557): every "
                                         "character garbled")

    def power_cycle(self) -> None:
        """Re-read P3.000 (● takes effect after a power cycle, L7014, L6722) and the line
        P3.001/P3.002 set, however they were written (an SDO, say), and reset the receiver.
        An explicit `station=` / `mode=` / `baud=` / `char_format=` argument keeps winning
        until the parameter takes over: a Modbus write of P3.001 / P3.002, a change of P3.000
        however it came (`station_written`)."""
        self.station = self._load_station()
        self._next_line = self._load_line()
        if self._next_line == self.line:
            self._next_line = None
        self._apply_line()
        self._buf.clear()
        self._outbox.clear()
        self._last_t = None
        self._in_ascii = False

    @property
    def mode(self) -> mb.Mode:
        return self.line.mode

    @property
    def t15_t35_ns(self) -> tuple[int, int]:
        return mb.silent_intervals_ns(
            self.line.baud,
            self.line.char_format,
            fixed_above_19200=self.options.fixed_t35_above_19200,
        )

    @property
    def silence_ns(self) -> int:
        """Silence that ends an RTU frame and precedes the reply."""
        if self.options.silence == "manual":
            return mb.MANUAL_SILENCE_NS
        return self.t15_t35_ns[1]

    def response_delay_ns(self) -> int:
        """P3.007 x unit (read at every request: no power cycle needed, L10610-L10617)."""
        value = self._param(P3_007) or 0
        return value * self.options.p3007_unit_ns

    # ------------------------------------------------------------------ input

    def feed(self, data: bytes, t_ns: int) -> None:
        """Bytes from the line; `t_ns` = arrival of the last one (earlier ones are taken to
        be back-to-back at the character time). Never raises on any byte content."""
        self._now = max(self._now, t_ns)
        n = len(data)
        if not n:
            self.tick(t_ns)
            return
        char = self.line.char_time_ns
        for i, byte in enumerate(data):
            t = t_ns - (n - 1 - i) * char
            if (self._reread or self._next_line is not None) and self.settled:
                self._take_written_line()  # written another way: from this frame on
                char = self.line.char_time_ns
            if self.line.mode == "rtu":
                self._rtu_byte(byte, t, char)
            else:
                self._ascii_byte(byte, t)
        self.stats["bytes"] += n  # after they are in hand (`settled` is read from elsewhere)
        self.tick(t_ns)

    def feed_timed(self, data: bytes, times_ns: tuple[int, ...] | list[int]) -> None:
        """Bytes with the time each character ended on the line (SerialLine.read_timed)."""
        if len(times_ns) != len(data):
            raise ValueError(f"{len(data)} bytes but {len(times_ns)} times")
        char = self.line.char_time_ns
        for byte, t in zip(data, times_ns, strict=True):
            self._now = max(self._now, t)
            if (self._reread or self._next_line is not None) and self.settled:
                self._take_written_line()  # written another way: from this frame on
                char = self.line.char_time_ns
            if self.line.mode == "rtu":
                self._rtu_byte(byte, t, char)
            else:
                self._ascii_byte(byte, t)
        self.stats["bytes"] += len(data)
        if times_ns:
            self.tick(times_ns[-1])

    @property
    def settled(self) -> bool:
        """Nothing in hand: no burst waiting for the silence that ends it, no ASCII frame
        open, no reply waiting for its P3.007 delay."""
        return not (self._in_burst or self._in_ascii or self._outbox)

    @property
    def _in_burst(self) -> bool:
        """Bytes (or a dropped, overlong burst) wait for the silence that ends them."""
        return bool(self._buf) or self._broken

    def _rtu_byte(self, byte: int, t: int, char: int) -> None:
        if self._in_burst and self._last_t is not None:
            gap = t - char - self._last_t
            if gap >= self.silence_ns:  # every frame after t3.5 of silence is judged afresh
                self._end_rtu_frame()
            elif self.options.enforce_t15 and self._buf and gap > self.t15_t35_ns[0]:
                self._broken = True
        self._last_t = t
        self._buf.append(byte)
        if self._garbled is not None:  # a character the UART misread: the burst is lost
            self._broken = True
        if len(self._buf) > mb.MAX_RTU_ADU:
            self._drop(f"RTU frame longer than {mb.MAX_RTU_ADU} bytes")
            self._broken = True  # swallow the rest until silence
            return
        if not self._broken:
            self._rtu_try_complete(t)

    def _rtu_try_complete(self, t: int) -> None:
        """Complete a request as soon as its length (by function) and CRC say so, counted
        from the burst's first byte: a frame runs from one silence to the next (L15621,
        L15628, L15703), so two frames glued without one are taken in turn, but bytes inside
        a frame are never taken for a frame of their own (another station's data may hold a
        valid request to this one)."""
        buf = self._buf
        n = len(buf)
        if n >= 8 and _request_length(buf, 0) == n and _crc_ok(bytes(buf)):
            frame = bytes(buf)
            self._buf.clear()
            self._dispatch(frame, t)

    def _resync_frame(self, buf: bytes) -> tuple[int, bytes] | None:
        """With `resync`: the longest request that ends the burst after leading garbage
        (a frame cut short before it, line noise), as (bytes skipped, frame), or None."""
        n = len(buf)
        if not self.options.resync or n < 9:
            return None
        first = max(1, n - mb.MAX_RTU_ADU)
        candidates = [n - 8] if n - 8 >= first and buf[n - 7] in (
            mb.READ_HOLDING, mb.WRITE_SINGLE) else []
        # 10h at k + 1: 9 + byte count (buf[k + 6]) bytes end the burst; found at C speed
        at = buf.find(mb.WRITE_MULTIPLE, first + 1, n - 6)
        while at >= 0:
            if 9 + buf[at + 5] == n - at + 1:
                candidates.append(at - 1)
            at = buf.find(mb.WRITE_MULTIPLE, at + 1, n - 6)
        for k in sorted(candidates):
            if _crc_ok(buf[k:]):
                return k, buf[k:]
        return None

    def _end_rtu_frame(self) -> None:
        """A silence ended the burst in the buffer: dispatch it if it is a valid frame (with
        `resync`, the valid request it ends with after leading garbage)."""
        buf = bytes(self._buf)
        t = self._now if self._last_t is None else self._last_t
        self._buf.clear()
        broken, self._broken = self._broken, False
        if broken:
            if buf:  # (an overlong burst cut at a multiple of 257 bytes leaves nothing here)
                self._drop(f"RTU burst of {len(buf)} bytes: {self._garbled}" if self._garbled
                           else f"RTU burst of {len(buf)} bytes broken (gap > t1.5 or overlong)")
            return
        if _crc_ok(buf):  # e.g. an unknown function: only the silence ends it
            self._dispatch(buf, t)
            return
        found = self._resync_frame(buf)
        if found is not None:
            k, frame = found
            self._note(f"skipped {k} bytes before a frame: {buf[:k].hex(' ')}")
            self._dispatch(frame, t)
            return
        self.stats["bad_check"] += 1
        self._note(f"RTU burst without a valid CRC: {buf[:32].hex(' ')}")

    def _ascii_byte(self, byte: int, t: int) -> None:
        if self._garbled is not None:  # a misread character: no ':' is ever seen
            if self._in_ascii or not self._garble_noted:
                self._drop(f"ASCII: {self._garbled}")
                self._garble_noted = True
            self._in_ascii = False
            return
        if byte == 0x3A:  # ':' starts a frame and restarts a broken one (L15617)
            if self._in_ascii and len(self._buf) > 1:
                self._drop(f"ASCII frame restarted by ':' after {len(self._buf)} chars")
            self._buf[:] = b":"
            self._in_ascii = True
            return
        if not self._in_ascii:
            return  # noise between frames
        self._buf.append(byte)
        if len(self._buf) > mb.MAX_ASCII_ADU:
            self._drop(f"ASCII frame longer than {mb.MAX_ASCII_ADU} chars")
            self._buf.clear()
            self._in_ascii = False
        elif byte == 0x0A and self._buf.endswith(b"\r\n"):
            adu = bytes(self._buf)
            self._buf.clear()
            self._in_ascii = False
            self._dispatch(adu, t)

    # ------------------------------------------------------------------ processing

    def _dispatch(self, adu: bytes, t_end: int) -> None:
        try:
            self._dispatch_frame(adu, t_end)
        except Exception as exc:  # last resort: the bytes of this chunk keep being read
            self.last_resort("frame", exc)

    def _dispatch_frame(self, adu: bytes, t_end: int) -> None:
        try:
            station, pdu = mb.decode_adu(adu, self.line.mode)
        except mb.FrameError as exc:
            self.stats["bad_check"] += 1
            self._note(str(exc))  # silence on a bad CRC / LRC
            return
        if station == mb.BROADCAST:
            self.stats["broadcast"] += 1
            if self.options.broadcast == "execute":
                self._touch_timeout(t_end)
                self._process(pdu, broadcast=True)
                if not self._outbox:
                    self._apply_line()
            return
        if station not in (self.station, mb.AUTO_REPLY):
            self.stats["foreign"] += 1
            return
        self.stats["frames"] += 1
        self._touch_timeout(t_end)
        reply = self._process(pdu, broadcast=False)
        if reply is None:
            return
        if station == mb.AUTO_REPLY and self.options.auto_reply_station == "echo":
            reply_station = mb.AUTO_REPLY
        else:
            reply_station = self.station
        due = t_end + self.silence_ns + self.response_delay_ns()
        if self._outbox:
            due = max(due, self._outbox[-1][0])
        self._outbox.append((due, mb.encode_adu(reply_station, reply, self.line.mode)))

    def _process(self, pdu: bytes, *, broadcast: bool) -> bytes | None:
        """Execute one request; the reply PDU (None for broadcast)."""
        fn = pdu[0] if pdu else 0
        try:
            req = mb.decode_request(
                pdu, max_read=self.options.max_read_words, max_write=self.options.max_write_words
            )
            if req.address in PM_ADDRESSES and req.address + req.count - 1 in PM_ADDRESSES:
                # the PM group exists on the drive (readable and writable by communication,
                # L16031, L16049) but is not modelled: "no parameter here" (02h), without
                # the AL019 of an address the drive has not (docs/manual-choices.md)
                return self._exception(fn, mb.ILLEGAL_DATA_ADDRESS,
                                       f"PM.{(req.address - PM_ADDRESSES.start) // 2:03d}: the "
                                       "motor parameters (PM group) are not modelled",
                                       broadcast, alarm=False)
            if req.function == mb.READ_HOLDING:
                if broadcast:
                    return None
                with self._lock:
                    values = self.registers.modbus_read(req.address, req.count)
                if len(values) != req.count:
                    raise errors.ModelError(f"store returned {len(values)} of {req.count} words")
                reply = mb.read_response([v & 0xFFFF for v in values])
            else:
                self._refuse_comm_write(req.address, req.count)
                with self._lock:
                    self.registers.modbus_write(req.address, list(req.values))
                self._after_write(req.address, req.count)
                if req.function == mb.WRITE_SINGLE:
                    reply = pdu
                else:
                    reply = mb.write_multiple_response(req.address, req.count)
        except mb.PduError as exc:
            return self._exception(fn, exc.code, str(exc), broadcast)
        except Exception as exc:  # a store refusal, or a bug: answer, never crash the face
            if not isinstance(exc, errors.ModelError):
                self.last_resort("request", exc)  # not a refusal: a model bug
            code = self._code_for(exc)
            return self._exception(fn, code, f"{type(exc).__name__}: {exc}", broadcast)
        if broadcast:
            return None
        self.stats["replies"] += 1
        return reply

    def _refuse_comm_write(self, address: int, count: int) -> None:
        """ReadOnly if the words touch a parameter ch.9.4 keeps from communication writes
        (`ModbusFaceOptions.comm_write_refused`, L16025)."""
        for low, name in self._refused_at.items():
            if address <= low + 1 and low < address + count:
                raise errors.ReadOnly(name, "not writable by communication (ch.9.4, L16025)")

    def _code_for(self, exc: Exception) -> int:
        for cls in type(exc).__mro__:
            if cls in self.options.exception_codes:
                return self.options.exception_codes[cls]
        return mb.SERVER_DEVICE_FAILURE

    def _exception(self, fn: int, code: int, message: str, broadcast: bool,
                   alarm: bool = True) -> bytes | None:
        self.stats["exceptions"] += 1
        self._note(message)
        if alarm and self.on_comm_error is not None:
            self._callback("on_comm_error", self.on_comm_error, code, message)
        return None if broadcast else mb.exception_response(fn, code)

    def station_written(self) -> None:
        """P3.000 changed, however it was written (Modbus, an SDO of 2300h, a plan): from
        now on the parameter sets the station, at the next power cycle (●, L7014), as
        P3.001/P3.002 set the line once written (helper-124: a virtual drive given its
        station by the bench kept it for ever; a write of the value it held changes
        nothing)."""
        self._explicit_station = None

    def params_written(self) -> None:
        """P3.001 / P3.002 written another way (an SDO, a test): the next frame uses them, as
        after a write over the line (L16035, L16037; P3.002 has no ● mark, and P3.001's is for
        digit Z, L10544). Only a flag here (any thread: an SDO's arrives in the CANopen face's);
        the reader's thread re-reads them at its next byte once nothing is in hand (`settled`)."""
        self._reread = True

    def _take_written_line(self) -> None:
        if self._reread:
            self._reread = False
            self._after_write(P3_001, 4)
        self._apply_line()

    def _after_write(self, address: int, count: int) -> None:
        """P3.001 / P3.002 written: the next frame uses them (L16035, L16037). (P3.000:
        `station_written`, however it was written.)"""
        if address <= P3_002 + 1 and address + count > P3_001:
            p3001, p3002 = self._param(P3_001), self._param(P3_002)
            mode, fmt = mb.P3002_PROTOCOLS.get(p3002, (self.line.mode, self.line.char_format))
            baud = mb.P3001_BAUD.get(p3001 & 0xF, self.line.baud) if p3001 is not None else None
            new = LineSettings(mode, baud or self.line.baud, fmt)
            if new != self.line:
                self._next_line = new  # applied once the reply to this write is sent
                # written over the line itself: from now on the parameters set it, also at
                # a power cycle (the line the face was built with was where it began)
                self._explicit_line = (None, None, None)

    def _apply_line(self) -> None:
        if self._next_line is not None:
            self.line, self._next_line = self._next_line, None
            self._buf.clear()
            self._in_ascii = False
            self._garbled = self._wire_mismatch()
            self._garble_noted = False
            if self.on_line_settings is not None:
                self._callback("on_line_settings", self.on_line_settings, self.line)

    # ------------------------------------------------------------------ time

    def tick(self, t_ns: int) -> list[bytes]:
        """Advance to `t_ns`: end an RTU frame after the silence, send due replies (via
        `send`), check the P3.004 timeout. Returns the ADUs sent."""
        self._now = max(self._now, t_ns)
        if (
            self.line.mode == "rtu"
            and self._in_burst
            and self._last_t is not None
            and t_ns - self._last_t >= self.silence_ns
        ):
            self._end_rtu_frame()
        sent = []
        while self._outbox and self._outbox[0][0] <= t_ns:
            _, adu = self._outbox.pop(0)
            sent.append(adu)
            if self.send is not None:
                self._callback("send", self.send, adu)
        if sent and not self._outbox:
            self._apply_line()
        self._check_timeout(t_ns)
        return sent

    def next_deadline(self) -> int | None:
        """Earliest time `tick` has something to do (ns), or None."""
        times = []
        if self._outbox:
            times.append(self._outbox[0][0])
        if self.line.mode == "rtu" and self._in_burst and self._last_t is not None:
            times.append(self._last_t + self.silence_ns)
        if self._timeout_enabled and not self._timeout_fired:
            limit = self._param(P3_004) or 0
            if limit:
                times.append(self._timeout_ref + limit * S)
        return min(times) if times else None

    def rearm_timeout(self, t: int) -> None:
        """The P3.004 timeout counts again from `t` (the drive cleared its AL020)."""
        self._touch_timeout(t)

    def _touch_timeout(self, t: int) -> None:
        self._timeout_ref = t
        self._timeout_fired = False

    def _check_timeout(self, t: int) -> None:
        """P3.004 (s): non-zero enables it at once (L10578); no valid frame for this drive
        for that long -> `on_timeout(t)` once (the drive raises AL020, L19598-L19602);
        re-armed by the next valid frame."""
        limit = self._param(P3_004) or 0
        if not limit:
            self._timeout_enabled = False
            return
        if not self._timeout_enabled:
            self._timeout_enabled = True
            self._timeout_ref = max(self._timeout_ref, t)
            self._timeout_fired = False
        if not self._timeout_fired and t - self._timeout_ref >= limit * S:
            self._timeout_fired = True
            self.stats["timeouts"] += 1
            if self.on_timeout is not None:
                self._callback("on_timeout", self.on_timeout, t)

    # ------------------------------------------------------------------ misc

    def _callback(self, name: str, fn: Callable[..., Any], *args: Any) -> None:
        """Call an owner's callback; a failing one is the owner's bug, not the line's."""
        try:
            fn(*args)
        except Exception as exc:
            self.last_resort(name, exc)

    def _drop(self, reason: str) -> None:
        self.stats["dropped"] += 1
        self._note(reason)
        self._buf.clear()

    def _note(self, reason: str) -> None:
        self.errors.append(reason)
        del self.errors[:-ERRORS_KEPT]


def _request_length(buf: bytearray, k: int) -> int | None:
    """Length of the 03h / 06h / 10h request starting at `buf[k]` (None: other function)."""
    fn = buf[k + 1]
    if fn in (mb.READ_HOLDING, mb.WRITE_SINGLE):
        return 8
    if fn == mb.WRITE_MULTIPLE:
        return 9 + buf[k + 6]
    return None


def _crc_ok(adu: bytes) -> bool:
    return len(adu) >= 4 and mb.crc16(adu[:-2]) == (adu[-2] | adu[-1] << 8)


# ---------------------------------------------------------------------- line pumping


class FdLine:
    """A raw file descriptor (e.g. a pty master) as a line: `read(n, timeout)`, `write`."""

    def __init__(self, fd: int) -> None:
        self.fd = fd

    def read(self, n: int, timeout: float | None) -> bytes:
        ready, _, _ = select.select([self.fd], [], [], timeout)
        if not ready:
            return b""
        try:
            return os.read(self.fd, n)
        except OSError:  # EIO when the other end of a pty is closed
            return b""

    def write(self, data: bytes) -> None:
        view = memoryview(data)
        while view:
            view = view[os.write(self.fd, view) :]


class ModbusSlaveRunner:
    """Pumps a line into a `ModbusSlave` in a daemon thread (wall clock `monotonic_ns`).

    The line needs `read(n, timeout) -> bytes` and `write(data)` (hil.transport's
    SerialLine, or `FdLine`). Use as a context manager or call `start()` / `stop()`.
    An exception in a step (a failing line, a face bug) is kept in `error`, counted in
    `slave.last_resort` (logged once) and the thread keeps serving.
    """

    def __init__(
        self,
        slave: ModbusSlave,
        line: Any,
        *,
        clock: Callable[[], int] = time.monotonic_ns,
        poll_s: float = 0.005,
    ) -> None:
        self.slave = slave
        self.line = line
        self.clock = clock
        self.poll_s = poll_s
        self.error: BaseException | None = None
        if slave.send is None:
            slave.send = line.write
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="modbus-slave", daemon=True)

    def start(self) -> ModbusSlaveRunner:
        self._thread.start()
        return self

    def stop(self, timeout: float = 2.0) -> None:
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout)

    def __enter__(self) -> ModbusSlaveRunner:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    def _run(self) -> None:
        timed = hasattr(self.line, "read_timed")  # hil.transport.serial_line.SerialLine
        while not self._stop.is_set():
            try:
                self._step(timed)
            except Exception as exc:  # last resort: log once, keep serving the line
                if self._stop.is_set():
                    return
                self.error = exc  # surfaced to the owner
                self.slave.last_resort("runner", exc)
                self._stop.wait(self.poll_s)  # e.g. a line that fails every read
            except BaseException as exc:  # KeyboardInterrupt / SystemExit: the thread ends
                self.error = exc
                return

    def _step(self, timed: bool) -> None:
        slave = self.slave
        now = self.clock()
        deadline = slave.next_deadline()
        wait = self.poll_s
        if deadline is not None:
            wait = min(wait, max(0.0, (deadline - now) / 1e9))
        # one byte with the wait, then whatever else is there (lines whose read(n)
        # waits for all n bytes would otherwise hold a request back)
        if timed:
            frame = self.line.read_timed(1, wait)
            if frame is not None and frame.data:
                more = self.line.read_timed(511, 0)
                data, times = frame.data, tuple(frame.times_ns)
                if more is not None:
                    data, times = data + more.data, times + tuple(more.times_ns)
                slave.feed_timed(data, times)
                return
        else:
            data = self.line.read(1, wait)
            if data:
                slave.feed(data + self.line.read(511, 0), self.clock())
                return
        slave.tick(self.clock())
