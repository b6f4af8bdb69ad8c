"""Digital inputs and outputs: function mapping, a/b contacts, filter, software DI, P0.046.

Inputs: DI1-DI10 (physical contacts) and VDI11-VDI13, mapped by P2.010-P2.017, P2.036-P2.040.
Outputs: DO1-DO6, mapped by P2.018-P2.022, P2.041. Mapping parameter layout (L9238-9256,
L9323-9339): low byte YX = function code (table 8.1 / 8.2), digit Z = contact: 0 = b (NC),
1 = a (NO). A DI function is active when an a-contact is closed or a b-contact is open; a DO
conducts when its function is true (a) or false (b).

Mapping changes need a power cycle (L9256, L9339): the mapping in effect is read at
construction and at `power_cycle()`. Choices: docs/manual-choices.md#alarms-dio.
"""

from __future__ import annotations

from collections.abc import Callable

from hil.model.errors import InertFunction, UnknownFunction
from hil.model.events import DoChanged
from hil.model.params import ParameterStore
from hil.model.timebase import Scheduler, Timer
from hil.profile.dio import (  # tables 8.1 / 8.2 and the mapping parameters (the A3 as data)
    DI_FUNCTIONS,
    DI_PARAMS,
    DI_SYMBOLS,
    DO_FUNCTIONS,
    DO_PARAMS,
    DO_SYMBOLS,
    N_DI,
    N_DO,
    N_PHYSICAL_DI,
    decode_mapping,
)
from hil.units import MS

# Table 8.1 functions the virtual drive does not model (docs/manual-choices.md). Mapping one of them
# by a P2.010-P2.017 / P2.036-P2.040 write, or in a bench, is refused: a mapped function that
# silently does nothing would make a test pass for the wrong reason. The motion functions
# PFQS, JOGU/JOGD, TRQLM/SPDLM, ZCLAMP, CCLR and GAINUP are modelled (di_functions.py), and
# the PT functions GNUM0/GNUM1, INHP and PT-PR (pulse_train.py); what stays here needs an
# input the virtual drive has not (analog position command, linear scale, gantry, E-cam) or
# a mode switch it does not model (the S/T mixed modes).
INERT_DI_FUNCTIONS: dict[str, str] = {
    "CMDINV": "command inversion of the analog S/T command is not modelled (L15094)",
    "CTRY": "the gantry function (P1.074 = 2) is not modelled (L15104)",
    "VPL": "the analog position command latch is not modelled (L15107)",
    "VPRS": "the analog position command clear is not modelled (L15113)",
    "FEC": "the full-closed loop (linear scale) is not modelled (L15117)",
    "S-P": "mixed-mode switching (P1.001 = 6/8) is not modelled (L15172)",
    "S-T": "mixed-mode switching (P1.001 = 0x0A) is not modelled (L15176)",
    "T-P": "mixed-mode switching (P1.001 = 7/9) is not modelled (L15180)",
    "ALGN": "E-cam alignment (P2.076) is not modelled (L15203)",
    "CAM": "the E-cam (P5.088) is not modelled (L15206)",
}

# The DO functions of table 8.2 nothing in the virtual drive drives: mapped, the output would
# sit at its idle level for ever (a b-contact one conducting), so mapping one is refused too.
INERT_DO_FUNCTIONS: dict[str, str] = {
    "OLW": "the overload warning (P1.056, L8711-8719) needs a thermal model the virtual "
           "drive has not (L15304)",
    "SP_OK": "speed reached (P1.047/P1.049, L8576-8590) is not modelled (L15332)",
    "CAM_AREA1": "the E-cam (P2.078-P2.079) is not modelled (L15329)",
    "CAM_AREA2": "the E-cam (P2.078-P2.079) is not modelled (L15335)",
    "Zon1": "the range comparisons of P0.009-P0.012 (P0.054-P0.061) are not modelled "
            "(L15336-15347)",
    "Zon2": "the range comparisons of P0.009-P0.012 (P0.054-P0.061) are not modelled "
            "(L15336-15347)",
    "Zon3": "the range comparisons of P0.009-P0.012 (P0.054-P0.061) are not modelled "
            "(L15336-15347)",
    "Zon4": "the range comparisons of P0.009-P0.012 (P0.054-P0.061) are not modelled "
            "(L15336-15347)",
}


