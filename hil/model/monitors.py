"""Monitor variables of table 8.3 (L15440-15523) the rest of the model does not own, the
status monitor registers P0.009-P0.013 and P0.044 that read them, the mapping parameters
P0.025-P0.032 and P0.008's hours (L7129-7145).

Every reader of a monitor code goes through `Hooks.monitors` (P0.009-P0.013 by P0.017-
P0.021, P0.044 by P0.045, a PR WRITE's monitor source, monitor 123 by P0.002). Position codes
000-006 and 049 are the pulse train's, 037 COMPARE's, 038 the battery's, 043 CAPTURE's, 064
the PR engine's; the codes below are the drive's. What the virtual drive does not simulate
reads a nominal constant (`DC_BUS_V`, `IGBT_C`), said in docs/manual-choices.md; codes it has
nothing for at all stay unregistered: a P0.009 reads its stored 0, a PR WRITE raises AL231.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hil.model.errors import ModelError, OutOfRange
from hil.units import S, s32

DC_BUS_V = 311.0  # the rectified 220 V mains (√2 x 220 V): the model has no bus
IGBT_C = 40  # °C: the model has no thermal part
HOUR_NS = 3600 * S


class Monitors:
    """The drive's own monitor codes and the P0.008 hour counters of one drive."""

    def __init__(self, drive: Any) -> None:
        self.d = drive
        self._reading: set[int] = set()  # codes being read now: a loop reads 0 (`guarded`)
        self._on_ns = 0  # control power on, whole run (P0.008 low word)
        self._servo_ns = 0  # Servo On (high word)
        self._t = drive.sched.now  # the counters are up to date to this model time
        self.cn2 = AxisPositionCn2(drive)  # P5.016 (`attach_monitors` registers it)

    # -- P0.008 ----------------------------------------------------------------------------
    def account(self) -> None:
        """Bring the hour counters up to now (the drive calls it before power and servo
        changes; a read does too)."""
        d = self.d
        now = d.sched.now
        dt = now - self._t
        self._t = now
        if dt <= 0:
            return
        if d.powered:
            self._on_ns += dt
            if d.servo_on:
                self._servo_ns += dt

    def p0008(self) -> int:
        """High word Servo On hours, low word power-on hours; "未滿 1 小時不會紀錄" (L7139)."""
        self.account()
        on_h = min(self._on_ns // HOUR_NS, 0xFFFF)
        servo_h = min(self._servo_ns // HOUR_NS, 0xFFFF)
        return int(servo_h << 16 | on_h)

    # -- codes -----------------------------------------------------------------------------
    def codes(self) -> dict[int, Callable[[], int]]:
        d = self.d
        ax = d.axis
        p = d.params

        def tenths(x: float) -> int:
            return round(x * 10)

        opts = d.options

        def z_offset() -> int:
            """Position to the nearest Z, -4999 .. +5000 over a turn (L15462): the bench's Z
            is `index_angle` past every whole turn (`Mechanics.index_crossed`)."""
            cpr = ax.cpr
            z = d.mech.index_angle * cpr
            frac = ((d.feedback_counts() - z) % cpr) / cpr  # 0 .. 1 past the last Z
            off = round(frac * 10000)
            return off - 10000 if off > 5000 else off

        def panel() -> int:
            """What the panel shows: the code P0.002 selects (L15518)."""
            part = d.hooks.monitors.get(p.get("P0.002"))
            return part() if part is not None else 0

        def register(name: str) -> Callable[[], int]:
            return lambda: p.read(name)

        codes: dict[int, Callable[[], int]] = {
            7: lambda: tenths(ax.velocity_rpm),  # 0.1 rpm (L15447; no filter modelled)
            8: lambda: round(opts.analog_v_ref * 100),  # analog speed command, 0.01 V (L15448)
            9: lambda: tenths(ax.demand_rpm),  # 0.1 rpm (L15449)
            10: lambda: round(opts.analog_t_ref * 100),  # analog torque command, 0.01 V
            11: lambda: round(ax.torque_demand / 10),  # % (L15451)
            12: lambda: round(abs(ax.torque) / 10),  # load %: the torque (no 20 ms average)
            13: lambda: round(abs(ax.torque) / 10),  # peak load %: the same (L15453)
            14: lambda: round(DC_BUS_V),  # V (L15454)
            15: lambda: tenths(d.mech.load_inertia / d.mech.motor_inertia)  # (L15455)
            if d.mech.motor_inertia else 0,
            16: lambda: IGBT_C,  # °C (L15456)
            18: z_offset,
            # mapped parameters P0.025-P0.028 and mapped monitors P0.009-P0.012 (L15463-15470)
            **{19 + n: register(f"P0.{25 + n:03d}") for n in range(4)},
            **{23 + n: register(f"P0.{9 + n:03d}") for n in range(4)},
            39: register("P4.007"),  # the DIs as the drive sees them (L15478)
            40: register("P4.009"),  # the DOs as driven (L15479)
            41: register("P0.046"),  # drive status (L15480)
            50: lambda: tenths(ax.demand_rpm),  # 0.1 rpm (L15486)
            51: lambda: tenths(ax.velocity_rpm),  # instant speed, 0.1 rpm (L15487)
            53: lambda: round(ax.torque_demand),  # 0.1 % (L15488)
            54: lambda: round(ax.torque),  # torque feedback, 0.1 % (L15489)
            56: lambda: round(DC_BUS_V * 10),  # 0.1 V (L15491)
            72: lambda: tenths(opts.analog_v_ref * p.get("P1.040") / 10.0),  # 0.1 rpm (L15502)
            96: lambda: p.read("P0.000") & 0xFFFF,  # DSP version low word, CPLD 0 (L15511)
            123: panel,
        }
        return {code: self.guarded(code, fn) for code, fn in codes.items()}

    def guarded(self, code: int, fn: Callable[[], int]) -> Callable[[], int]:
        """`fn` reading 0 when it is read again while it is being read: a selection that
        loops (P0.002 = 23 with P0.017 = 123, say) reads 0 rather than recurse."""
        def read() -> int:
            if code in self._reading:
                return 0
            self._reading.add(code)
            try:
                return int(fn())
            finally:
                self._reading.discard(code)
        return read


MAPPING_REGISTERS = frozenset(f"P0.{n:03d}" for n in (*range(25, 33), *range(35, 43)))


class ParamMapping:
    """P0.025-P0.032, each mapped on the parameter(s) its P0.035-P0.042 names (L7326-7372):
    a high and a low word, each group digit C / Z and index BA / YX in hex (0x0203 = P2.003;
    digits D / U "無作用"); the same word twice is one 32-bit parameter, two words two 16-bit
    ones (the high word the first), a zero word no parameter (that half reads 0, a write
    leaves it). A read gives the targets, a write writes them at once (a target's refusal
    refuses it); a target must exist and may not be a mapping register itself (checked when
    P0.035-P0.042 is written). An unset target (0) leaves the register a plain value."""

    def __init__(self, drive: Any, i: int) -> None:
        self.d, self.reg, self.target = drive, f"P0.{25 + i:03d}", f"P0.{35 + i:03d}"
        self._busy = False  # inside `read`

    @staticmethod
    def word_name(word: int) -> str | None:
        word &= 0x0FFF  # D / U: no effect (L7335)
        return f"P{word >> 8 & 0xF}.{word & 0xFF:03d}" if word else None

    def check_target(self, _name: str, value: int) -> None:
        """Validator of P0.035-P0.042: each word names an existing parameter that is not a
        mapping register (a loop would never end)."""
        for word in (value >> 16 & 0xFFFF, value & 0xFFFF):
            name = self.word_name(word)
            if name is None:
                continue
            spec = self.d.params.table.spec(name)  # UnknownParameter for none (P0.034 ...)
            if spec.param in MAPPING_REGISTERS:
                raise OutOfRange(self.target, f"0x{word:04X} names {spec.param}, a mapping "
                                 "register (L7326-7440)")

    def _names(self) -> tuple[str | None, str | None] | None:
        v = self.d.params.get(self.target)
        hi, lo = self.word_name(v >> 16), self.word_name(v)
        return None if hi is None and lo is None else (hi, lo)

    def _split(self, value: int) -> list[tuple[str, int]]:
        names = self._names()
        if names is None:
            return []
        hi, lo = names
        table = self.d.params.table
        if hi == lo:  # one 32-bit parameter: its own signedness
            assert hi is not None
            return [(hi, value if table.spec(hi).min < 0 else value & 0xFFFFFFFF)]
        out = []
        for name, word in ((hi, value >> 16 & 0xFFFF), (lo, value & 0xFFFF)):
            if name is None:
                continue
            signed = table.spec(name).min < 0
            out.append((name, word - 0x10000 if signed and word & 0x8000 else word))
        return out

    def read(self, peek: bool = False) -> int:
        """The targets as one register value (`peek`: without their reads' side effects);
        a target list that loops back here reads 0 (a value a bench or an old file set
        before the check of P0.035-P0.042 could)."""
        names = self._names()
        p = self.d.params
        if names is None:
            return p.stored(self.reg)
        if self._busy:
            return 0
        self._busy = True
        try:
            get = p.peek if peek else p.read
            hi, lo = names
            if hi == lo:
                return s32(get(hi))  # the register is signed 32-bit (its CSV range)
            word = [get(n) & 0xFFFF if n is not None else 0 for n in (hi, lo)]
            return s32(word[0] << 16 | word[1])
        finally:
            self._busy = False

    def peek(self) -> int:
        return self.read(peek=True)

    def validate(self, _name: str, value: int) -> None:
        for name, word in self._split(value):  # a target refuses: the register does too
            self.d.params.check_write(name, word)

    def write(self, _name: str, _old: int, new: int) -> None:
        for name, word in self._split(new):
            self.d.params.write(name, word)


def _selected(drive: Any, reg: str, select: str) -> Callable[[], int]:
    """Register `reg` reading the monitor code its selector `select` names (L7147-7237): a
    code nothing models keeps the register's stored value."""
    def read() -> int:
        part = drive.hooks.monitors.get(drive.params.get(select))
        # a 32-bit register (L7150): a PUU count past 2^31 wraps as 6064h does (L16417)
        return s32(part()) if part is not None else drive.params.stored(reg)
    return read


class AxisPositionCn2:
    """P5.016 (L11280-11286): read, the CN2 feedback position, monitor 000 plus an offset;
    a write of any value only sets that offset, so that it reads back what was written,
    monitor 000 and the coordinates untouched ("只是為了調整一偏移值，方便觀察用"). The
    offset is the drive's RAM: a power cycle starts it at 0."""

    def __init__(self, drive: Any) -> None:
        self.d, self.offset = drive, 0

    def _fb_puu(self) -> int:
        part = self.d.hooks.monitors.get(0)  # monitor 000, Fb_PUU (L15440)
        return part() if part is not None else 0

    def read(self) -> int:
        return s32(self._fb_puu() + self.offset)

    def write(self, _name: str, _old: int, new: int) -> None:
        self.offset = new - self._fb_puu()


# the status monitor registers and their selectors: P0.009-P0.013 by P0.017-P0.021 (L7147-7237)
# and P0.044 by P0.045 ("同參數 P0.009 / P0.017", L7442-7458)
SELECTED = (*((f"P0.{9 + i:03d}", f"P0.{17 + i:03d}") for i in range(5)), ("P0.044", "P0.045"))


def attach_monitors(drive: Any) -> Monitors:
    """Register the drive's monitor codes, the status monitor registers, the mapping
    parameters and P0.008's hours."""
    mon = Monitors(drive)
    for code, fn in mon.codes().items():
        drive.hooks.monitors.setdefault(code, fn)
    for reg, select in SELECTED:
        drive.params.on_read(reg, _selected(drive, reg, select))
    for i in range(8):  # P0.025-P0.032 by P0.035-P0.042 (L7326-7440)
        m = ParamMapping(drive, i)
        drive.params.on_read(m.reg, m.read)
        drive.params.on_peek(m.reg, m.peek)  # a one-word Modbus write keeps the other half
        drive.params.on_validate(m.reg, m.validate)
        drive.params.on_write(m.reg, m.write)
        drive.params.on_validate(m.target, m.check_target)
        try:  # a value given before the check (a bench's params, an old parameter file)
            m.check_target(m.target, drive.params.stored(m.target))
        except ModelError:  # ... that names no parameter or a register: unmapped
            drive.params.set_internal(m.target, 0)
    drive.params.on_read("P0.008", mon.p0008)
    drive.params.on_read("P5.016", mon.cn2.read)
    drive.params.on_write("P5.016", mon.cn2.write)
    return mon
