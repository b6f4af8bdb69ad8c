"""PDOs of the CANopen face: mapping, TPDO triggers (SYNC, change, inhibit, event timer),
RPDOs (synchronous at the next SYNC, L17051-L17057) and the rules for writing the PDO
communication and mapping objects (L17980-L18024). A part of `CanopenSlave`."""

from __future__ import annotations

from dataclasses import dataclass

from hil.model import errors
from hil.model.errors import ObjectError
from hil.protocol import canopen as cop
from hil.units import MS, US

# Harness default PDOs (option pdo_defaults="harness"); the manual ships none (L17980-L18024).
HARNESS_PDOS: dict[tuple[int, int], int] = {
    (0x1400, 2): 255,
    (0x1600, 1): 0x60400010,
    (0x1600, 2): 0x60600008,
    (0x1600, 0): 2,
    (0x1800, 2): 255,
    (0x1800, 5): 10,  # event timer 10 ms: BaseNode402 needs a cyclic statusword (feas. §3.3)
    (0x1A00, 1): 0x60410010,
    (0x1A00, 2): 0x60610008,
    (0x1A00, 0): 2,
}


# An RPDO entry the drive refuses raises its PDO alarm (table 13, L19965-L20019): AL124 data
# out of the object's range, AL125 object read-only, AL127 not writable while servo on, AL132
# a parameter whose writing is restricted now (P4.016 without P2.008 = 22, say: the SDO's
# abort 0800 0020h)
_RPDO_ALARMS = {cop.ABORT_VALUE_RANGE: "AL124", cop.ABORT_VALUE_HIGH: "AL124",
                cop.ABORT_VALUE_LOW: "AL124", cop.ABORT_READ_ONLY: "AL125",
                cop.ABORT_DATA_STATE: "AL127", cop.ABORT_DATA_STORE: "AL132"}


def restricted_cob_id(cob: int) -> bool:
    """A COB-ID no PDO may use (CiA 301 §7.3.5): NMT 000h, 001h-07Fh, 101h-180h, the SDOs
    581h-5FFh and 601h-67Fh, 6E0h-6FFh, error control 701h-77Fh, 780h-7FFh."""
    return (cob <= 0x07F or 0x101 <= cob <= 0x180 or 0x581 <= cob <= 0x5FF
            or 0x601 <= cob <= 0x67F or 0x6E0 <= cob <= 0x6FF or cob >= 0x701)


@dataclass
class PdoRun:
    """Run-time state of one PDO (configuration lives in the OD values)."""

    last_data: bytes | None = None
    last_sent: int | None = None
    sync_count: int = 0
    sampled: bytes | None = None  # a type 252 TPDO's data sampled at the last SYNC
    pending: bytes | None = None  # synchronous RPDO waiting for the next SYNC


P_SIGNED = {"INTEGER8", "INTEGER16", "INTEGER32"}


