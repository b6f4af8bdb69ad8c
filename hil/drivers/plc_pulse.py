"""A PLC's pulse positioning program: FATEK FBs FUN140 (HSPSO) / FUN141 (MPARA) on a pulse line.

Seed 001 (digest `../shared/spec/others.md` §2) is the source; lines are cited `001:N`.
`PulseMaster(port, AxisParams)` runs a `Program` as the PLC does: one step after the other,
each a speed (SPD), a drive command (DRV, DRVC, DRVZ) and a transition (WAIT, ACT, EXT), then
GOTO; MD ends. It outputs segments on a `PulsePort(role="master")`, reads the PLC's inputs
(DOG, stroke limit: levels `X<n>`; PG0: the drive's OZ pulses) and sets its CLR output
(`Y<n>`). Every wait is on `hil.clock`, so it runs in virtual time like the rest of a plan.

Choices where the seed is garbled or silent (docs/pulse.md):
* speeds and strokes are in pulses (P0 = 1, motor unit, the default, 001:50); P0 = 0
  (mechanical) converts `value x P1 / P2`; P3 (decimals) is not applied;
* acceleration is a constant slope (P4 - P5) / P8 from the start speed P5 (001:56), the
  profile is cut into `slice_ms` slices, one segment each (a cruise is one segment);
* DRVC: a faster segment accelerates from its start, a slower one is reached at its own speed
  (the slope begins before the joint, as the stop ramp before the end; 001:40 gives no figure);
* a stop at the zero point, EXT and abort are immediate (M1991 OFF, 001:28);
* the CLR pulse is `clr_ms` = 30 ms (> 20 ms, 001:124);
* P7 backlash is output on a reversal and not counted in the position; P10/P11 travel
  compensation is not modelled;
* register operands (Rxxxx / Dxxxx, 001:38-44): SPD and DRV strokes read two registers (the
  named one the low word, the next the high word, 32 bits signed), TIME (WAIT, ACT, in 0.01 s)
  and GOTO one register (16 bits); the PLC's own status registers of Ps0 are read as they
  stand when the step runs: R4060 error, R4064 step, DR4072 remaining pulses, DR4080
  frequency, DR4088 position.
"""

from __future__ import annotations

import math
import re
from collections.abc import Callable
from dataclasses import dataclass, field
from itertools import accumulate
from typing import Any

from hil import clock
from hil.units import MS, S

EXT_POLL_S = 0.0002  # how often a running segment looks at EXT / abort on the wall clock

MAX_STEPS = 250  # 001:26
MAX_DRVC = 8  # 001:40
OUTPUT_MAX_HZ = {"single": 200_000, "differential": 920_000}  # 001:14
AB_MAX_HZ = 460_000  # two-phase (A/B) maximum (001:14)
MD1_WAIT_NS = 500 * MS  # "wait 0.5 s" (001:112)
CLR_MIN_MS = 20.0  # "> 20 ms" (001:124)
CLR_MAX_MS = 10_000.0  # not in the seed: a CLR pulse of 10 s is already no pulse
DRVZ_MODES = ("MD0", "MD1", "MD2")
# Register operands (001:38-44): data registers R0-R3839, R5000-R8071 and D0-D3999 (the
# register map of FUN141's operand table, 001:50), and Ps0's status registers (001:28-34)
REGISTER = re.compile(r"^([RD])([0-9]{1,4})\Z")
STATUS_REGISTERS = {"R4060": "error", "R4064": "step", "R4072": "remaining", "R4080": "freq",
                    "R4088": "position"}
TIME_UNIT_S = 0.01  # WAIT TIME / ACT count 0.01 s (001:42)
FORMS = {"P/R": "pulse_sign", "U/D": "cw_ccw", "A/B": "ab"}

# Error codes R4060 (001:34, 74); FUN141 parameter k -> code k + 1 (0-9) / k + 1 (12-14)
ERRORS = {
    30: "speed variable number", 31: "speed value", 32: "stroke variable number",
    33: "stroke value", 34: "illegal program", 35: "step length", 36: "too many steps",
    37: "maximum frequency", 38: "start/stop frequency", 39: "compensation too large",
    40: "travel out of range", 41: "ABS not allowed inside DRVC",
    42: "DRVC may not chain into DRVZ", 43: "drive command code", 50: "DRVZ mode",
    51: "DOG input", 52: "PG0 input", 53: "CLR output", 60: "illegal interpolation command",
}


class PlcError(ValueError):
    """A program or parameter the PLC refuses, with its R4060 error code (001:74)."""

    def __init__(self, code: int, message: str, *, step: int | None = None,
                 field: str = "") -> None:
        self.code, self.step, self.field = code, step, field
        what = ERRORS.get(code, "FUN141 parameter")
        super().__init__(f"error {code} ({what}): {message}")


def canonical_register(name: Any) -> str | None:
    """`R0500` -> `R500`: the register a name means (None: no register name)."""
    m = REGISTER.match(name) if isinstance(name, str) else None
    return f"{m.group(1)}{int(m.group(2))}" if m else None


def _next(name: str) -> str:
    return f"{name[0]}{int(name[1:]) + 1}"


def _in_map(reg: str) -> bool:
    n = int(reg[1:])
    return n <= 3999 if reg[0] == "D" else (n <= 3839 or 5000 <= n <= 8071)


def data_register(name: str, bits: int = 16) -> bool:
    """A data register (R0-R3839, R5000-R8071, D0-D3999); with `bits` 32 its high word,
    the next register, is one too."""
    reg = canonical_register(name)
    return reg is not None and _in_map(reg) and (bits == 16 or _in_map(_next(reg)))


def operand_register(name: Any, bits: int = 16) -> bool:
    """A register a program step may name as its operand: a data or a status register."""
    return isinstance(name, str) and (data_register(name, bits) or name in STATUS_REGISTERS)