def inert_mapping(param: str, value: int) -> str | None:
    """Why mapping `value` on DI or DO parameter `param` is refused, or None (not a mapping
    or a modelled function)."""
    if param in DI_PARAMS:
        kind, table, inert = "DI", DI_FUNCTIONS, INERT_DI_FUNCTIONS
    elif param in DO_PARAMS:
        kind, table, inert = "DO", DO_FUNCTIONS, INERT_DO_FUNCTIONS
    else:
        return None
    fn = table.get(value & 0xFF)
    if fn is None or fn.symbol not in inert:
        return None
    return f"{kind} function {fn.symbol} (0x{fn.code:02X}): {inert[fn.symbol]}"


def check_mapping_write(param: str, value: int) -> None:
    """Validator of a DI or DO mapping write: unknown codes and inert functions are
    refused."""
    decode_mapping("DI" if param in DI_PARAMS else "DO", value, param)
    why = inert_mapping(param, value)
    if why:
        raise InertFunction(param, why)


# Functions whose trigger ("rising/level" in table 8.1) a parameter selects: level when it
# holds this value, and then they act from power-up like any level function. CCLR: P2.050 = 1
# (L9753).
LEVEL_BY_PARAM: dict[str, tuple[str, int]] = {"CCLR": ("P2.050", 1)}

# Functions that only exist through the absolute handshake overlay (L15145).
OVERLAY_DI_SYMBOLS = ("ABSQ",)

OVERLAY_DO_SYMBOLS = ("ABSR", "ABSD")  # L15409, L15413


# P0.046 status bits (L7460-7475).
P0046_BITS = {
    "SRDY": 0, "SON": 1, "ZSPD": 2, "TSPD": 3, "TPOS": 4, "TQL": 5, "ALRM": 6, "BRKR": 7,
    "HOME": 8, "OLW": 9, "WARN": 10,
}  # fmt: skip

FILTER_MODES = ("stable", "delay")


class UnknownSymbol(UnknownFunction):
    """A function symbol that table 8.1 / 8.2 does not define."""

    def __init__(self, kind: str, symbol: str) -> None:
        Exception.__init__(
            self, f"unknown {kind} function symbol {symbol!r} (table 8.{1 if kind == 'DI' else 2})"
        )
        self.kind = kind
        self.code = -1
        self.symbol = symbol


