"""A PLC's pulse positioning program on the drive's pulse line: `plc_program` (docs/pulse.md).

    - plc_program:
        axis: {max_speed: 100000, accel_ms: 200, creep_speed: 2000, dog: X0, clr: Y8}
        program:
          - {SPD: 50000, DRV: "ABS,,300000,Ps", WAIT: 100ms}
          - {SPD: 10000, DRVC: "ADR,+,20000,Ps"}
          - {SPD: 3000, DRV: "ADR,,5000,Ps"}
          - {SPD: 20000, DRVZ: MD1}
          - MD
        expect: {position: 325000, remaining: 0}

`axis:` is FUN141 (hil.drivers.plc_pulse.AxisParams field names), `program:` FUN140 steps
(SPD, DRV, DRVC, DRVZ, WAIT, ACT, EXT, GOTO, MD). What the PLC would refuse (its error codes
30-60 and parameter errors 1-15, seed 001:34, 74) is refused here with file:line.
`registers:` sets data registers (`{R1000: 5000, D100: -20000}`, 32 bits each) that SPD, DRV
strokes, WAIT / ACT times and GOTO may name instead of a constant (001:38-44).
"""

from __future__ import annotations

import dataclasses
import re
from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker, join, level, parse_duration
from hil.drivers.plc_pulse import (
    STATUS_REGISTERS,
    AxisParams,
    Drv,
    PlcError,
    Program,
    canonical_register,
    data_register,
    operand_register,
    register_words,
)
from hil.drivers.plc_pulse import Step as PlcStep
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds.base import CheckContext, StepKind
from hil.units import S

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

_STEP_KEYS = {"SPD", "DRV", "DRVC", "DRVZ", "WAIT", "ACT", "EXT", "GOTO"}
_X = re.compile(r"^[XMY](0|[1-9][0-9]{0,3})\Z")  # X00 / Y08 name no line: refused
_DRV = re.compile(r"^ *(ABS|ADR) *, *([+-]?) *, *(-?[0-9]+(?:\.[0-9]+)?|[A-Za-z]{1,2}[0-9]+)"
                  r" *, *(Ut|Ps) *\Z")  # spaces only: no tab or newline
# meant as a register (R1000, r1000, DR1000, R10000, R0500): checked by operand_register
_REG = re.compile(r"^[A-Za-z]{1,2}[0-9]+\Z")
_LINE_MAX = {"X": 255, "Y": 255, "M": 1911}  # 001:42
# what `expect:` may name, and what each holds (the PLC's status, hil.drivers.plc_pulse.Status)
_EXPECT = {"position": "int", "remaining": "int", "error": "int", "done": "bool",
           "freq": "number", "feedback": "int", "feedback_tol": "tolerance"}
_AXIS = {f.name: f for f in dataclasses.fields(AxisParams)}


def _axis(v: Checker, obj: Any, line: int, where: str) -> AxisParams:
    m = v.mapping(obj, line, where)
    v.keys(m, set(_AXIS), where)
    values: dict[str, Any] = {}
    for k, val in m.items():
        want = type(getattr(AxisParams(), k))
        ok = isinstance(val, want) and not (want is int and isinstance(val, bool))
        if want is float and isinstance(val, int) and not isinstance(val, bool):
            ok = True  # an int where a float goes: converted once it is in range
        if not ok:
            raise v.err(m.kline(k), join(where, k), f"{val!r}: {want.__name__} expected")
        if want in (int, float):
            if not abs(val) <= 1e12:  # NaN, inf, 10**400 (float() of it overflows)
                raise v.err(m.kline(k), join(where, k),
                            f"{repr(val)[:40]}: a number (finite, within ±1e12)")
            val = want(val)
        values[k] = val
    p = AxisParams(**values)
    try:
        p.check()
    except PlcError as e:
        raise v.err(m.kline(e.field) if e.field in m else line, join(where, e.field),
                    str(e)) from None
    return p