def register_words(values: dict[str, Any]) -> dict[str, int]:
    """The 16-bit words a plan's `registers:` sets: a value of 0-65535 is one word; a
    negative or larger one (32 bits signed) is a pair, its register the low word and the
    next the high word (001:38). Raises ValueError when two values set one word."""
    words: dict[str, int] = {}
    for name, value in values.items():
        reg = canonical_register(name)
        if reg is None or not data_register(reg):
            raise ValueError(f"{name}: a data register R0-R3839, R5000-R8071 or D0-D3999")
        if not isinstance(value, int) or isinstance(value, bool) \
                or not -(2**31) <= value < 2**32:
            raise ValueError(f"{name} = {value!r}: a whole number of 16 or 32 bits")
        pair = not 0 <= value <= 0xFFFF
        if pair and not data_register(reg, 32):
            raise ValueError(f"{name} = {value}: a 32-bit value takes {reg} and "
                             f"{_next(reg)}, which is no data register")
        v = value & 0xFFFFFFFF
        for r, w in ((reg, v & 0xFFFF), (_next(reg), v >> 16)) if pair else ((reg, v),):
            if r in words:
                raise ValueError(f"{name}: {r} is set twice (a 32-bit value takes its "
                                 "register and the next, the high word)")
            words[r] = w
    return words


def read_register(name: str, words: dict[str, int], status: Any, bits: int) -> int:
    """`name`'s value: a status register as the PLC shows it now, else the data register's
    word (unset: 0); 16 bits unsigned, 32 bits the word and the next (high) signed."""
    if name in STATUS_REGISTERS:
        v = int(getattr(status, STATUS_REGISTERS[name]))
        v = v & 0xFFFF if bits == 16 else v & 0xFFFFFFFF
    else:
        reg = canonical_register(name) or name
        v = words.get(reg, 0)
        if bits == 32:
            v |= words.get(_next(reg), 0) << 16
    return v - (1 << 32) if bits == 32 and v >> 31 else v


Operand = float | str  # a constant or a register name (Rxxxx / Dxxxx)