class PdoEngine:
    """The PDOs, mixed into `CanopenSlave` (its `_values`, `_pdo`, `_send`, `drive`, `od`)."""

    # ------------------------------------------------------------------ PDO
    def _mapping(self, map_index: int) -> list[tuple[int, int, int]]:
        count = self._values[(map_index, 0)]
        out = []
        for s in range(1, count + 1):
            v = self._values[(map_index, s)]
            out.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
        return out

    def _tpdo_active(self, n: int) -> bool:
        return not self._values[(0x1800 + n, 1)] & 0x80000000 and self._values[(0x1A00 + n, 0)] > 0

    def _read_mapped(self, index: int, sub: int) -> int:
        if index == 0x1001:
            return self._error_register()
        if index < 0x2000:
            v = self._values.get((index, sub), 0)
            return v if isinstance(v, int) else 0
        return int(self.drive.read_object(index, sub))

    def _tpdo_data(self, n: int) -> bytes | None:
        acc, bits = 0, 0
        for index, sub, length in self._mapping(0x1A00 + n):
            try:
                value = self._read_mapped(index, sub)
            except errors.ModelError:
                self.stats["pdo_errors"] += 1
                return None
            except Exception as exc:
                self.stats["pdo_errors"] += 1
                self.last_resort("TPDO", exc)
                return None
            acc |= (value & ((1 << length) - 1)) << bits
            bits += length
        return acc.to_bytes((bits + 7) // 8, "little")

    def _send_tpdo(
        self, n: int, now: int, *, force: bool = False, data: bytes | None = None
    ) -> None:
        if data is None:
            data = self._tpdo_data(n)
        if data is None:
            return
        run = self._pdo[4 + n]
        self._send(self._values[(0x1800 + n, 1)] & 0x7FF, data)
        run.last_data = data
        run.last_sent = now

    def _event_tpdo(self, n: int, now: int) -> None:
        run = self._pdo[4 + n]
        inhibit = self._values[(0x1800 + n, 3)] * 100 * US
        timer = self._values[(0x1800 + n, 5)] * MS
        if run.last_sent is not None and now - run.last_sent < inhibit:
            return
        data = self._tpdo_data(n)
        if data is None:
            return
        due = timer and run.last_sent is not None and now - run.last_sent >= timer
        if data != run.last_data or due:
            self._send_tpdo(n, now, data=data)

    def _on_sync(self, now: int) -> None:
        for n in range(4):  # TPDOs sample at SYNC (L17055-L17057)
            if not self._tpdo_active(n):
                continue
            tt = self._values[(0x1800 + n, 2)]
            run = self._pdo[4 + n]
            if tt == 0:
                data = self._tpdo_data(n)
                if data is not None and data != run.last_data:
                    self._send_tpdo(n, now, data=data)
            elif 1 <= tt <= 240:
                run.sync_count += 1
                if run.sync_count >= tt:
                    run.sync_count = 0
                    self._send_tpdo(n, now)
            elif tt == 252:  # synchronous, RTR only (L18075-L18083): sampled here, sent on
                run.sampled = self._tpdo_data(n)  # the next RTR (CiA 301 §7.2.2.2)
        for n in range(4):  # RPDOs of the previous cycle apply at this SYNC (L17051-L17053)
            run = self._pdo[n]
            if run.pending is not None:
                data, run.pending = run.pending, None
                self._apply_rpdo(n, data)

    def _on_rpdo(self, n: int, data: bytes) -> None:
        if self._values[(0x1600 + n, 0)] == 0:
            return
        if self._values[(0x1400 + n, 2)] <= 240:
            self._pdo[n].pending = data
        else:
            self._apply_rpdo(n, data)

    def _apply_rpdo(self, n: int, data: bytes) -> None:
        mapping = self._mapping(0x1600 + n)
        if (sum(m[2] for m in mapping) + 7) // 8 != len(data):
            # AL123 "the data length in the message does not match the objects" (L19959-
            # L19963), shorter or longer: not processed (EMCY 8210h, a3_alarms.csv)
            self.stats["pdo_errors"] += 1
            self.drive.raise_alarm("AL123")
            return
        acc, bits = int.from_bytes(data, "little"), 0
        # a parameter an RPDO writes is kept per P3.011.X (the drive's `write_pdo_object`)
        write = getattr(self.drive, "write_pdo_object", self.drive.write_object)
        for index, sub, length in mapping:
            raw = (acc >> bits) & ((1 << length) - 1)
            bits += length
            e = self.od.entries.get((index, sub))
            if e is not None and e.type in P_SIGNED and raw >= 1 << (length - 1):
                raw -= 1 << length
            try:
                write(index, sub, raw)
            except errors.ModelError as exc:  # refused: an RPDO has no answer (CiA 301) but
                self.stats["pdo_errors"] += 1  # the drive's PDO alarms (L19965-L19987)
                alarm = _RPDO_ALARMS.get(getattr(exc, "abort_code", None))
                if alarm is not None:
                    self.drive.raise_alarm(alarm)
            except Exception as exc:
                self.stats["pdo_errors"] += 1
                self.last_resort("RPDO", exc)

    def _write_pdo_comm(self, index: int, sub: int, value: int) -> None:
        rx = index < 0x1800
        old = self._values[(index, 1)]
        valid = not old & 0x80000000
        if sub == 1:
            if value & 0x20000000 or value & 0x1FFFF800:
                raise ObjectError(
                    index, sub, cop.ABORT_VALUE_RANGE, "29-bit COB-IDs unsupported"
                )
            if valid and not value & 0x80000000 and (value & 0x7FF) != (old & 0x7FF):
                raise ObjectError(
                    index, sub, cop.ABORT_VALUE_RANGE, "COB-ID change while the PDO is valid"
                )
            if not value & 0x80000000 and restricted_cob_id(value & 0x7FF):
                raise ObjectError(index, sub, cop.ABORT_VALUE_RANGE,
                                  f"COB-ID {value & 0x7FF:03X}h is restricted (CiA 301 §7.3.5)")
            n = index & 3
            self._pdo[n if rx else 4 + n] = PdoRun()
        elif sub == 2:
            if 241 <= value <= 251 or (rx and value in (252, 253)):
                raise ObjectError(
                    index, sub, cop.ABORT_VALUE_RANGE, f"transmission type {value}"
                )
            if not rx:  # a type 252 sample belongs to the type it was taken under
                self._pdo[4 + (index & 3)].sampled = None
        elif sub == 3 and valid and not rx:
            raise ObjectError(index, sub, cop.ABORT_DATA_STATE, "inhibit time while PDO valid")

    def _write_pdo_map(self, index: int, sub: int, value: int) -> None:
        rx = index < 0x1A00
        comm = (0x1400 if rx else 0x1800) + (index & 3)
        if not self._values[(comm, 1)] & 0x80000000:
            raise ObjectError(index, sub, cop.ABORT_DATA_STATE, "mapping change while PDO valid")
        if sub == 0:
            total = 0
            for s in range(1, value + 1):
                total += self._check_map_entry(index, s, self._values[(index, s)], rx)
            if total > 64:
                raise ObjectError(
                    index, sub, cop.ABORT_PDO_LENGTH, f"{total} bits > 64 (L18024)"
                )
            return
        if self._values[(index, 0)] != 0:
            raise ObjectError(index, sub, cop.ABORT_DATA_STATE, "mapping change while sub0 != 0")
        if value:
            self._check_map_entry(index, sub, value, rx)

    def _check_map_entry(self, index: int, sub: int, value: int, rx: bool) -> int:
        t_index, t_sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        try:
            target = self.od.get(t_index, t_sub)
        except ObjectError as exc:
            raise ObjectError(index, sub, cop.ABORT_NO_OBJECT, f"maps {exc}") from None
        ok = target.pdo and target.bits == bits and (target.writable if rx else target.readable)
        if not ok:
            raise ObjectError(
                index, sub, cop.ABORT_NOT_MAPPABLE,
                f"{t_index:04X}h sub {t_sub} cannot be mapped"
            )
        return bits