def _drv(v: Checker, text: Any, line: int, where: str, chained: bool) -> Drv:
    m = _DRV.match(text) if isinstance(text, str) else None
    if not m:
        raise v.err(line, where, f"{text!r}: write it as the PLC does, e.g. \"ABS,,300000,Ps\" "
                    "or \"ADR,+,200,Ut\" (mode ABS/ADR, direction +/-/blank, stroke, unit "
                    "Ut/Ps; error 43)")
    if m.group(1) == "ABS" and m.group(2):  # 001:38 lists ABS only with a blank direction:
        raise v.err(line, where, f"{text!r}: ABS takes no direction (the target's sign and "
                    "the current position give it, 001:38; error 43)")
    value = m.group(3)
    if _REG.match(value):
        reg = _register(v, value, line, where, 32, 32)
        return Drv(m.group(1), m.group(2), reg, m.group(4), chained)
    stroke = float(value)
    if not abs(stroke) <= 1e12:  # 309 digits and more are inf as a float (helper-139)
        raise v.err(line, where, f"{text[:60]!r}: a stroke within ±1e12")
    return Drv(m.group(1), m.group(2), stroke, m.group(4), chained)


TIME_UNIT_NS = 10 * 1_000_000  # TIME counts 0.01 s (001:42)
TIME_MAX = 65535  # a 16-bit count of them (a register operand holds one word, 001:42)


def _plc_time(ns: int) -> float:
    """A WAIT / ACT constant in s: whole 0.01 s counts of 0-65535 (001:42)."""
    if ns % TIME_UNIT_NS or not 0 <= ns // TIME_UNIT_NS <= TIME_MAX:
        raise ValueError(f"{ns / 1e6:g} ms: TIME counts 0.01 s, 0-655.35 s (001:42)")
    return ns / S


def _register(v: Checker, val: Any, line: int, where: str, code: int, bits: int = 16
              ) -> str | None:
    """The register `val` names (`R0500` is R500), if a step may read it with `bits`; None
    if `val` is no register name. SPD and strokes read a pair (32 bits, 001:38)."""
    if not isinstance(val, str) or not _REG.match(val):
        return None
    reg = canonical_register(val)
    if reg is None or not operand_register(reg, bits):
        pair = " and the next register, its high word," if bits == 32 else ""
        raise v.err(line, where, f"{val}: not a register{pair} (R0-R3839, R5000-R8071, "
                    f"D0-D3999 or a status register {', '.join(STATUS_REGISTERS)}; "
                    f"error {code})")
    return reg


def _registers(v: Checker, obj: Any, line: int, where: str) -> dict[str, int]:
    """`registers:` the data registers a program reads: 32-bit values, each taking its
    register and the next (the low and the high word, 001:38)."""
    m = v.mapping(obj, line, where)
    out: dict[str, int] = {}
    for k, val in m.items():
        name, at = str(k), join(where, str(k))
        reg = canonical_register(name)
        if reg in STATUS_REGISTERS:
            raise v.err(m.kline(k), at, f"{name} is the PLC's status, not set by a plan")
        if reg is None or not data_register(reg):
            raise v.err(m.kline(k), at, f"{name!r}: a data register R0-R3839, R5000-R8071 "
                        "or D0-D3999")
        if not isinstance(val, int) or isinstance(val, bool) or not -(2**31) <= val < 2**32:
            raise v.err(m.kline(k), at, f"{val!r}: a whole number of 16 or 32 bits")
        if reg in out:
            raise v.err(m.kline(k), at, f"{name} is {reg}, set above" if name != reg
                        else f"{reg} is set above (as a name with leading zeros)")
        try:  # 0-65535 is one word; a negative or larger value its register and the next
            register_words({**out, reg: val})
        except ValueError as e:
            raise v.err(m.kline(k), at, str(e)) from None
        out[reg] = val
    return out