@dataclass
class AxisParams:
    """FUN141 MPARA, one axis (001:50-60)."""

    unit: int = 1  # P0: 0 mechanical, 1 motor (pulses), 2 compound
    pulses_per_rev: int = 2000  # P1, 1 ~ 65535
    travel_per_rev: int = 2000  # P2
    decimals: int = 2  # P3, 0 ~ 3
    max_speed: int = 200_000  # P4, Ps/s (default garbled in the seed)
    start_speed: int = 141  # P5
    creep_speed: int = 1000  # P6, 1 ~ 65535
    backlash: int = 0  # P7, 0 ~ 32767
    accel_ms: int = 5000  # P8, 0 ~ 30000
    run_direction: int = 0  # P9-0: 0 forward pulses count up
    home_direction: int = 1  # P9-1 (001:58): 0 towards increasing count ("origin on the
    # right"), 1 (the default) towards decreasing count ("origin on the left")
    decel_ms: int = 0  # P12, 0 = P8
    dog: str = ""  # P15-0, X<n> (with dog_nc for a b contact)
    dog_nc: bool = False
    limit: str = ""  # P15-1 stroke limit in the homing direction, X<n>
    limit_nc: bool = False
    pg0: str = ""  # P15-2 zero signal: "OZ" (the drive's Z output) or empty
    pg0_edge: str = "leading"  # b7: 0 count from the DOG leading edge, 1 from the trailing
    clr: str = ""  # P15-3 CLR output, Y<n>
    clr_ms: float = 30.0
    origin: int = 0  # P16 machine origin value
    zero_count: int = 1  # P17, 0 ~ 255
    output: str = "P/R"  # U/D, P/R, A/B (001:14, 28)
    logic: int = 0  # normal ON / normal OFF (001:28)
    hardware: str = "single"  # single-ended transistor 200 kHz / differential 920 kHz
    # DRV ABS with a stroke of 0: 001:38 says a stroke of 0 runs on "whether ADR or ABS";
    # 001:10 writes "DRV ABS,,0,Ut" to go from 300 mm to 0 mm. "continuous" (001:38) or
    # "position" (001:10): docs/manual-choices.md
    abs_zero: str = "continuous"

    @property
    def home_sign(self) -> int:
        """P9-1 as a count direction: +1 towards increasing count, -1 decreasing."""
        return 1 if self.home_direction == 0 else -1

    def check(self) -> None:
        """Refuse what FUN141 refuses (codes 1-15, 37-39, 001:34)."""
        rules: list[tuple[int, str, bool, str]] = [
            (1, "unit", self.unit in (0, 1, 2), "0, 1 or 2"),
            (2, "pulses_per_rev", 1 <= self.pulses_per_rev <= 65535, "1 ~ 65535"),
            (3, "travel_per_rev", 1 <= self.travel_per_rev <= 999_999, "1 ~ 999999"),
            (4, "decimals", 0 <= self.decimals <= 3, "0 ~ 3"),
            (5, "max_speed", self.max_speed >= 1, ">= 1 Ps/s"),
            (7, "creep_speed", 1 <= self.creep_speed <= 65535, "1 ~ 65535 Ps/s"),
            (9, "accel_ms", 0 <= self.accel_ms <= 30000, "0 ~ 30000 ms"),
            (10, "home_direction", self.home_direction in (0, 1),
             "0 towards increasing count, 1 towards decreasing (001:58)"),
            (13, "decel_ms", 0 <= self.decel_ms <= 30000, "0 ~ 30000 ms"),
        ]
        for code, name, ok, want in rules:
            if not ok:
                raise PlcError(code, f"{name} = {getattr(self, name)!r}: {want}", field=name)
        if not 0 <= self.backlash <= 32767:  # P7: error 8 (001:34, parameter number + 1)
            raise PlcError(8, f"backlash = {self.backlash}: 0 ~ 32767 Ps", field="backlash")
        if self.output not in FORMS:
            raise PlcError(1, f"output {self.output!r}: one of {', '.join(FORMS)}",
                           field="output")
        hw = OUTPUT_MAX_HZ.get(self.hardware)
        if hw is None:
            raise PlcError(37, f"hardware {self.hardware!r}: single or differential",
                           field="hardware")
        top = min(hw, AB_MAX_HZ) if self.output == "A/B" else hw
        if self.max_speed_pps > top:
            raise PlcError(37, f"max_speed {self.max_speed_pps:g} Ps/s above the {self.hardware}"
                               f" {self.output} output's {top} Hz (001:14)", field="max_speed")
        creep = self.speed(self.creep_speed)  # P6 in Ps/s: a homing's creep speed may not
        if creep > self.max_speed_pps:  # go past P4 nor the output (it had sent 65.5 MHz)
            raise PlcError(37, f"creep_speed {self.creep_speed} ({creep:g} Ps/s) above "
                               f"max_speed ({self.max_speed_pps:g} Ps/s, 001:14, 001:56)",
                           field="creep_speed")
        if not 1 <= self.start_speed_pps <= self.max_speed_pps:  # 38: start/stop frequency
            raise PlcError(38, f"start_speed {self.start_speed} ({self.start_speed_pps:g} Ps/s) "
                               f"not within 1 Ps/s ~ max_speed ({self.max_speed_pps:g} Ps/s)",
                           field="start_speed")
        if not 0 <= self.zero_count <= 255:  # P17: 18 by the seed's "parameter N + 1" rule
            raise PlcError(18, f"zero_count {self.zero_count}: 0 ~ 255", field="zero_count")
        if self.abs_zero not in ("continuous", "position"):
            raise PlcError(33, f"abs_zero {self.abs_zero!r}: continuous (001:38) or position "
                               "(001:10)", field="abs_zero")
        if self.pg0_edge not in ("leading", "trailing"):
            raise PlcError(52, f"pg0_edge {self.pg0_edge!r}: leading or trailing",
                           field="pg0_edge")
        # DOG a host point X0~X15, the stroke limit X0~X125 (P15-0 b6~b0, P15-1 b14~b8,
        # 001:58), CLR Y0~Y23 (001:60); the seed gives no error code of its own for the
        # stroke limit (P15-1): 51, DOG's, the other homing input
        for name, prefix, top, code in (("dog", "X", 15, 51), ("limit", "X", 125, 51),
                                        ("clr", "Y", 23, 53)):
            val = getattr(self, name)
            # (X00 or Y08 would name no line the bench drives: refused, not read as X0 / Y8)
            if val and not (re.fullmatch(rf"{prefix}(0|[1-9][0-9]{{0,2}})", val)
                            and int(val[1:]) <= top):
                raise PlcError(code, f"{name} {val!r}: {prefix}0 ~ {prefix}{top}", field=name)
        if self.pg0 not in ("", "OZ"):
            raise PlcError(52, f"pg0 {self.pg0!r}: OZ (the drive's Z output) or empty; a "
                           "PLC takes PG0 on X0~X15 (001:60), but the pulse line carries "
                           "the drive's Z pulses as OZ only, not as an X input's level",
                           field="pg0")
        if self.run_direction not in (0, 1):  # P9-0, error 10 (P9's)
            raise PlcError(10, f"run_direction {self.run_direction}: 0 or 1", field="run_direction")
        if self.logic not in (0, 1):
            raise PlcError(1, f"logic {self.logic}: 0 normal ON or 1 normal OFF (001:28)",
                           field="logic")
        if not -2**31 <= self.origin < 2**31:  # P16 into DR4088, 32 bits (001:122)
            raise PlcError(17, f"origin {self.origin}: a 32-bit value", field="origin")
        if self.clr and not CLR_MIN_MS < self.clr_ms <= CLR_MAX_MS:  # NaN fails too
            raise PlcError(53, f"clr_ms {self.clr_ms:g}: the CLR pulse must be > 20 ms "
                               f"(001:124), at most {CLR_MAX_MS:g} here", field="clr_ms")

    # -- units -----------------------------------------------------------------------------
    def pulses(self, value: float, unit: str = "Ps") -> int:
        """A stroke in pulses: `Ut` in the mechanical unit (P0 = 0 or 2) is mm with P3
        decimals, P2 (B) is µm a revolution and P1 (A) pulses a revolution (001:54-56);
        `Ps` (or P0 = 1) as is."""
        if unit == "Ut" and self.unit != 1:
            um = value * 10 ** (3 - self.decimals)
            return round(um * self.pulses_per_rev / self.travel_per_rev)
        return round(value)

    def speed(self, value: float) -> float:
        """A speed (SPD, P4, P5, P6) in Ps/s: with P0 = 0 it is cm/min, f = V x 1000 x A /
        (6 x B) (001:54-56); P0 = 1 and 2 give it in Ps/s."""
        if self.unit == 0:
            return value * 1000 * self.pulses_per_rev / (6 * self.travel_per_rev)
        return float(value)

    @property
    def max_speed_pps(self) -> float:
        return self.speed(self.max_speed)

    @property
    def start_speed_pps(self) -> float:
        return self.speed(self.start_speed)

    @property
    def accel(self) -> float:
        """Ps/s² of P8 (constant slope from P5 to P4); inf for P8 = 0."""
        span = max(self.max_speed_pps - self.start_speed_pps, 1.0)
        return math.inf if self.accel_ms == 0 else span * 1000.0 / self.accel_ms

    @property
    def decel(self) -> float:
        ms = self.decel_ms or self.accel_ms
        span = max(self.max_speed_pps - self.start_speed_pps, 1.0)
        return math.inf if ms == 0 else span * 1000.0 / ms


@dataclass
class Drv:
    """DRV / DRVC: ABS or ADR, direction "+", "-" or "" (sign of the value), stroke, unit."""

    mode: str  # "ABS" | "ADR"
    direction: str
    value: Operand  # pulses or units, or a register holding them (32 bits)
    unit: str = "Ps"
    chained: bool = False  # DRVC


@dataclass
class Step:
    """One program step: SPD, a drive command, a transition, GOTO (001:38-44)."""

    spd: Operand | None = None  # a speed, or a register holding it (32 bits)
    drive: Drv | str | None = None  # Drv, "MD0"/"MD1"/"MD2" (DRVZ), None
    wait_time: Operand | None = None  # WAIT TIME: s, or a register of 0.01 s (16 bits)
    wait_line: str = ""  # WAIT X<n>
    act: Operand | None = None  # ACT: s, or a register of 0.01 s (16 bits)
    ext: str = ""  # EXT X<n>
    goto: int | str | None = None  # None = NEXT; a 1-based step number or a register
    end: bool = False  # MD
    line: int = 0  # plan-file line, for errors


