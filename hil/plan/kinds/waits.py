"""Time and conditions: `wait`, `wait_until` (poll until met or timeout), `expect` (now)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import Checker, parse_duration
from hil.drivers.cia402 import decode_state
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, StepKind
from hil.plan.kinds.fields import Condition
from hil.units import fmt_ms

if TYPE_CHECKING:
    from hil.bench.bench import Bench
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


def evaluate(d: DriveIO, c: Condition) -> tuple[bool, str]:
    """(met, what was observed) for one condition."""
    if c.kind == "do":
        v = d.do_active(c.key)
        return v == c.value, f"{c.key} {'on' if v else 'off'}"
    if c.kind == "fdbk":
        v = d.line("FDBK")
        return v == c.value, f"FDBK {'closed' if v else 'open'}"
    if c.kind == "state":
        sw = d.cia.statusword
        st = decode_state(sw)
        return st == c.value, f"{st} (statusword 0x{sw:04X})"
    if c.kind == "param":
        v = d.read_param(c.key, c.via)
        return v == c.value, f"{c.key} = {v}"
    a = d.alarm(c.via)
    return a == c.value, f"alarm {a or 'none'}"


@dataclass(frozen=True)
class WaitArgs:
    duration: int  # ns


@dataclass(frozen=True)
class ConditionArgs:
    conditions: list[Condition]
    timeout: int | None = None  # ns (wait_until; None: the bench's timeout)


class Wait(StepKind):
    """`wait: 200ms`."""

    name = "wait"
    args: WaitArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> WaitArgs:
        try:
            d = parse_duration(obj)
        except ValueError as e:
            raise v.err(line, where, str(e)) from None
        return WaitArgs(d)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        ctx.sleep(self.args.duration)
        return Outcome()

    def describe(self) -> str:
        return f"wait {fmt_ms(self.args.duration)}ms"

    def own_timeout_ns(self, step: Step, bench: Bench) -> int | None:
        return self.args.duration or None

    def imposed_ns(self) -> int:
        return self.args.duration


class _Conditions(StepKind):
    args: ConditionArgs

    def check(self, cc: CheckContext) -> None:
        d, dname = cc.drive, cc.dname
        for c in self.args.conditions:
            if c.kind == "do" and c.key not in d.do:
                raise cc.err(f"drive {dname} has no DO wired to {c.key} (wired: "
                             f"{', '.join(d.do) or 'none'})", f"do.{c.key}")
            if c.kind == "fdbk" and not d.dio:
                raise cc.err(f"drive {dname} has no DI/DO lines", "fdbk")
            if c.kind == "state" and not d.can:
                raise cc.err(f"drive {dname} has no CAN bus", "state")
            if c.kind in ("param", "alarm"):
                fields.check_via(cc, c.kind, c.via)

    def describe(self) -> str:
        return f"{self.name} " + " and ".join(c.describe() for c in self.args.conditions)


class WaitUntil(_Conditions):
    """`wait_until: {do: {BRKR: off}, timeout: 1s}`: poll until every condition holds."""

    name = "wait_until"

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> ConditionArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, fields.COND_KEYS | {"timeout"}, where)
        conditions = fields.conditions(v, m, where)
        timeout = v.duration(m, "timeout", where) if "timeout" in m else None
        if timeout is not None and timeout <= 0:  # 0 fell back to the bench's, unsaid
            raise v.err(m.kline("timeout"), f"{where}.timeout", "must be > 0")
        return ConditionArgs(conditions, timeout)

    def own_timeout_ns(self, step: Step, bench: Bench) -> int | None:
        return self.args.timeout or bench.timeouts["wait_until"]  # its own, or the bench's

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        conds = self.args.conditions
        timeout = self.args.timeout or ctx.bench.timeouts["wait_until"]
        polls_bus = any(c.kind in ("param", "alarm", "state") for c in conds)
        poll = 10_000_000 if polls_bus else 1_000_000
        t0 = clock.monotonic_ns()
        while True:
            seen = [evaluate(d, c) for c in conds]
            if all(ok for ok, _ in seen):
                return Outcome(f"met after {(clock.monotonic_ns() - t0) / 1e6:.1f} ms")
            left = timeout - (clock.monotonic_ns() - t0)
            if left <= 0:
                want = " and ".join(c.describe() for c in conds)
                saw = ", ".join(obs for _, obs in seen)
                raise StepFailed(f"timeout {timeout / 1e6:g} ms waiting for {want}; saw {saw}")
            # the last look is at the deadline, not a poll past it: a condition met after
            # the timeout had passed (helper-131: BRKR at 2 ms passed a 1.5 ms timeout)
            ctx.sleep(min(poll, left))


class Expect(_Conditions):
    """`expect: {alarm: AL013}`: every condition holds now."""

    name = "expect"

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> ConditionArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, fields.COND_KEYS, where)
        return ConditionArgs(fields.conditions(v, m, where))

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        seen = [(c, *evaluate(d, c)) for c in self.args.conditions]
        bad = [f"expected {c.describe()}, saw {obs}" for c, ok, obs in seen if not ok]
        if bad:
            raise StepFailed("; ".join(bad))
        return Outcome(", ".join(obs for _, _, obs in seen))


KINDS = (Wait, WaitUntil, Expect)

