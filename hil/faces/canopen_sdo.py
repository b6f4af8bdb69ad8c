"""The SDO server of the CANopen face: expedited and segmented transfers, aborts for every
refusal (CiA 301 §7.2.4), object access (1xxx held here, 2xxx/6xxx in the drive). A part of
`CanopenSlave`; the A3 does expedited only (L16942)."""

from __future__ import annotations

from dataclasses import dataclass, field

from hil import clock
from hil.model import errors
from hil.model.errors import ObjectError
from hil.profile.od import Entry
from hil.protocol import canopen as cop


@dataclass
class Transfer:
    """A segmented SDO transfer in progress."""

    upload: bool
    entry: Entry
    toggle: int = 0
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    started: int = 0


class SdoServer:
    """The SDO server, mixed into `CanopenSlave` (its `_values`, `_send`, `drive`, `od`)."""

    # ------------------------------------------------------------------ SDO
    def _sdo_send(self, data: bytes) -> None:
        # stamped before the answer leaves: a master that sends its next request once it has
        # the answer is never "before the answer" (AL111), however late this thread runs on
        self.comm.sdo_answered(clock.time_ns())
        self._sdo_replied = True
        self._send(self._values.get((0x1200, 2), cop.SDO_RESPONSE + self.node_id) & 0x7FF, data)

    def _sdo_abort(self, index: int, sub: int, code: int) -> None:
        self.stats["sdo_aborts"] += 1
        self._sdo_send(cop.sdo_abort(index, sub, code))

    def _abort_code(self, exc: Exception, download: bool) -> int:
        """The CiA 301 abort for an exception raised while serving an SDO request."""
        if isinstance(exc, ObjectError):
            return exc.abort_code
        if isinstance(exc, errors.ModelError):  # a refusal that names no abort code itself
            return cop.ABORT_VALUE_RANGE if download else cop.ABORT_GENERAL
        self.last_resort("SDO", exc)  # a bug: still answered, with the general abort
        return cop.ABORT_GENERAL

    def _on_sdo(self, data: bytes, now: int) -> None:
        """Serve one SDO request: every request but an abort gets an answer."""
        try:
            self._serve_sdo(data, now)
        except Exception as exc:  # last resort: no SDO goes unanswered
            self._transfer = None
            padded = data.ljust(4, b"\0")
            self._sdo_abort(padded[1] | padded[2] << 8, padded[3], self._abort_code(exc, True))

    def _serve_sdo(self, data: bytes, now: int) -> None:
        if len(data) != 8:  # CiA 301: SDO frames are 8 bytes
            padded = data.ljust(4, b"\0")
            self._transfer = None
            self._sdo_abort(padded[1] | padded[2] << 8, padded[3], cop.ABORT_COMMAND)
            return
        cs = data[0] >> 5
        index, sub = data[1] | data[2] << 8, data[3]
        if cs == cop.CCS_ABORT:
            self._transfer = None
            return
        if cs in (cop.CCS_DOWNLOAD_SEGMENT, cop.CCS_UPLOAD_SEGMENT):
            self._on_segment(cs, data, now)
            return
        self._transfer = None
        try:
            if cs == cop.CCS_INITIATE_UPLOAD:
                self._initiate_upload(index, sub, now)
            elif cs == cop.CCS_INITIATE_DOWNLOAD:
                self._initiate_download(index, sub, data, now)
            else:  # block transfers (5, 6) and 7: the A3 does expedited only (L16942)
                raise ObjectError(
                    index, sub, cop.ABORT_COMMAND, "command specifier not supported"
                )
        except Exception as exc:  # every refusal becomes an abort (CiA 301 §7.2.4.3.17)
            self._transfer = None
            code = self._abort_code(exc, cs == cop.CCS_INITIATE_DOWNLOAD)
            self._sdo_abort(index, sub, code)

    def _initiate_upload(self, index: int, sub: int, now: int) -> None:
        e = self.od.get(index, sub)
        if not e.readable:
            raise ObjectError(index, sub, cop.ABORT_WRITE_ONLY, "write-only object")
        raw = self._read_bytes(e)
        if len(raw) <= 4 and raw:
            self._sdo_send(cop.sdo_expedited_upload_response(index, sub, raw))
            return
        self._transfer = Transfer(upload=True, entry=e, data=bytearray(raw), started=now)
        size = len(raw).to_bytes(4, "little")
        self._sdo_send(bytes([0x41, index & 0xFF, index >> 8, sub]) + size)

    def _initiate_download(self, index: int, sub: int, data: bytes, now: int) -> None:
        e = self.od.get(index, sub)
        if not e.writable:
            raise ObjectError(index, sub, cop.ABORT_READ_ONLY, "read-only object")
        expedited, sized = bool(data[0] & 2), bool(data[0] & 1)
        if expedited:
            n = 4 - ((data[0] >> 2) & 3) if sized else (e.size or 4)
            self._write_bytes(e, data[4 : 4 + n])
            self._sdo_send(cop.sdo_download_response(index, sub))
            return
        size = int.from_bytes(data[4:8], "little") if sized else None
        if size is not None and e.size is not None and size != e.size:
            code = cop.ABORT_LENGTH_HIGH if size > e.size else cop.ABORT_LENGTH_LOW
            raise ObjectError(index, sub, code, f"{size} bytes for a {e.size}-byte object")
        self._transfer = Transfer(upload=False, entry=e, size=size, started=now)
        self._sdo_send(cop.sdo_download_response(index, sub))

    def _on_segment(self, cs: int, data: bytes, now: int) -> None:
        t = self._transfer
        toggle = (data[0] >> 4) & 1
        if t is None or t.upload != (cs == cop.CCS_UPLOAD_SEGMENT):
            self._transfer = None
            self._sdo_abort(0, 0, cop.ABORT_COMMAND)
            return
        e = t.entry
        if toggle != t.toggle:
            self._transfer = None
            self._sdo_abort(e.index, e.sub, cop.ABORT_TOGGLE)
            return
        t.started = now
        t.toggle ^= 1
        if t.upload:
            chunk, t.data = bytes(t.data[:7]), t.data[7:]
            last = not t.data
            n = 7 - len(chunk)
            self._sdo_send(bytes([toggle << 4 | n << 1 | int(last)]) + chunk + bytes(n))
            if last:
                self._transfer = None
            return
        n = (data[0] >> 1) & 7
        t.data += data[1 : 8 - n]
        if t.size is not None and len(t.data) > t.size:  # past the size it indicated: at
            self._transfer = None  # once, not at the last segment (CiA 301, 0607 0012h)
            self._sdo_abort(e.index, e.sub, cop.ABORT_LENGTH_HIGH)
            return
        if not data[0] & 1:
            self._sdo_send(bytes([0x20 | toggle << 4]) + bytes(7))
            return
        self._transfer = None
        try:
            if t.size is not None and len(t.data) != t.size:
                raise ObjectError(
                    e.index, e.sub, cop.ABORT_LENGTH, "size indicated != size sent"
                )
            self._write_bytes(e, bytes(t.data))
        except Exception as exc:
            self._sdo_abort(e.index, e.sub, self._abort_code(exc, True))
            return
        self._sdo_send(bytes([0x20 | toggle << 4]) + bytes(7))

    # ------------------------------------------------------------------ object access
    def read(self, index: int, sub: int) -> int | bytes:
        """Value of an object as an SDO upload sees it (call with `lock` held)."""
        e = self.od.get(index, sub)
        raw = self._read_bytes(e)
        return raw if e.size is None else e.decode(raw)

    def _read_bytes(self, e: Entry) -> bytes:
        index, sub = e.index, e.sub
        if 0x2000 <= index <= 0x2FFF or 0x6000 <= index <= 0x6FFF:
            return e.encode(int(self.drive.read_object(index, sub)))
        if index == 0x1001:
            return e.encode(self._error_register())
        if index == 0x1003:
            hist = self._history()
            if sub == 0:
                return e.encode(len(hist))
            return e.encode(hist[sub - 1] if sub <= len(hist) else 0)
        value = self._values.get((index, sub), 0)
        if e.size is None:
            return bytes(value) if not isinstance(value, int) else b""
        return e.encode(value or 0)

    def _write_bytes(self, e: Entry, raw: bytes) -> None:
        index, sub = e.index, e.sub
        if e.size is None:
            self._values[(index, sub)] = bytes(raw)
            return
        if len(raw) != e.size:
            code = cop.ABORT_LENGTH_HIGH if len(raw) > e.size else cop.ABORT_LENGTH_LOW
            raise ObjectError(index, sub, code, f"{len(raw)} bytes for a {e.size}-byte object")
        value = e.decode(raw)
        if value < 0 and e.min is not None and e.min >= 0:
            value += 1 << (8 * e.size)  # hex parameters are carried unsigned
        if e.max is not None and value > e.max:
            raise ObjectError(index, sub, cop.ABORT_VALUE_HIGH, f"{value} > max {e.max}")
        if e.min is not None and value < e.min:
            raise ObjectError(index, sub, cop.ABORT_VALUE_LOW, f"{value} < min {e.min}")
        if 0x2000 <= index <= 0x2FFF or 0x6000 <= index <= 0x6FFF:
            self.drive.write_object(index, sub, value)
            return
        self._write_comm(e, value)

    def _write_comm(self, e: Entry, value: int) -> None:
        index, sub = e.index, e.sub
        if index == 0x1003:
            if value != 0:
                raise ObjectError(index, sub, cop.ABORT_VALUE_RANGE, "only 0 clears 1003h")
            self._history_cleared = tuple(self._history())  # the drive keeps its P4.000 list
            return
        if index == 0x1016 and sub >= 1 and not (value >> 16) & 0xFF <= 0x7F:
            # bits 23..16 are a node-ID (L17742), 1..127 in CiA 301 (0: not used)
            raise ObjectError(index, sub, cop.ABORT_VALUE_RANGE,
                              f"node-ID {(value >> 16) & 0xFF} is not 1..127")
        if 0x1400 <= index <= 0x1403 or 0x1800 <= index <= 0x1803:
            self._write_pdo_comm(index, sub, value)
        elif 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
            self._write_pdo_map(index, sub, value)
        self._values[(index, sub)] = value
        self._full_path_cobs = None
        now = self.clock()
        if index == 0x1017:
            self._restart_heartbeat(now)
            if value and self._guarding_off():  # life guarding ends with a heartbeat
                self.comm.life_deadline = None
        elif index == 0x1016:
            self.comm.consumer_deadline = None
        elif index in (0x100C, 0x100D):
            self.comm.life_deadline = None
        elif index == 0x1006:
            self.comm.sync_reset()