def _expect_value(v: Checker, val: Any, line: int, where: str, kind: str) -> None:
    """An `expect:` value of the kind its status field holds."""
    if kind == "bool":
        if not isinstance(val, bool):
            raise v.err(line, where, f"{val!r}: true or false")
        return
    number = isinstance(val, int | float) and not isinstance(val, bool)
    if not number or not abs(val) <= 1e12:  # NaN, inf and a 400-digit int too
        raise v.err(line, where, f"{repr(val)[:40]}: a number (finite, within ±1e12)")
    if kind == "int" and val != int(val):
        raise v.err(line, where, f"{val!r}: a whole number (the PLC counts pulses)")
    if kind == "tolerance" and val < 0:
        raise v.err(line, where, f"{val!r}: a tolerance, 0 or more")


def _line_name(v: Checker, val: Any, line: int, where: str) -> str:
    if not isinstance(val, str) or not _X.match(val):
        raise v.err(line, where, f"{val!r}: a PLC line like X3 (error 34)")
    if int(val[1:]) > _LINE_MAX[val[0]]:
        raise v.err(line, where, f"{val}: X0-X255, Y0-Y255 or M0-M1911 (001:42; error 34)")
    return val


def _step(v: Checker, obj: Any, line: int, where: str) -> PlcStep:
    if obj == "MD":
        return PlcStep(end=True, line=line)
    m = v.mapping(obj, line, where)
    unknown = sorted(set(m) - _STEP_KEYS)
    if unknown:
        raise v.err(m.kline(unknown[0]), join(where, unknown[0]),
                    f"not a FUN140 sub-command (error 34); known: "
                    f"{', '.join(sorted(_STEP_KEYS))}, MD")
    s = PlcStep(line=line)
    if "SPD" in m:
        val = m["SPD"]
        reg = _register(v, val, m.kline("SPD"), join(where, "SPD"), 30, 32)
        if reg is not None:
            s.spd = reg
        elif (not isinstance(val, int | float) or isinstance(val, bool)
              or not abs(val) <= 1e12 or not float(val).is_integer()):
            # the program holds a speed as a whole 32-bit number, Hz or cm/min (001:38)
            raise v.err(m.kline("SPD"), join(where, "SPD"),
                        f"{repr(val)[:40]}: a whole number (Ps/s, or cm/min with P0 = 0; "
                        "within ±1e12) or a register (error 31)")
        else:
            s.spd = float(val)
    drives = [k for k in ("DRV", "DRVC", "DRVZ") if k in m]
    if len(drives) > 1:
        raise v.err(line, where, f"one drive command per step, not {' and '.join(drives)} "
                    "(error 34)")
    if "DRV" in m or "DRVC" in m:
        k = drives[0]
        s.drive = _drv(v, m[k], m.kline(k), join(where, k), chained=k == "DRVC")
    elif "DRVZ" in m:
        s.drive = str(m["DRVZ"])
    trans = [k for k in ("WAIT", "ACT", "EXT") if k in m]
    if len(trans) > 1:
        raise v.err(line, where, f"one transition per step, not {' and '.join(trans)} "
                    "(error 34)")
    if "WAIT" in m:
        val = m["WAIT"]
        reg = (None if isinstance(val, str) and _X.match(val)  # a line: X, Y, M
               else _register(v, val, m.kline("WAIT"), join(where, "WAIT"), 34))
        if reg is not None:
            s.wait_time = reg  # TIME from a register, 0.01 s (001:42)
        elif isinstance(val, str) and _X.match(val):
            s.wait_line = _line_name(v, val, m.kline("WAIT"), join(where, "WAIT"))
        else:
            try:
                s.wait_time = _plc_time(parse_duration(val))
            except ValueError as e:
                raise v.err(m.kline("WAIT"), join(where, "WAIT"),
                            f"a time (e.g. 500ms) or a line (X3): {e}") from None
    if "ACT" in m:
        reg = _register(v, m["ACT"], m.kline("ACT"), join(where, "ACT"), 34)
        if reg is not None:
            s.act = reg
        else:
            try:
                s.act = _plc_time(parse_duration(m["ACT"]))
            except ValueError as e:
                raise v.err(m.kline("ACT"), join(where, "ACT"), str(e)) from None
    if "EXT" in m:
        s.ext = _line_name(v, m["EXT"], m.kline("EXT"), join(where, "EXT"))
    if "GOTO" in m:
        val = m["GOTO"]
        reg = _register(v, val, m.kline("GOTO"), join(where, "GOTO"), 34)
        if reg is not None:
            s.goto = reg
        elif val != "NEXT":
            if not isinstance(val, int) or isinstance(val, bool):
                raise v.err(m.kline("GOTO"), join(where, "GOTO"),
                            f"{val!r}: NEXT, a step number or a register (error 34)")
            s.goto = val
    return s


