"""Alarms and warnings of chapter 13: table, raise / cause / reset / power cycle, history.

Table: `hil.profile.alarms` (`fixtures/drive/a3_alarms.csv`, columns: fixtures/drive/README.md).
Resets (L7079-7083, L15082, L20199): DI.ARST rising edge ("di"), P0.001 := 0 ("p0001"),
CiA 402 6040h fault reset ("6040h"), CANopen NMT reset ("nmt").
History P4.000-P4.004: low word = alarm number, high word = CANopen error code (L10781-10792).
1003h: high word = Delta alarm number, low word = CiA error code (L17577-17588).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

from hil.model.events import AlarmChanged, AlarmReset
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler
from hil.profile.alarms import CLEAR_RULES, AlarmSpec, AlarmTable, UnknownAlarm

RESET_SOURCES = ("di", "p0001", "6040h", "nmt")
HISTORY_PARAMS = ("P4.000", "P4.001", "P4.002", "P4.003", "P4.004")
GENERIC_EMCY = 0x1000  # CiA 301 "generic error" for alarms without a chosen code


@dataclass
class AlarmOptions:
    """Per-code override of the clear rule, e.g. {"AL501": "reset"} (deviation knob)."""

    clear_override: dict[str, str] = field(default_factory=dict)
    # ModelOptions.fault_reset_clears == "listed": 6040h clears only the alarms whose row
    # names it ("NMT or 6040h" rule, or a note citing 6040h such as AL500 L20199)
    fault_reset_listed: bool = False


POWER_CYCLE_KEEPS = frozenset({"AL3F1"})
# "reset" alarms an NMT reset clears as well: AL401's remedy is an NMT reset or a 6040h reset
# (L20186), its clear row an alarm reset (L20187)
NMT_ALSO_CLEARS = frozenset({"AL401"})


class AlarmManager:
    """Active alarms, their causes, resets, P0.001, P4.000-P4.004, 1001h and 1003h."""

    def __init__(
        self,
        table: AlarmTable | None,
        scheduler: Scheduler,
        params: ParameterStore,
        emit: Callable[[AlarmChanged], None] | None = None,
        options: AlarmOptions | None = None,
        on_reset: Callable[[AlarmReset], None] | None = None,
    ) -> None:
        self.table = table if table is not None else AlarmTable.load()
        self.scheduler = scheduler
        self.params = params
        self.emit = emit or (lambda event: None)
        self.on_reset = on_reset or (lambda event: None)  # the request, for the record
        self.options = options or AlarmOptions()
        for code, rule in self.options.clear_override.items():
            self.table.spec(code)
            if rule not in CLEAR_RULES:
                raise ValueError(f"{code}: clear override {rule!r} not one of {CLEAR_RULES}")
        self._active: list[str] = []  # activation order
        self._causes: set[str] = set()
        params.on_write("P0.001", self._on_p0001)

    # -- queries ---------------------------------------------------------------------------

    @property
    def active(self) -> tuple[str, ...]:
        return tuple(self._active)

    @property
    def current(self) -> str | None:
        """What P0.001 shows: the most recently raised active alarm."""
        return self._active[-1] if self._active else None

    @property
    def emcy_alarm(self) -> str | None:
        """The alarm 603Fh and the EMCY object carry (L17063): an ALM-class alarm before a
        WARN; of one class the first raised (only a higher priority overrides)."""
        best, rank = None, 0
        for code in self._active:
            r = 2 if self.kind(code) == "ALM" else 1
            if r > rank:
                best, rank = code, r
        return best

    @property
    def servo_off_required(self) -> bool:
        return any(self.table.spec(c).servo_off for c in self._active)

    @property
    def alrm(self) -> bool:
        """DO ALRM (0x07): an ALM-class alarm is active (L15282, L7470)."""
        return any(self.kind(c) == "ALM" for c in self._active)

    @property
    def warn(self) -> bool:
        """DO WARN (0x11): a WARN-class event (limits, EMGS, undervoltage, comm...) (L15307)."""
        return any(self.kind(c) == "WARN" for c in self._active)

    def kind(self, code: str) -> str:
        """"ALM" or "WARN" (table 13.1); P2.066 bit 9 = 1 makes AL003 an ALM (L9973-9975,
        L19510)."""
        spec = self.table.spec(code)
        if spec.code == "AL003" and self.params.get("P2.066") & 0x200:
            return "ALM"
        return spec.kind

    def cause_present(self, code: str) -> bool:
        return self.table.spec(code).code in self._causes

    def clear_rule(self, code: str) -> str:
        spec = self.table.spec(code)
        rule = self.options.clear_override.get(spec.code)
        if rule is not None:
            return rule
        if spec.code == "AL003" and self.params.get("P2.066") & 0x4:
            return "auto"  # P2.066 bit2 = 1: undervoltage auto-clears (L19512)
        return spec.clear

    @property
    def history(self) -> list[str]:
        """Codes in P4.000 (newest) .. P4.004, empty entries left out."""
        out = []
        for name in HISTORY_PARAMS:
            number = self.params.read(name) & 0xFFFF
            if number:
                try:
                    out.append(self.table.by_number(number).code)
                except UnknownAlarm:
                    out.append(f"AL{number:03X}")
        return out

    @property
    def error_register(self) -> int:
        """1001h: bit0 generic, 1 current, 2 voltage, 3 temperature, 4 communication, 7 other."""
        reg = 0
        for code in self._active:
            emcy = self.table.spec(code).emcy
            reg |= 0x01
            top = emcy >> 12
            if top == 0x2:
                reg |= 0x02
            elif top == 0x3:
                reg |= 0x04
            elif top == 0x4:
                reg |= 0x08
            elif emcy >> 8 in (0x81, 0x82, 0x87, 0x75):
                # communication (L17534): CiA 301's 81xxh communication and 82xxh protocol
                # errors, the SYNC controller 87xxh (AL305, AL3E3) and the serial interface
                # 75xxh; not the drive's own monitoring (84xxh speed, 8611h following error,
                # 8612h limits): those set the generic bit only
                reg |= 0x10
            elif emcy == GENERIC_EMCY or top == 0xF:
                reg |= 0x80
        return reg

    @property
    def error_history(self) -> list[int]:
        """1003h sub 1..n, newest first: (Delta number << 16) | CiA error code."""
        out = []
        for name in HISTORY_PARAMS:
            raw = self.params.read(name)
            if raw & 0xFFFF:
                out.append(((raw & 0xFFFF) << 16) | (raw >> 16))
        return out

    # -- changes ---------------------------------------------------------------------------

    def raise_alarm(self, code: str) -> bool:
        """Make `code` active (if it is not); record history. True when newly active."""
        spec = self.table.spec(code)
        if spec.code in self._active:
            return False
        self._active.append(spec.code)
        self._shift_history(spec)
        self._update_p0001()
        self.emit(AlarmChanged(self.scheduler.now, spec.code, True, spec.emcy))
        return True

    def set_cause(self, code: str, present: bool) -> None:
        """The condition behind `code` appeared (raises it) or went away (auto alarms clear)."""
        spec = self.table.spec(code)
        if present:
            self._causes.add(spec.code)
            self.raise_alarm(spec.code)
            return
        self._causes.discard(spec.code)
        if spec.code in self._active and self.clear_rule(spec.code) == "auto":
            self._clear(spec.code)

    def clear(self, code: str) -> bool:
        """Clear `code` whatever its rule (its owner finished the clearing procedure)."""
        spec = self.table.spec(code)
        if spec.code not in self._active:
            return False
        self._clear(spec.code)
        return True

    def reset(self, source: str = "di") -> bool:
        """Alarm reset; clears resettable alarms whose cause is gone.

        source: "di" (ARST rising edge), "p0001" (P0.001 := 0), "6040h" (fault reset),
        "nmt" (CANopen NMT reset: only nmt_or_reset alarms). Returns servo_off_required.
        """
        if source not in RESET_SOURCES:
            raise ValueError(f"reset source {source!r} not one of {RESET_SOURCES}")
        if source != "nmt":  # an alarm reset the manual names (L20199), recorded for the specs
            self.on_reset(AlarmReset(self.scheduler.now, source))
        for code in list(self._active):
            if code in self._causes:
                continue
            rule = self.clear_rule(code)
            if (source == "6040h" and self.options.fault_reset_listed and rule == "reset"
                    and "6040h" not in self.table.spec(code).note):
                continue
            if (rule == "reset" and (source != "nmt" or code in NMT_ALSO_CLEARS)) or (
                rule == "nmt_or_reset" and source in ("6040h", "nmt")
            ):
                self._clear(code)
        return self.servo_off_required

    def power_cycle(self) -> None:
        """Clear every alarm whose cause is gone, but a `service` one (a repair, L19877,
        L19893, L20217; AL555 "無", L20227) and AL3F1 (its clear is the absolute origin,
        L20175); history is kept (P4.000-P4.004)."""
        for code in list(self._active):
            if (code not in self._causes and code not in POWER_CYCLE_KEEPS
                    and self.clear_rule(code) != "service"):
                self._clear(code)
        self._update_p0001()

    # -- internals -------------------------------------------------------------------------

    def _clear(self, code: str) -> None:
        self._active.remove(code)
        self._update_p0001()
        self.emit(AlarmChanged(self.scheduler.now, code, False, 0))

    def _update_p0001(self) -> None:
        cur = self.current
        self.params.set_internal("P0.001", self.table.spec(cur).number if cur else 0)

    def _shift_history(self, spec: AlarmSpec) -> None:
        values = [self.params.read(n) for n in HISTORY_PARAMS]
        values = [(spec.emcy << 16) | spec.number, *values[:-1]]
        for name, value in zip(HISTORY_PARAMS, values, strict=True):
            self.params.set_internal(name, value)

    def _on_p0001(self, name: str, old: int, new: int) -> None:
        if new == 0:
            self.reset("p0001")
        self._update_p0001()
