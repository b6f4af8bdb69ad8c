"""NMT state and error control of the CANopen face: NMT commands, heartbeat producer,
node guarding answers, the heartbeat it watches, EMCY and the error fields (L17061-L17069,
L17806-L17838). A part of `CanopenSlave` (canopen_slave.py); what the drive does about a
lost heartbeat is `hil.model.comm_supervision`."""

from __future__ import annotations

from hil.model.events import AlarmChanged
from hil.protocol import canopen as cop
from hil.units import MS


class NmtErrorControl:
    """NMT and error control, mixed into `CanopenSlave` (its `_values`, `_send`, `drive`)."""

    def _set_state(self, state: str) -> None:
        if state == "OPERATIONAL" and self.state != "OPERATIONAL":
            for run in self._pdo.values():
                run.last_data = None
                run.last_sent = None
                run.pending = None
                run.sampled = None  # a type 252 TPDO samples again at the next SYNC
            # SYNC supervision starts anew: the SYNCs outside OPERATIONAL were not watched, so
            # the last one seen before is no measure of the period (no stale AL3E3 / AL301)
            self.comm.sync_reset()
        was = self.state
        self.state = state
        if was == "STOPPED" and state in ("PRE-OPERATIONAL", "OPERATIONAL"):
            self._catch_up()

    def _on_nmt(self, data: bytes) -> None:
        if len(data) != 2 or data[1] not in (0, self.node_id):
            return
        cs = data[0]
        if cs == cop.NMT_START:
            self._set_state("OPERATIONAL")
        elif cs == cop.NMT_STOP:
            self._set_state("STOPPED")
            if self.on_nmt_stop is not None:  # the drive decides (nmt_stop_action)
                self._callback("on_nmt_stop", self.on_nmt_stop)
        elif cs == cop.NMT_PRE_OPERATIONAL:
            self._set_state("PRE-OPERATIONAL")
        elif cs in (cop.NMT_RESET_NODE, cop.NMT_RESET_COMMUNICATION):
            kind = "reset node" if cs == cop.NMT_RESET_NODE else "reset communication"
            self.state = "INITIALISING"  # no EMCY before the boot-up (L17089-L17095)
            if self.on_nmt_reset is not None:
                self._callback("on_nmt_reset", self.on_nmt_reset, kind)  # AL401, alarm clearing
            self._reset(kind)
            self._announce()  # the alarm standing after the reset (AL401), after the boot-up

    def _restart_heartbeat(self, now: int) -> None:
        period = self._values.get((0x1017, 0), 0)
        self._hb_next = now + period * MS if period else None

    def _comm_error(self) -> None:
        """AL180 (raised by the drive's supervision): the NMT state 1029h asks for
        (L17806-L17838)."""
        behaviour = self.comm.error_behaviour(self._values.get((0x1029, 1), 0))
        if behaviour == 0 and self.state == "OPERATIONAL":
            self._set_state("PRE-OPERATIONAL")
        elif behaviour == 2:
            self._set_state("STOPPED")

    def _guarding_off(self) -> bool:
        """The heartbeat producer runs (1017h != 0) and the option says that ends guarding
        (`guarding_with_heartbeat`, docs/manual-choices.md)."""
        opts = getattr(self.drive, "options", None)
        return bool(self._values.get((0x1017, 0), 0)) and \
            getattr(opts, "guarding_with_heartbeat", "heartbeat") == "heartbeat"

    def _on_guard(self, now: int) -> None:
        if self._guarding_off():  # the heartbeat protocol is in use: no answer, no life time
            self.comm.life_deadline = None
            return
        state = {"STOPPED": 4, "OPERATIONAL": 5, "PRE-OPERATIONAL": 127}.get(self.state, 0)
        self._send(cop.HEARTBEAT + self.node_id, bytes([self._guard_toggle << 7 | state]))
        self._guard_toggle ^= 1
        self.comm.guarded(now, self._values.get((0x100C, 0), 0), self._values.get((0x100D, 0), 0))

    def _on_heartbeat_in(self, cid: int, data: bytes, now: int, remote: bool) -> bool:
        if remote or not (0x701 <= cid <= 0x77F):
            return False
        watch = self._values.get((0x1016, 1), 0)
        node, t_ms = (watch >> 16) & 0x7F, watch & 0xFFFF
        if node and t_ms and cid == cop.HEARTBEAT + node and data:
            # A boot-up restarts monitoring; it starts with the first heartbeat (CiA 301).
            self.comm.heartbeat(now, t_ms, bootup=data[0] == 0)
        return True

    # ------------------------------------------------------------------ EMCY
    def _error_register(self) -> int:
        return int(self.drive.alarms.error_register) & 0xFF

    def _emcy(self, ev: AlarmChanged) -> None:
        """EMCY (L17061-L17069): code, 1001h, Delta alarm code in bytes 3-4 (little-endian).
        One alarm at a time (L17063, option `emcy_priority`): with "class" the alarm 603Fh
        shows, sent when it changes, 0000h once no alarm is left."""
        alarms = self.drive.alarms
        opts = getattr(self.drive, "options", None)  # a drive without the option: "latest"
        if getattr(opts, "emcy_priority", "latest") == "class":
            shown = alarms.emcy_alarm
            if shown == self._emcy_shown:
                return  # a lower (or equal) priority alarm, or another one's clear
            # what the drive shows now, sent or not: a clear while STOPPED is no EMCY, but the
            # alarm's next occurrence is one (helper-109: it had been taken as shown already)
            self._emcy_shown = shown
            code, name = (alarms.table.spec(shown).emcy, shown) if shown else (0, "")
        else:
            code, name = (ev.emcy_code, ev.code) if ev.active else (0, "")
            self._emcy_shown = name or None  # what this mode would have said, sent or not
        self._send_emcy(code, name)

    def _announce(self) -> None:
        """After an NMT reset's boot-up: the EMCY of the alarm the drive still shows (AL401
        raised by that very reset, or one the reset did not clear), so that its clear is
        announced too (L17063; CiA 301: each change of an error is an EMCY)."""
        alarms = getattr(self.drive, "alarms", None)
        if alarms is None:
            return
        opts = getattr(self.drive, "options", None)
        shown = (alarms.emcy_alarm if getattr(opts, "emcy_priority", "latest") == "class"
                 else alarms.current)
        if shown is None:
            return
        self._emcy_shown = shown
        self._send_emcy(alarms.table.spec(shown).emcy, shown)

    def _catch_up(self) -> None:
        """Out of STOPPED: the alarm changes made there were not sent (L17089-L17095); the
        master hears where the drive stands now, if that differs from the last EMCY it heard:
        the alarm shown, or 0000h (helper-110: a clear while STOPPED was never announced)."""
        shown = self._emcy_shown  # what the mode's EMCYs said while STOPPED, none sent
        if shown == self._emcy_sent:
            return
        spec = self.drive.alarms.table.spec(shown) if shown else None
        self._send_emcy(spec.emcy if spec is not None else 0, shown or "")

    def _send_emcy(self, code: int, name: str) -> None:
        cob = self._values.get((0x1014, 0), 0x80 + self.node_id)
        if cob & 0x80000000 or self.state not in ("PRE-OPERATIONAL", "OPERATIONAL"):
            return
        self._emcy_sent = name or None  # what the master last heard
        alarm = 0
        if name.upper().startswith("AL"):
            try:
                alarm = int(name[2:], 16)
            except ValueError:
                alarm = 0
        data = bytes([code & 0xFF, code >> 8 & 0xFF, self._error_register()])
        data += alarm.to_bytes(2, "little") + bytes(3)
        self._send(cob & 0x7FF, data)

    def _history(self) -> list[int]:
        hist = [int(h) for h in self.drive.alarms.error_history][:5]
        if self._history_cleared is not None:
            if tuple(hist) == self._history_cleared:
                return []
            if self._history_cleared and self._history_cleared[0] in hist:
                return hist[: hist.index(self._history_cleared[0])]
            self._history_cleared = None
        return hist