@dataclasses.dataclass(frozen=True)
class PlcProgramArgs:
    axis: AxisParams
    program: Program
    timeout: int  # ns
    expect: dict[str, Any]  # status fields to expect at the end
    slice_ms: float  # the PLC's scan slice
    registers: dict[str, int] = dataclasses.field(default_factory=dict)  # data registers


@dataclasses.dataclass(frozen=True)
class PlcOutputArgs:
    levels: dict[str, bool]  # PLC output -> level


class PlcProgram(StepKind):
    """`plc_program: {axis, program, timeout, expect, slice}`: run a FUN140 program."""

    name = "plc_program"
    args: PlcProgramArgs
    motion = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PlcProgramArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"axis", "program", "timeout", "expect", "slice", "registers"}, where)
        axis = (_axis(v, m["axis"], m.kline("axis"), join(where, "axis")) if "axis" in m
                else AxisParams())
        if "program" not in m:
            raise v.err(line, where, "needs `program:` (FUN140 steps)")
        items = v.seq(m["program"], m.kline("program"), join(where, "program"))
        lines = getattr(items, "item_lines", None) or [m.kline("program")] * len(items)
        steps = [_step(v, it, lines[i], join(where, f"program[{i}]"))
                 for i, it in enumerate(items)]
        prog = Program(steps)
        regs = (_registers(v, m["registers"], m.kline("registers"), join(where, "registers"))
                if "registers" in m else {})
        try:
            prog.check(axis)
            prog.check_registers(axis, regs)
        except PlcError as e:
            s = steps[e.step - 1] if e.step else None
            fld = join(where, f"program[{e.step - 1}]") if e.step else join(where, "program")
            raise v.err(s.line if s else m.kline("program"),
                        join(fld, e.field) if e.field else fld, str(e)) from None
        timeout = v.duration(m, "timeout", where, 60 * S)
        slice_ns = v.duration(m, "slice", where, 10_000_000)
        if not 1_000_000 <= slice_ns <= 1_000_000_000:
            raise v.err(m.kline("slice"), join(where, "slice"), "1ms ~ 1s")
        expect: dict[str, Any] = {}
        if "expect" in m:
            e = v.mapping(m["expect"], m.kline("expect"), join(where, "expect"))
            v.keys(e, set(_EXPECT), join(where, "expect"))
            for k, val in e.items():
                _expect_value(v, val, e.kline(k), join(join(where, "expect"), k), _EXPECT[k])
            if e.get("error", 0) != 0:  # a program the PLC would refuse is refused here
                raise v.err(e.kline("error"), join(join(where, "expect"), "error"),
                            f"{e['error']}: R4060 reads 0 at the end of a program that "
                            "ran: a program or parameter the PLC refuses with an error code "
                            "is refused by --check with that code, and a status register "
                            "read as an operand that it refuses fails the step with it "
                            "(docs/pulse.md)")
            expect = dict(e)
        return PlcProgramArgs(axis, prog, timeout, expect, slice_ns / 1e6, regs)

    def check(self, cc: CheckContext) -> None:
        if not cc.drive.pulse:
            raise cc.err(f"drive {cc.dname} has no pulse line (bench `pulse:`)")

    def own_timeout_ns(self, step: Step, bench: Any) -> int | None:
        """The program's timeout, written or its 60 s default: a program that runs out of it
        fails saying where, before the step's watchdog (the bench's 60 s step timeout had
        fired at the same instant, a harness error, helper-139)."""
        return self.args.timeout

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        plc = d.plc(a.axis, a.slice_ms)
        plc._abort = False
        rec = ctx.rec
        topic = f"/plc/{d.name}/status"

        def on_status(st: Any, what: str) -> None:
            if rec is not None:
                rec.write(topic, {"event": what, "step": st.step, "ready": st.ready,
                                  "done": st.done, "position": st.position,
                                  "remaining": st.remaining, "error": st.error,
                                  "homed": st.homed, "drvz": st.drvz})
        plc.on_status = on_status
        cancel = getattr(ctx, "cancel", None)
        try:
            st = plc.run(a.program, a.timeout / S, registers=a.registers)
        except (TimeoutError, PlcError) as e:  # PlcError: a status register's value, R4060
            raise StepFailed(f"PLC program: {e}") from None
        finally:
            if cancel is not None and cancel.is_set():
                plc.stop()
        seen = {"position": st.position, "remaining": st.remaining, "error": st.error,
                "done": st.done, "freq": st.freq, "feedback": st.feedback}
        want = dict(a.expect)
        tol = want.pop("feedback_tol", 0)
        bad = [f"expected {k} {w!r}, PLC shows {seen[k]!r}" for k, w in want.items()
               if (abs(seen[k] - w) > tol if k == "feedback" else seen[k] != w)]
        text = (f"PLC at step {st.step}: position {st.position} Ps, remaining "
                f"{st.remaining}, output {plc.total} pulses, OA/OB counter {st.feedback}")
        if bad:
            raise StepFailed("; ".join(bad) + f" ({text})")
        return Outcome(text)

    def describe(self) -> str:
        n = len(self.args.program.steps)
        return f"plc_program ({n} steps)"


