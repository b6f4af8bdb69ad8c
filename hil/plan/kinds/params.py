"""Parameter access: `write` (optionally expecting the drive's refusal) and `read`."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.bench import virtual_rules
from hil.bench.param_rules import check_param, wire_range
from hil.bench.yamlio import Checker, LDict, join
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, StepKind
from hil.plan.session import LINE_ERRORS, line_error, refusal_code

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


@dataclass(frozen=True)
class WriteArgs:
    values: dict[str, int]  # parameter -> value
    via: str | None  # sdo | modbus | None (the bench's route)
    expect_error: int | None = None  # the refusal code the drive must answer


@dataclass(frozen=True)
class ReadArgs:
    values: dict[str, int | None]  # parameter -> expected value (None: only record)
    via: str | None
    expect_error: str | None = None  # a line error (timeout, bad_reply, comm_error)


class Write(StepKind):
    """`write: {P1.042: 150, via: sdo}`; with `expect_error:` the write must be refused."""

    name = "write"
    args: WriteArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> WriteArgs:
        m = v.mapping(obj, line, where)
        via = fields.parse_via(v, m, where)
        plain = {k: x for k, x in m.items() if k != "expect_error"}
        fm = LDict(plain)
        fm.line, fm.key_lines = m.line, m.key_lines
        if "expect_error" in m:
            fm["expect_error"] = m["expect_error"]  # seen by param_values: no range rule
        values = fields.param_values(v, fm, where, False, write=True)
        if "expect_error" not in m:
            return WriteArgs(values, via)
        fw = join(where, "expect_error")
        code = m["expect_error"]
        if isinstance(code, bool) or not isinstance(code, int) or code <= 0:
            raise v.err(m.kline("expect_error"), fw, f"{code!r}: the refusal code, a "
                        "Modbus exception code (e.g. 3) or an SDO abort code (e.g. "
                        "0x06090031)")
        if len(values) != 1:
            raise v.err(m.kline("expect_error"), fw, "one parameter per refused write "
                        f"(got {', '.join(values)})")
        fields.check_expect_error(v, m.kline("expect_error"), fw, code, via)
        return WriteArgs(values, via, code)

    def check(self, cc: CheckContext) -> None:
        fields.check_via(cc, "", self.args.via)
        raw = cc.step.raw.get(self.name)
        if cc.bench.virtual and self.args.expect_error is None:
            for k, val in self.args.values.items():
                if why := virtual_rules().inert_mapping(k, val):  # the virtual drive refuses
                    line = raw.kline(k) if hasattr(raw, "kline") else cc.step.line
                    raise cc.err(f"0x{val:04X} maps {why}; on a virtual bench a write that "
                                 "expects the refusal needs expect_error (0x06090030 / 3)", k,
                                 line=line)
        if self.args.expect_error is not None:
            via = self.args.via or cc.drive.param_via
            line = raw.kline("expect_error") if hasattr(raw, "kline") else cc.step.line
            fields.check_expect_error(cc.v, line, join(cc.field, "expect_error"),
                                 self.args.expect_error, via)
            for k, val in self.args.values.items():  # the refusal must be the drive's
                lo, hi = wire_range(k, via)
                if val is not None and not lo <= val <= hi:
                    line = raw.kline(k) if hasattr(raw, "kline") else cc.step.line
                    raise cc.err(f"{val} cannot be sent via {via}: {k} carries {lo}..{hi} "
                                 "there, so the drive would never see the write to refuse it",
                                 k, line=line)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        want = self.args.expect_error
        if want is not None:
            return Outcome(self._refused(d, want))
        for p, val in self.args.values.items():
            d.write_param(p, val, self.args.via)
            ctx.written(d.name, {p: val})
        return Outcome()

    def _refused(self, d: DriveIO, want: int) -> str:
        """A write the drive must refuse with `want` (Modbus exception / SDO abort code)."""
        [(p, val)] = self.args.values.items()
        via = self.args.via or d.spec.param_via
        what = "exception" if via == "modbus" else "abort"
        try:
            d.write_param(p, val, via)
        except Exception as e:
            got = refusal_code(e)
            if got is None:
                raise
            if got != want:
                raise StepFailed(f"{p} = {val} via {via}: refused with {what} 0x{got:X}, "
                                 f"expected 0x{want:X} ({e})") from None
            return f"{p} = {val} refused as expected: {e}"
        raise StepFailed(f"{p} = {val} via {via} was accepted; expected a refusal with {what} "
                         f"0x{want:X}")

    def describe(self) -> str:
        a = self.args
        vals = ", ".join(f"{p}={v}" for p, v in a.values.items())
        refused = f" refused 0x{a.expect_error:X}" if a.expect_error else ""
        via = f" via {a.via}" if a.via else ""  # none: the bench's `param_via`
        return f"write {vals}{via}{refused}"


class Read(StepKind):
    """`read: P0.001` or `read: {P1.042: 150}` (a value to expect, or null to only record);
    `expect_error: timeout | bad_reply | comm_error` (via modbus): the read must fail on the
    line as the harness master sees it, with no value (RS-485 faults, docs/faults.md)."""

    name = "read"
    args: ReadArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> ReadArgs:
        if isinstance(obj, str):
            if not fields.PARAM_RE.match(obj):
                raise v.err(line, where, f"{obj!r}: a parameter name like P1.042")
            check_param(v, line, where, obj, None, write=False)
            return ReadArgs({obj: None}, None)
        m = v.mapping(obj, line, where)
        values, via = fields.param_values(v, m, where, True), fields.parse_via(v, m, where)
        if "expect_error" not in m:
            return ReadArgs(values, via)
        fw = join(where, "expect_error")
        if m["expect_error"] not in LINE_ERRORS:
            raise v.err(m.kline("expect_error"), fw, f"{m['expect_error']!r}: one of "
                        f"{', '.join(LINE_ERRORS)} (the harness master's line errors)")
        if via != "modbus":
            raise v.err(m.kline("expect_error"), fw, "line errors need via: modbus")
        return ReadArgs(values, via, m["expect_error"])

    def check(self, cc: CheckContext) -> None:
        fields.check_via(cc, "", self.args.via)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        want = self.args.expect_error
        if want is not None:
            return Outcome(self._line_error(d, want))
        got, bad = [], []
        for p, want in self.args.values.items():
            val = d.read_param(p, self.args.via)
            got.append(f"{p} = {val}")
            if want is not None and val != want:
                bad.append(f"{p} = {val}, expected {want}")
        if bad:
            raise StepFailed("; ".join(bad))
        return Outcome(", ".join(got))

    def _line_error(self, d: DriveIO, want: str) -> str:
        """A read that must fail on the line with `want` (never return a value)."""
        names = ", ".join(self.args.values)
        try:
            vals = [d.read_param(p, self.args.via) for p in self.args.values]
        except Exception as e:
            got = line_error(e)
            if got is None:
                raise
            if want not in (got, "comm_error"):
                raise StepFailed(f"read {names}: {got} ({e}), expected {want}") from None
            return f"read {names}: {got} as expected: {e}"
        raise StepFailed(f"read {names} returned {vals}; expected {want} (a line fault "
                         "that lets a value through)")

    def describe(self) -> str:
        err = f" expecting {self.args.expect_error}" if self.args.expect_error else ""
        via = f" via {self.args.via}" if self.args.via else ""  # none: the bench's
        return f"read {', '.join(self.args.values)}{via}{err}"


KINDS = (Write, Read)