@dataclass
class Program:
    steps: list[Step] = field(default_factory=list)

    def check(self, p: AxisParams) -> None:
        """Refuse what FUN140 would (codes 30-53, 001:34, 40, 108)."""
        if not self.steps:
            raise PlcError(34, "the program has no step")
        if len(self.steps) > MAX_STEPS:
            raise PlcError(36, f"{len(self.steps)} steps: at most {MAX_STEPS} (001:26)")
        chain = 0
        for i, s in enumerate(self.steps, 1):
            if s.end:
                if chain:
                    raise PlcError(34, "a DRVC chain must end with a DRV (001:40)", step=i)
                continue
            if isinstance(s.spd, str):
                if not operand_register(s.spd, 32):
                    raise PlcError(30, f"SPD {s.spd}: not a register pair (R0-R3839, "
                                       "R5000-R8071, D0-D3999 and the next, or a status "
                                       "register)", step=i, field="SPD")
            elif s.spd is not None:
                self.check_speed(p, s.spd, i)
            for fld, op in (("WAIT", s.wait_time), ("ACT", s.act), ("GOTO", s.goto)):
                if isinstance(op, str) and not operand_register(op):
                    raise PlcError(34, f"{fld} {op}: not a register", step=i, field=fld)
            if isinstance(s.goto, int):
                self.check_goto(s.goto, i)
            d = s.drive
            if isinstance(d, str):
                if chain:
                    raise PlcError(42, "a DRVC chain may not end in DRVZ (001:74)", step=i)
                self._check_drvz(p, d, i)
                continue
            if d is None:
                if chain:
                    raise PlcError(34, "a DRVC chain must end with a DRV (001:40)", step=i)
                continue
            if s.spd is None:
                raise PlcError(30, "a DRV/DRVC step needs an SPD", step=i, field="SPD")
            if isinstance(d.value, str):
                if not operand_register(d.value, 32):
                    raise PlcError(32, f"stroke {d.value}: not a register pair", step=i,
                                   field="DRV")
            else:
                self.check_stroke(p, d, d.value, i)
            if d.mode not in ("ABS", "ADR"):
                raise PlcError(43, f"{d.mode!r}: ABS or ADR", step=i, field="DRV")
            if chain and d.mode == "ABS":
                raise PlcError(41, "only the first DRVC may be ABS (001:40)", step=i)
            if d.chained and not chain and d.mode == "ADR" and not d.direction:
                raise PlcError(43, "the first DRVC's direction is + or - (the chain runs "
                                   "that way, 001:40)", step=i, field="DRVC")
            if d.chained and (s.goto is not None or s.wait_time is not None or s.wait_line
                              or s.act is not None or s.ext):
                raise PlcError(34, "a DRVC step runs on into the next segment (001:40: "
                                   "GOTO NEXT, no WAIT, ACT or EXT): its transition would be "
                                   "ignored", step=i, field="DRVC")
            if d.chained:
                chain += 1
                if chain >= MAX_DRVC:
                    raise PlcError(34, f"a DRVC chain has at most {MAX_DRVC} segments "
                                       "(001:40)", step=i)
            else:
                chain = 0
        if chain:
            raise PlcError(34, "a DRVC chain must end with a DRV (001:40)",
                           step=len(self.steps))

    @staticmethod
    def check_speed(p: AxisParams, value: float, i: int, via: str = "") -> None:
        if value == 0 and via:  # the PLC waits for a non-zero value (001:38): for ever here
            raise PlcError(31, f"SPD {via} holds 0: the step would wait for ever for a non-zero "
                               "speed (001:38)", step=i, field="SPD")
        if not 1 <= p.speed(value) <= p.max_speed_pps:
            raise PlcError(31, f"SPD {via + ' = ' if via else ''}{value:g}: 1 ~ max_speed "
                               f"{p.max_speed_pps:g} Ps/s", step=i, field="SPD")

    @staticmethod
    def check_stroke(p: AxisParams, d: Drv, value: float, i: int, via: str = "") -> None:
        what = f"stroke {via + ' = ' if via else ''}{value:g}"
        if abs(p.pulses(value, d.unit)) >= 2**31:
            raise PlcError(33, f"{what}: beyond 32 bits", step=i, field="DRV")
        if value and p.pulses(value, d.unit) == 0:  # stroke 0 means "until the transition"
            raise PlcError(33, f"{what} {d.unit}: less than one pulse", step=i, field="DRV")
        if d.unit == "Ps" and value != int(value):
            raise PlcError(33, f"{what} Ps: a whole number of pulses", step=i, field="DRV")
        # a data register holds a stroke as a constant does; a status register (DR4072's
        # count, DR4088's position) is taken by its size in the direction written
        if d.direction and value < 0 and via not in STATUS_REGISTERS:
            raise PlcError(33, f"{what}: a direction {d.direction} and a negative stroke",
                           step=i, field="DRV")

    def check_goto(self, goto: int, i: int, via: str = "") -> None:
        if not 1 <= goto <= len(self.steps):
            raise PlcError(34, f"GOTO {via + ' = ' if via else ''}{goto}: no such step "
                               f"(1 ~ {len(self.steps)})", step=i, field="GOTO")

    def check_registers(self, p: AxisParams, registers: dict[str, Any]) -> dict[str, int]:
        """What the program reads from data registers (`registers:` values, `register_words`),
        checked as the constants are: nothing changes them while it runs (the status
        registers are read at run time). Returns the registers' words."""
        try:
            words = register_words(registers)
        except ValueError as e:
            raise PlcError(34, str(e)) from None

        def val(name: str, bits: int) -> int:
            return read_register(name, words, None, bits)
        for i, s in enumerate(self.steps, 1):
            if isinstance(s.spd, str) and s.spd not in STATUS_REGISTERS:
                self.check_speed(p, val(s.spd, 32), i, via=s.spd)
            d = s.drive
            if isinstance(d, Drv) and isinstance(d.value, str) \
                    and d.value not in STATUS_REGISTERS:
                self.check_stroke(p, d, val(d.value, 32), i, via=d.value)
            if isinstance(s.goto, str) and s.goto not in STATUS_REGISTERS:
                self.check_goto(val(s.goto, 16), i, via=s.goto)
        return words

    @staticmethod
    def _check_drvz(p: AxisParams, mode: str, i: int) -> None:
        if mode not in DRVZ_MODES:
            raise PlcError(50, f"DRVZ {mode!r}: MD0, MD1 or MD2", step=i, field="DRVZ")
        if not p.dog:
            raise PlcError(51, "DRVZ needs the DOG input (P15-0, 001:108)", step=i,
                           field="DRVZ")
        if mode == "MD2" and not p.pg0:
            raise PlcError(52, "DRVZ MD2 needs the PG0 input (P15-2, 001:108)", step=i,
                           field="DRVZ")