class PlcOutput(StepKind):
    """`plc_output: {Y8: on}`: the PLC's ladder sets its outputs on the pulse line (CLR)."""

    name = "plc_output"
    args: PlcOutputArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PlcOutputArgs:
        m = v.mapping(obj, line, where)
        if not m:
            raise v.err(line, where, "name at least one PLC output, e.g. Y8: on")
        out: dict[str, bool] = {}
        for k, val in m.items():
            # the program's own rule (_X): Y08 names no line (a leading 0), so it is refused
            # here too, not recorded on a line nothing is wired to
            if (not isinstance(k, str) or not _X.match(k) or k[0] != "Y"
                    or int(k[1:]) > _LINE_MAX["Y"]):
                raise v.err(m.kline(k), join(where, str(k)),
                            f"{k!r}: a PLC output Y0 ~ Y{_LINE_MAX['Y']} (001:42), like Y8 "
                            "(no leading 0)")
            lv = level(val)
            if lv is None:
                raise v.err(m.kline(k), join(where, str(k)), f"{val!r}: on or off")
            out[str(k)] = lv
        return PlcOutputArgs(out)

    def check(self, cc: CheckContext) -> None:
        if not cc.drive.pulse:
            raise cc.err(f"drive {cc.dname} has no pulse line (bench `pulse:`)")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        if d.pulse is None:
            raise StepFailed(f"drive {d.name}: no pulse line")
        for k, lv in self.args.levels.items():
            d.pulse.set(k, lv)
        return Outcome()

    def describe(self) -> str:
        return "plc_output " + ", ".join(f"{k}={'on' if v else 'off'}"
                                         for k, v in self.args.levels.items())


KINDS = (PlcProgram, PlcOutput)