class DigitalIO:
    """DI/DO logic of one drive. Electrical levels in, electrical levels out."""

    def __init__(
        self,
        params: ParameterStore,
        scheduler: Scheduler,
        emit: Callable[[DoChanged], None] | None = None,
        name: str = "drive",
        *,
        filter_mode: str = "stable",
        extra_delay_ns: int = 0,
        mapping_on_write: bool = True,
    ) -> None:
        if filter_mode not in FILTER_MODES:
            raise ValueError(f"filter_mode {filter_mode!r} not one of {FILTER_MODES}")
        self.params = params
        self.scheduler = scheduler
        self.emit = emit or (lambda event: None)
        self.name = name
        self.filter_mode = filter_mode
        self.extra_delay_ns = extra_delay_ns  # deviation knob dev_di_filter_extra_ms
        self._raw = [False] * N_PHYSICAL_DI  # contact level at the terminal
        self._accepted = [False] * N_PHYSICAL_DI  # after the P2.009 filter
        self._pending: list[Timer | None] = [None] * N_PHYSICAL_DI
        self._sdi = params.stored("P4.007")
        self._di_map: list[tuple[int, bool]] = [(0, True)] * N_DI
        self._do_map: list[tuple[int, bool]] = [(0, True)] * N_DO
        self._di_state: dict[str, bool] = {}
        self._do_state: dict[str, bool] = {}
        self._do_level = [False] * N_DO
        self._subs: dict[str, list[Callable[[bool], None]]] = {}
        self._overlay_di: dict[int, str] = {}
        self._overlay_do: dict[int, str] = {}
        self._held: dict[str, bool] = {}
        self._reserved_di: set[int] = set()  # DI7 while CAPTURE runs (capture.py, L5150)
        self._forced_do: dict[int, bool] = {}  # DO4 while COMPARE runs (compare.py, L5188)
        self._raw_subs: list[Callable[[int, bool], None]] = []
        self._off = False  # control power off: no DO conducts (power_off)
        self.forced_do_mode = False  # P2.008 = 406 (below)
        for p in (*DI_PARAMS, *DO_PARAMS):
            params.on_validate(p, check_mapping_write)
            # values written before this validator existed (`Drive(params=...)`) too
            check_mapping_write(p, params.stored(p))
        if mapping_on_write:  # option mapping_effect (docs/manual-choices.md)
            for p in (*DI_PARAMS, *DO_PARAMS):
                params.on_write(p, lambda *_: self._apply_mapping())
        params.on_write("P3.006", lambda *_: self._update_di())
        params.on_write("P4.007", self._on_sdi)
        params.on_write("P4.006", lambda *_: self._update_spo())
        # forced DO mode (L2769, L9226-9227): P2.008 = 406 enters it, 400 leaves it; in it
        # P4.006 bit n-1 drives DOn, whatever its function (an output check on the bench)
        params.on_write("P2.008", self._on_p2008)
        params.on_read("P4.007", self.di_word)
        self._apply_mapping()

    # -- mapping --------------------------------------------------------------------------

    def _apply_mapping(self) -> None:
        self._di_map = [decode_mapping("DI", self.params.get(p), p) for p in DI_PARAMS]
        self._do_map = [decode_mapping("DO", self.params.get(p), p) for p in DO_PARAMS]
        self._update_di()
        self._update_spo()
        self._update_do()

    def power_off(self) -> None:
        """Control power off: no output transistor conducts until `power_cycle()`."""
        self._off = True
        self._update_do()

    def _on_p2008(self, _name: str, _old: int, new: int) -> None:
        if new in (400, 406):
            self.forced_do_mode = new == 406
            self._update_do()

    def power_cycle(self) -> None:
        """Re-read the mapping (L9256, L9339), P4.006/P4.007 after their ■ revert."""
        self.forced_do_mode = False  # a command, not a setting
        self._off = False
        self._sdi = self.params.stored("P4.007")
        self.clear_overlay()
        self._apply_mapping()

    def di_function(self, n: int) -> str:
        """Symbol of the function mapped to DI n in effect ("" when disabled)."""
        code, _ = self._di_map[self._di_index(n)]
        return DI_FUNCTIONS[code].symbol if code else ""

    def do_function(self, n: int) -> str:
        """Symbol DO n shows now (overlay included; "" when disabled)."""
        idx = self._do_index(n)
        if n in self._overlay_do:
            return self._overlay_do[n]
        code, _ = self._do_map[idx]
        return DO_FUNCTIONS[code].symbol if code else ""

    # -- DI side --------------------------------------------------------------------------

    def set_input(self, n: int, closed: bool, *, settled: bool = False) -> None:
        """Physical DI n (1-10) electrical level: True = contact closed (24 V).

        `settled=True` accepts the level at once (it was already stable when the drive
        powered up), bypassing the P2.009 filter.
        """
        i = self._physical_index(n)
        closed = bool(closed)
        if closed != self._raw[i]:
            for fn in list(self._raw_subs):  # high-speed inputs see the terminal, unfiltered
                fn(n, closed)
        if settled:
            if self._pending[i] is not None:
                self._pending[i].cancel()
                self._pending[i] = None
            self._raw[i] = closed
            self._accept(i, closed)
            return
        pending = self._pending[i]
        if pending is not None and not pending.cancelled and pending.deadline <= self.scheduler.now:
            pending.cancel()  # due at this very instant: accept it before the new change
            self._accept(i, not self._accepted[i])
        self._raw[i] = closed
        delay = self.params.get("P2.009") * MS + self.extra_delay_ns  # L9229-9236
        if self.filter_mode == "delay":
            if delay == 0:
                self._accept(i, closed)
            else:
                self.scheduler.after(delay, lambda: self._accept(i, closed))
            return
        if pending is not None:
            pending.cancel()
            self._pending[i] = None
        if closed == self._accepted[i]:
            return
        if delay == 0:
            self._accept(i, closed)
        else:
            self._pending[i] = self.scheduler.after(delay, lambda: self._accept(i, closed))

    def input_level(self, n: int) -> bool:
        """Physical terminal level of DI n as last set (before the filter)."""
        return self._raw[self._physical_index(n)]

    def contact(self, n: int) -> bool:
        """Contact state of DI n (1-13) after filter and P3.006/P4.007 source selection."""
        i = self._di_index(n)
        if (self.params.get("P3.006") >> i) & 1:
            return bool((self._sdi >> i) & 1)  # software SDI (L10585-10606)
        return self._accepted[i] if i < N_PHYSICAL_DI else False

    def di_word(self) -> int:
        """P4.007 as read: the mixed final DI contact states (L10897-10906)."""
        return sum(1 << i for i in range(N_DI) if self.contact(i + 1))

    def function_active(self, function: str | int) -> bool:
        """Logical state of a DI function by symbol ("SON") or code (0x01)."""
        symbol = self._di_symbol(function)
        return self._di_state.get(symbol, False)

    def on_function(self, function: str | int, fn: Callable[[bool], None]) -> Callable[[], None]:
        """fn(active) on every change of a DI function; returns an unsubscribe callable."""
        symbol = self._di_symbol(function)
        self._subs.setdefault(symbol, []).append(fn)
        return lambda: self._subs[symbol].remove(fn)

    def apply_levels(self) -> None:
        """Power-up: tell the handlers of every active level-triggered function (table 8.1
        "準位") its state once, as if it had just become active. Level functions act for as
        long as they are on, including from power-up (EMGS/NL/PL at power-up show AL013-
        AL015, L2829-2831); edge-triggered functions (ARST, ABSC, ...) saw no edge."""
        for sym, active in list(self._di_state.items()):
            code = DI_SYMBOLS.get(sym)
            if not active or code is None:
                continue
            trigger = DI_FUNCTIONS[code].trigger
            by = LEVEL_BY_PARAM.get(sym)
            if trigger == "level" or (by is not None and self.params.get(by[0]) == by[1]):
                for fn in list(self._subs.get(sym, ())):
                    fn(True)

    def _accept(self, i: int, closed: bool) -> None:
        self._pending[i] = None
        if self._accepted[i] != closed:
            self._accepted[i] = closed
            self._update_di()

    def _on_sdi(self, name: str, old: int, new: int) -> None:
        self._sdi = new
        self._update_di()

    def _update_di(self) -> None:
        state: dict[str, bool] = {}
        for i, (code, a_contact) in enumerate(self._di_map):
            n = i + 1
            if n in self._overlay_di:
                sym = self._overlay_di[n]
                state[sym] = state.get(sym, False) or self.contact(n)
                if code:
                    held = DI_FUNCTIONS[code].symbol
                    state[held] = state.get(held, False) or self._held.get(held, False)
                continue
            if not code or n in self._reserved_di:
                continue
            sym = DI_FUNCTIONS[code].symbol
            active = self.contact(n) == a_contact
            state[sym] = state.get(sym, False) or active
        old = self._di_state
        self._di_state = state
        for sym in dict.fromkeys([*old, *state]):  # a fixed order (a set's varies by process)
            before, after = old.get(sym, False), state.get(sym, False)
            if before != after:
                for fn in list(self._subs.get(sym, ())):
                    fn(after)

    # -- DO side --------------------------------------------------------------------------

    def set_do_function(self, symbol: str, active: bool) -> None:
        """The drive reports a DO function state (SRDY, SON, ZSPD, BRKR, ALRM, ABSR, ...)."""
        if symbol not in DO_SYMBOLS and symbol not in OVERLAY_DO_SYMBOLS:
            raise UnknownSymbol("DO", symbol)
        active = bool(active)
        if self._do_state.get(symbol, False) == active:
            return
        self._do_state[symbol] = active
        if symbol in P0046_BITS:
            self._update_p0046()
        self._update_do()

    def do_function_state(self, symbol: str) -> bool:
        return self._do_state.get(symbol, False)

    def do_level(self, n: int) -> bool:
        """DO n (1-6) electrical level: True = output transistor conducting."""
        return self._do_level[self._do_index(n)]

    def do_levels(self) -> list[bool]:
        return list(self._do_level)

    def input_levels(self) -> list[bool]:
        """Physical terminal levels of DI1..DI10 (`input_level` of each)."""
        return list(self._raw)

    def _update_spo(self) -> None:
        word = self.params.get("P4.006")  # SPO_0..SPO_F = P4.006 bits (L15353-15403)
        changed = False
        for bit in range(16):
            sym, val = f"SPO_{bit:X}", bool((word >> bit) & 1)
            if self._do_state.get(sym, False) != val:
                self._do_state[sym] = val
                changed = True
        if changed:
            self._update_do()

    def _update_do(self) -> None:
        for i, (code, a_contact) in enumerate(self._do_map):
            n = i + 1
            if self._off:
                sym, level = "", False
            elif self.forced_do_mode:
                sym, level = "", bool((self.params.get("P4.006") >> i) & 1)
            elif n in self._forced_do:
                sym, level = "", self._forced_do[n]
            elif n in self._overlay_do:
                sym = self._overlay_do[n]
                level = self._do_state.get(sym, False)  # overlay outputs act as a-contacts
            elif code:
                sym = DO_FUNCTIONS[code].symbol
                level = self._do_state.get(sym, False) == a_contact
            else:
                sym, level = "", False
            if level != self._do_level[i]:
                self._do_level[i] = level
                self.emit(DoChanged(self.scheduler.now, n, level, sym))
        word = sum(1 << i for i, lvl in enumerate(self._do_level) if lvl)
        self.params.set_internal("P4.009", word)

    def _update_p0046(self) -> None:
        word = sum(1 << bit for sym, bit in P0046_BITS.items() if self._do_state.get(sym))
        self.params.set_internal("P0.046", word)

    # -- high-speed lines: CAPTURE on DI7, COMPARE on DO4 (A3 §7.2.2-7.2.3) -----------------

    def on_raw(self, fn: Callable[[int, bool], None]) -> None:
        """fn(n, closed) on every terminal change of a physical DI, before the P2.009 filter."""
        self._raw_subs.append(fn)

    def reserve_di(self, n: int, on: bool) -> None:
        """While on, DI n feeds no mapped function (CAPTURE forces DI7, L5150)."""
        if on == (n in self._reserved_di):
            return
        (self._reserved_di.add if on else self._reserved_di.discard)(n)
        self._update_di()

    def force_do(self, n: int, level: bool | None) -> None:
        """Drive DO n to `level` regardless of its mapping; None gives it back (COMPARE forces
        DO4, L5188)."""
        if level is None:
            if self._forced_do.pop(n, None) is None:
                return
        else:
            self._forced_do[n] = bool(level)
        self._update_do()

    # -- absolute handshake overlay (L15137, L16503-16521) ----------------------------------

    def overlay(self, di4: str = "ABSQ", do2: str = "ABSR", do3: str = "ABSD") -> None:
        """While ABSE is on, DI4 feeds ABSQ and DO2/DO3 show ABSR/ABSD.

        The function normally mapped to DI4 holds the state it had (L15137).
        """
        code, _ = self._di_map[3]
        if code:
            sym = DI_FUNCTIONS[code].symbol
            self._held[sym] = self._di_state.get(sym, False)
        self._overlay_di = {4: di4}
        self._overlay_do = {2: do2, 3: do3}
        self._update_di()
        self._update_do()

    def clear_overlay(self) -> None:
        if not self._overlay_di and not self._overlay_do:
            return
        self._overlay_di = {}
        self._overlay_do = {}
        self._held = {}
        self._update_di()
        self._update_do()

    @property
    def overlay_active(self) -> bool:
        return bool(self._overlay_di or self._overlay_do)

    # -- helpers --------------------------------------------------------------------------

    def _di_symbol(self, function: str | int) -> str:
        if isinstance(function, int):
            if function not in DI_FUNCTIONS:
                raise UnknownFunction("DI", function)
            return DI_FUNCTIONS[function].symbol
        if function in DI_SYMBOLS or function in OVERLAY_DI_SYMBOLS:
            return function
        raise UnknownSymbol("DI", str(function))

    @staticmethod
    def _physical_index(n: int) -> int:
        if not isinstance(n, int) or not 1 <= n <= N_PHYSICAL_DI:
            raise ValueError(f"DI{n}: physical inputs are DI1..DI{N_PHYSICAL_DI}")
        return n - 1

    @staticmethod
    def _di_index(n: int) -> int:
        if not isinstance(n, int) or not 1 <= n <= N_DI:
            raise ValueError(f"DI{n}: inputs are DI1..DI10 and VDI11..VDI13")
        return n - 1

    @staticmethod
    def _do_index(n: int) -> int:
        if not isinstance(n, int) or not 1 <= n <= N_DO:
            raise ValueError(f"DO{n}: outputs are DO1..DO{N_DO}")
        return n - 1