# ------------------------------------------------------------------------------ profiles


def plan_profile(segments: list[tuple[int, float]], v0: float, acc: float, dec: float,
                 slice_ns: int = 10 * MS, limit_ns: int | None = None) -> list[tuple[int, int]]:
    """Time slices `(duration_ns, pulses)` of a chained move: `segments` = [(pulses, speed)]
    (pulses > 0), started and stopped at `v0` with slopes `acc` / `dec` (Ps/s²). The pulses
    of the slices add up exactly to the total; a constant speed stays one slice.

    `limit_ns`: plan no further than that (the program's time left: a move past it is cut
    there anyway), so a 32-bit stroke at a low speed is not planned for hours up front. The
    slices then end short of the total."""
    total = sum(n for n, _ in segments)
    if total <= 0:
        return []
    dt = 1e-3
    per = max(1, slice_ns // MS)
    steps_max = (limit_ns // MS + per) if limit_ns is not None else None
    v, x = 0.0, 0.0
    bounds = list(accumulate(n for n, _ in segments))
    ends: list[float] = []  # the position at the end of each slice (each `per` ms)
    flat: list[float | None] = []  # each slice's speed when it held one speed throughout
    slice_v: float | None = None  # this slice's one speed so far (None: it changed)
    steps = 0  # ms planned
    i = 0
    v = min(v0, segments[0][1])
    while x < total - 1e-9:
        if steps_max is not None and steps >= steps_max:
            break
        while i < len(segments) - 1 and x >= bounds[i]:
            i += 1
        want = segments[i][1]
        rem = total - x
        stop_cap = math.sqrt(v0 * v0 + 2.0 * dec * rem) if math.isfinite(dec) else math.inf
        if math.isfinite(dec):  # a slower segment ahead is entered at its own speed
            for j in range(i + 1, len(segments)):
                vj = segments[j][1]
                stop_cap = min(stop_cap, math.sqrt(vj * vj + 2.0 * dec * (bounds[j - 1] - x)))
        target = min(want, stop_cap)
        if v < target:
            v = min(target, v + acc * dt) if math.isfinite(acc) else target
        elif v > target:
            v = max(target, v - dec * dt) if math.isfinite(dec) else target
        v = max(v, min(v0, want))
        short = x + v * dt > total  # the last step, cut short: not a whole ms at `v`
        x = min(total, x + v * dt)
        slice_v = None if short else v if steps % per == 0 else (
            slice_v if slice_v == v else None)
        steps += 1
        if steps % per == 0:
            ends.append(x)
            flat.append(slice_v)
        if steps_max is None and steps > 10_000_000:  # 2.8 h of 1 ms steps: no caller's
            raise PlcError(40, "profile longer than 10000 s: give the move a time limit")
    reached = x >= total - 1e-9
    if steps % per:
        ends.append(x)  # the last, shorter slice
        flat.append(None)
    out: list[tuple[int, int]] = []
    done = 0
    lead = 0  # the time of leading slices without a whole pulse: the first segment's
    run = 0  # ms of the stretch at one speed the slices so far belong to (floored at its end)
    for k, end in enumerate(ends):
        last = k == len(ends) - 1
        dur = (steps - k * per if last else per) * MS
        if (not last and flat[k] is not None and k + 1 < len(flat)
                and flat[k + 1] == flat[k]):
            run += dur  # a constant speed stays one segment at its own frequency (the
            continue  # floor of every 10 ms slice alternated 1200/1300 Hz for SPD 1234)
        dur += run
        run = 0
        n = (total if last and reached else math.floor(end)) - done
        if n <= 0:
            if out:
                out[-1] = (out[-1][0] + dur, out[-1][1])
            else:
                lead += dur  # (they had been dropped: the move ran shorter than planned)
            continue
        dur += lead
        lead = 0
        done += n
        if out and out[-1][1] * dur == n * out[-1][0]:  # same speed: one segment
            out[-1] = (out[-1][0] + dur, out[-1][1] + n)
        else:
            out.append((dur, n))
    return out


# ------------------------------------------------------------------------------ executor


@dataclass
class Status:
    """What the PLC shows (001:28-30): ready/busy, done, position DR4088, frequency
    DR4080, remaining pulses DR4072, error R4060, step number R4064."""

    ready: bool = True
    done: bool = False
    position: int = 0
    freq: float = 0.0
    remaining: int = 0
    error: int = 0
    step: int = 0
    feedback: int = 0  # OA/OB quadrature counts seen by the high-speed counter
    homed: bool = False  # a DRVZ found the zero point and completed (CLR included)
    drvz: str = ""  # the DRVZ mode running or completed; empty before any and after a failed one
    zero_found_ns: int | None = None


class PulseMaster:
    """One PLC axis (Ps0) on a pulse line."""

    def __init__(self, port: Any, params: AxisParams, *, slice_ms: float = 10.0,
                 on_status: Callable[[Status, str], None] | None = None) -> None:
        params.check()
        self.port, self.p = port, params
        self.slice_ns = max(MS, round(slice_ms * MS))
        self.status = Status()
        self.total = 0  # signed pulses output (backlash included)
        self._seg: tuple[int, float, int, int] | None = None  # (t0, freq, dir, count)
        self._last_dir = 0
        self._oz = 0
        self._abort = False
        self._counted = 1
        self.registers: dict[str, int] = {}  # the data registers' 16-bit words
        self.on_status = on_status
        self._unsub = port.subscribe(self._on_line)
        self.init_outputs()

    def init_outputs(self) -> None:
        """The PLC's outputs at their idle level (CLR off), on the record."""
        if self.p.clr and self.p.clr not in self.port.levels():
            self.port.set(self.p.clr, False)

    def close(self) -> None:
        self._unsub()

    # -- lines -------------------------------------------------------------------------
    def _on_line(self, kind: str, data: dict[str, Any], t: int, source_t: int | None) -> None:
        if kind == "oz":
            self._oz += 1
        elif kind == "oab":  # the high-speed counter on OA/OB (closed loop, 001:10)
            self.status.feedback += data["direction"] * data["count"]

    def line(self, name: str, nc: bool = False) -> bool:
        """The PLC input `name` (X<n>) as its function sees it (b contact inverted)."""
        return self.port.get(name) != nc

    def dog(self) -> bool:
        return self.line(self.p.dog, self.p.dog_nc)

    def at_limit(self) -> bool:
        return bool(self.p.limit) and self.line(self.p.limit, self.p.limit_nc)

    def abort(self) -> None:
        """ABT: stop at once (001:26)."""
        self._abort = True

    # -- pulses ------------------------------------------------------------------------
    def _output_now(self) -> int:
        """Pulses of the current segment output so far."""
        if self._seg is None:
            return 0
        t0, freq, _d, count = self._seg
        n = int((clock.monotonic_ns() - t0) * freq // S) if freq > 0 else 0
        return min(n, count) if count else n

    def _close_segment(self) -> None:
        if self._seg is not None:
            n = self._output_now()
            self.total += self._seg[2] * n
            # P9-0 = 1: forward pulses count down, reverse pulses count up (001:56)
            sign = -1 if self.p.run_direction else 1
            self.status.position += sign * self._seg[2] * n * self._counted
            self._seg = None

    def _send(self, freq: float, direction: int, count: int = 0, *, counted: bool = True
              ) -> None:
        self._close_segment()
        self.port.send("seg", {"freq": freq, "direction": direction, "count": count,
                               "form": FORMS[self.p.output], "logic": self.p.logic,
                               "total": self.total})
        self._counted = 1 if counted else 0
        self.status.freq = freq
        if freq > 0:
            self._seg = (clock.monotonic_ns(), freq, direction, count)
            self._last_dir = direction

    def stop(self) -> None:
        """Pulses stop at once (PSOFF, FUN142, 001:62)."""
        self._send(0.0, 1)
        self.status.freq = 0.0

    def _run(self, freq: float, direction: int, count: int, until: Callable[[], bool] | None,
             timeout_ns: int | None, counted: bool = True) -> bool:
        """Output a segment; True when `until` (or abort) ended it early."""
        self._send(freq, direction, count, counted=counted)
        if count:
            dur = math.ceil(count * S / freq)
        else:
            dur = timeout_ns if timeout_ns is not None else 3600 * S
        if timeout_ns is not None:
            dur = min(dur, timeout_ns)
        pred = (lambda: self._abort or until()) if until else (lambda: self._abort)
        # EXT and abort act at once (001:28): on the wall clock the lines are looked at every
        # 0.2 ms (a PLC scan), not at the 2 ms default of a harness wait
        hit = clock.wait_for(pred, dur / S, poll_s=EXT_POLL_S)
        self._close_segment()
        return bool(hit)

    # -- moves -------------------------------------------------------------------------
    def move(self, segments: list[tuple[int, float]], direction: int,
             until: Callable[[], bool] | None = None, limit_ns: int | None = None) -> bool:
        """A DRV / DRVC chain of (pulses, Ps/s); True when `until` or abort cut it short.
        The remaining pulses are then in `status.remaining` (DR4072, 001:44). `limit_ns`:
        the time the move may take at most (planned no further, `plan_profile`)."""
        p = self.p
        if self._last_dir and direction != self._last_dir and p.backlash:
            self._run(min(p.start_speed_pps * 10, p.max_speed_pps), direction, p.backlash,
                      None, None, counted=False)  # P7 on a reversal (001:56)
        total = sum(n for n, _ in segments)
        slices = plan_profile(segments, p.start_speed_pps, p.accel, p.decel, self.slice_ns,
                              limit_ns)
        done = 0
        self.status.remaining = total
        for dur, n in slices:
            freq = n * S / dur
            start = self.status.position
            cut = self._run(freq, direction, n, until, None)
            done += abs(self.status.position - start)
            self.status.remaining = total - done
            if cut:
                self.stop()
                return True
        self.status.freq = 0.0
        return False

    def ramp_run(self, v_from: float, v_to: float, direction: int,
                 until: Callable[[], bool], timeout_s: float) -> bool:
        """Ramp from `v_from` to `v_to` (P8 slope, `slice_ms` steps), then run at `v_to`
        until `until()`; False on timeout."""
        p = self.p
        slope = p.accel if v_to >= v_from else p.decel
        end = clock.monotonic_ns() + round(timeout_s * S)
        if math.isfinite(slope) and v_from != v_to:
            t_ramp = abs(v_to - v_from) / slope
            n = max(1, math.ceil(t_ramp * S / self.slice_ns))
            for k in range(1, n + 1):
                v = v_from + (v_to - v_from) * k / n
                if self._run(v, direction, 0, until, round(t_ramp * S / n)):
                    return True
        left = end - clock.monotonic_ns()
        return left > 0 and self._run(v_to, direction, 0, until, left)

    def ramp_stop(self, v: float, direction: int, slope: float | None = None) -> None:
        """Decelerate from `v` to the start speed (P12, or P8 when P12 = 0; `slope` instead
        if given) and stop."""
        p = self.p
        v0 = min(p.start_speed_pps, v)
        slope = p.decel if slope is None else slope
        if math.isfinite(slope) and v > v0:
            t = (v - v0) / slope
            n = max(1, math.ceil(t * S / self.slice_ns))
            for k in range(1, n + 1):
                self._run(v + (v0 - v) * k / n, direction, 0, None, round(t * S / n))
        self.stop()

    # -- DRVZ ----------------------------------------------------------------------------
    def home(self, mode: str, speed: float, timeout_s: float) -> None:
        """DRVZ MD0 / MD1 / MD2 (001:108-124). Raises TimeoutError when no zero is found."""
        p = self.p
        # P9-1 names the count's direction (001:58): P9-0 = 1 reverses the pulses for it
        hd = -p.home_sign if p.run_direction else p.home_sign
        v0 = min(p.start_speed_pps, speed)
        creep = p.speed(p.creep_speed)
        self.status.homed, self.status.drvz = False, mode
        self._report("drvz")
        deadline = clock.monotonic_ns() + round(timeout_s * S)

        def left() -> float:
            s = (deadline - clock.monotonic_ns()) / S
            if s <= 0:
                self.stop()
                raise TimeoutError(f"DRVZ {mode}: no zero point within {timeout_s:g} s")
            return s

        # start on or in front of DOG (001:118): to the stroke limit, back through DOG
        if self.dog() or (p.limit and self.at_limit()):
            self._front_of_dog(hd, speed, v0, left)
            self.ramp_run(v0, speed, hd, self.dog, left())
        else:
            hit = self.ramp_run(v0, speed, hd, lambda: self.dog() or self.at_limit(), left())
            if not hit:
                left()
            if not self.dog():  # the stroke limit came first: we started in front of DOG
                self.stop()
                self._front_of_dog(hd, speed, v0, left)
                self.ramp_run(v0, speed, hd, self.dog, left())
        # DOG is on, moving in the homing direction at `speed`
        if mode == "MD0":  # at DOG at once to the creep speed (001:110, 122)
            self._run(creep, hd, 0, lambda: not self.dog(), round(left() * S))
        elif mode == "MD1":  # "以加減速時間設定 (參數 8) 之斜率減速停止" (001:112): P8, not P12
            # "由目前速度": from the speed it has when DOG comes, which may be part-way up
            # its ramp, not the homing speed
            self.ramp_stop(self.status.freq or speed, hd, p.accel)
            clock.sleep(MD1_WAIT_NS / S)
            if not self.dog():  # the P8 stop ran past DOG: back into it first (a choice)
                self._run(creep, -hd, 0, self.dog, round(left() * S))
            self._run(creep, -hd, 0, lambda: not self.dog(), round(left() * S))
        else:
            if p.pg0_edge == "leading":  # at DOG at once to the creep speed (001:114)
                self._oz = 0
                goal = p.zero_count
                self._run(creep, hd, 0, lambda: self._oz >= goal, round(left() * S))
            else:
                self._run(creep, hd, 0, lambda: not self.dog(), round(left() * S))
                self._oz = 0
                goal = p.zero_count
                self._run(creep, hd, 0, lambda: self._oz >= goal, round(left() * S))
        left()
        self.stop()  # the zero point: pulses stop at once (PSOFF, 001:62)
        self.status.zero_found_ns = clock.monotonic_ns()
        self._report("zero")
        if p.clr:  # CLR > 20 ms, homing completes after it (001:122-124)
            self.port.set(p.clr, True)
            clock.sleep(p.clr_ms / 1000.0)
            self.port.set(p.clr, False)
        self.status.position = p.origin  # P16 into DR4088 (001:122)
        self.status.homed = True
        self._report("homed")

    def _front_of_dog(self, hd: int, speed: float, v0: float,
                      left: Callable[[], float]) -> None:
        """To the stroke limit at homing speed in the homing direction `hd` (P9-1, with P9-0
        applied), then back until DOG goes 1 -> 0 (001:118); the ramp goes on through DOG
        (the speed never jumps to the homing speed)."""
        p = self.p
        if p.limit and not self.at_limit():
            self.ramp_run(v0, speed, hd, self.at_limit, left())
        self.stop()
        if not self.dog():
            self.ramp_run(v0, speed, -hd, self.dog, left())
        if not self.ramp_run(self.status.freq or v0, speed, -hd, lambda: not self.dog(),
                             left()):
            left()
        self.stop()

    # -- the program ---------------------------------------------------------------------
    def _op(self, op: Operand, bits: int = 32) -> float:
        """An operand's value now: the constant, or what its register holds."""
        if isinstance(op, str):
            return read_register(op, self.registers, self.status, bits)
        return op

    def _seconds(self, op: Operand) -> float:
        """WAIT TIME / ACT in s: a register counts 0.01 s (001:42)."""
        return self._op(op, 16) * TIME_UNIT_S if isinstance(op, str) else float(op)

    def _speed(self, program: Program, s: Step, i: int, left: float) -> float:
        """SPD in Ps/s; from a register holding 0 the step waits until it is not 0
        (001:38), then its value is checked as a constant's (error 31)."""
        op = s.spd
        assert op is not None
        if isinstance(op, str) and self._op(op) == 0 \
                and not clock.wait_for(lambda: self._op(op) != 0, left):
            raise TimeoutError(f"SPD {op} stayed 0: the step waited for a speed (001:38)")
        v = self._op(op)
        if isinstance(op, str):
            program.check_speed(self.p, v, i, via=op)
        return self.p.speed(v)

    def run(self, program: Program, timeout_s: float = 60.0, *,
            log: Callable[[str], None] | None = None,
            registers: dict[str, int] | None = None) -> Status:
        """Run `program` from step 1 until MD or its last step (001:26-44). `registers`:
        the data registers its operands read (unset ones hold 0)."""
        program.check(self.p)
        self.registers = program.check_registers(self.p, registers or {})
        st = self.status
        st.ready, st.done, st.error = False, False, 0
        deadline = clock.monotonic_ns() + round(timeout_s * S)
        steps = program.steps
        i = 0
        spd: float | None = None
        instant, seen = clock.monotonic_ns(), set()  # steps run in this instant of time
        try:
            while 0 <= i < len(steps):
                now = clock.monotonic_ns()
                if now != instant:
                    instant, seen = now, set()
                if i in seen:  # back at a step with no time passed: the GOTOs loop for ever
                    raise TimeoutError(f"step {i + 1} is reached again by GOTO with no time "
                                       "passed: the program loops without end")
                seen.add(i)
                s = steps[i]
                st.step = i + 1
                self._report("step")
                if s.end:
                    break
                left = (deadline - clock.monotonic_ns()) / S
                if left <= 0:
                    raise TimeoutError(f"program timeout {timeout_s:g} s at step {i + 1}")
                if s.spd is not None:
                    spd = self._speed(program, s, i + 1, left)
                if isinstance(s.drive, Drv):
                    chain = [(s, spd)]
                    while chain[-1][0].drive.chained and i + 1 < len(steps):
                        i += 1
                        nxt = steps[i]
                        if nxt.spd is not None:
                            spd = self._speed(program, nxt, i + 1, left)
                        chain.append((nxt, spd))
                    s = chain[-1][0]
                    self._drive(chain, s, left)
                elif isinstance(s.drive, str):
                    try:
                        self.home(s.drive, spd or self.p.max_speed_pps, left)
                    except BaseException:
                        self.status.drvz = ""  # no homing runs any more: none completed
                        raise
                    self._transition_after(s, max(0.0, (deadline - clock.monotonic_ns()) / S))
                else:
                    self._transition_after(s, left)
                if self._abort:
                    break
                if s.goto is None:
                    i += 1
                else:
                    goto = int(self._op(s.goto, 16))
                    if isinstance(s.goto, str):
                        program.check_goto(goto, i + 1, via=s.goto)
                    i = goto - 1
                st.done = True  # DN stays on until cleared (001:26)
                self._report("done")
        except BaseException as e:
            self.stop()
            st.ready = True
            if isinstance(e, PlcError):
                st.error = e.code  # R4060 keeps the latest error code (001:34)
            self._report("error")
            raise
        st.ready = True
        st.freq = 0.0
        self._report("end")
        if log:
            log(f"PLC program ended at step {st.step}, position {st.position}")
        return st

    def _drive(self, chain: list[tuple[Step, float | None]], last: Step, left: float) -> None:
        first = chain[0][0].drive
        assert isinstance(first, Drv)
        pos = self.status.position
        segs: list[tuple[int, float]] = []
        direction = 0
        values = []
        for s, _spd in chain:  # each stroke as its register holds it now
            d = s.drive
            assert isinstance(d, Drv)
            v = self._op(d.value)
            if isinstance(d.value, str):
                Program.check_stroke(self.p, d, v, self.status.step, via=d.value)
            values.append(v)
        for k, (s, spd) in enumerate(chain):
            d = s.drive
            assert isinstance(d, Drv)
            n = self.p.pulses(values[k], d.unit)
            if k == 0 and d.mode == "ABS":
                n = n - pos
            elif d.direction == "-":
                n = -abs(n)
            elif d.direction == "+":
                n = abs(n)
            if k == 0:
                direction = 1 if n >= 0 else -1
            segs.append((abs(n), spd or self.p.max_speed_pps))
        if self.p.run_direction:
            direction = -direction
        segs = [(n, v) for n, v in segs if n > 0]
        ext = last.ext
        act_ns = round(self._seconds(last.act) * S) if last.act is not None else None
        t0 = clock.monotonic_ns()
        if ext:
            until = lambda: self.port.get(ext)  # noqa: E731 - EXT (001:42-44)
        elif act_ns is not None:
            until = lambda: clock.monotonic_ns() - t0 >= act_ns  # noqa: E731 - ACT
        else:
            until = None
        if len(chain) == 1 and self.p.pulses(values[0], first.unit) == 0 and not (
                first.mode == "ABS" and self.p.abs_zero == "position"):
            # stroke 0: run until the transition (001:38)
            v = chain[0][1] or self.p.max_speed_pps
            direction = -1 if first.direction == "-" else 1
            if self.p.run_direction:
                direction = -direction
            hit = self.ramp_run(self.p.start_speed_pps, v, direction,
                                until or (lambda: False), left)
            self.stop()
            if not hit:  # it runs until execute goes off (001:38): the program did not end
                raise TimeoutError(f"a stroke-0 move ran {left:g} s without its EXT/ACT "
                                   "transition")
            return
        # the program's time runs inside a move too: a DRV longer than it stops there (the
        # deadline had been looked at only between steps, so a 50 s move passed a 5 s limit)
        end = clock.monotonic_ns() + round(left * S)
        out_of_time = False

        def stop_at() -> bool:
            nonlocal out_of_time
            if until is not None and until():
                return True
            out_of_time = clock.monotonic_ns() >= end
            return out_of_time

        # planned past the program's time (by 2 slices, and by 1 s for the first pulse at
        # the lowest start speed), so the move reaches `end` still moving
        cut = self.move(segs, direction, stop_at,
                        limit_ns=round(left * S) + 2 * self.slice_ns + S)
        if not cut and self.status.remaining > 0:  # the plan ended short of the stroke: it
            out_of_time = True  # could only have run past the program's time
        if out_of_time:
            raise TimeoutError(f"program timeout: a move ran past the program's time ({left:g} "
                               f"s left at its start), {self.status.remaining} pulses short")
        if cut and ext:
            self._report("ext")  # the remaining pulses are abandoned (001:42-44)
        if not cut:  # the WAIT after a move has what the move left of the program's time
            self._transition_after(last, max(0.0, left - (clock.monotonic_ns() - t0) / S))

    def _transition_after(self, s: Step, left: float) -> None:
        """WAIT time / line, EXT as WAIT once the pulses are done (001:42-44)."""
        if s.wait_time is not None:
            wait = self._seconds(s.wait_time)
            if wait > left:
                clock.sleep(left)
                raise TimeoutError(f"WAIT {wait:g} s: longer than the program's time left "
                                   f"({left:g} s)")
            clock.sleep(wait)
        line = s.wait_line or s.ext
        if line and not clock.wait_for(lambda: self.port.get(line), left):
            raise TimeoutError(f"{'WAIT' if s.wait_line else 'EXT'} {line}: not on within "
                               "the program's time")

    def _report(self, what: str) -> None:
        if self.on_status is not None:
            self.on_status(self.status, what)
