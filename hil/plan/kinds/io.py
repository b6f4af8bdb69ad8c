"""Inputs the harness drives: DI functions (`di`, `pulse`) and the STO channels (`sto`,
`sto_dropout`)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import Checker
from hil.plan.context import Outcome
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, StepKind
from hil.profile.dio import DI_SYMBOLS
from hil.units import fmt_ms

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


@dataclass(frozen=True)
class Levels:
    """Each named input (DI function or STO channel) to a level (True = on)."""

    levels: dict[str, bool]


@dataclass(frozen=True)
class Widths:
    """Each named input to a pulse width (ns)."""

    widths: dict[str, int]


def _on_off(levels: dict[str, bool]) -> str:
    return ", ".join(f"{f}={'on' if v else 'off'}" for f, v in levels.items())


def _ms(widths: dict[str, int]) -> str:
    return ", ".join(f"{f} {fmt_ms(w)}ms" for f, w in widths.items())


def _check_wired(cc: CheckContext, names: dict) -> None:
    for f in names:
        if f not in cc.drive.di:
            raise cc.err(f"drive {cc.dname} has no DI wired to {f} "
                         f"(wired: {', '.join(cc.drive.di) or 'none'})", f)


class Di(StepKind):
    """`di: {SON: on}`: set DI functions to levels."""

    name = "di"
    args: Levels

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> Levels:
        return Levels(fields.levels(v, obj, line, where, DI_SYMBOLS, "DI function"))

    def check(self, cc: CheckContext) -> None:
        _check_wired(cc, self.args.levels)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        for f, lv in self.args.levels.items():
            d.set_function(f, lv)
        return Outcome()

    def describe(self) -> str:
        return f"di {_on_off(self.args.levels)}"


class Pulse(StepKind):
    """`pulse: {CTRG: 5ms}`: DI functions on together, each off after its width."""

    name = "pulse"
    args: Widths

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> Widths:
        return Widths(fields.widths(v, obj, line, where, DI_SYMBOLS, "DI function"))

    def check(self, cc: CheckContext) -> None:
        _check_wired(cc, self.args.widths)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        widths = sorted(self.args.widths.items(), key=lambda x: x[1])
        t0 = clock.monotonic_ns()
        for f, _w in widths:
            d.set_function(f, True)
        for f, w in widths:
            left = t0 + w - clock.monotonic_ns()
            if left > 0:
                ctx.sleep(left)
            d.set_function(f, False)
        return Outcome()

    def describe(self) -> str:
        return f"pulse {_ms(self.args.widths)}"

    def imposed_ns(self) -> int:
        return max(self.args.widths.values())


class Sto(StepKind):
    """`sto: {A: off, B: off}`: the STO channels' levels (on = 24 V, servo may run)."""

    name = "sto"
    args: Levels

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> Levels:
        return Levels(fields.levels(v, obj, line, where, fields.STO, "STO channel"))

    def check(self, cc: CheckContext) -> None:
        fields.check_dio(cc)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        for ch, lv in self.args.levels.items():
            d.set_line(d.spec.sto[ch], lv)
        return Outcome()

    def describe(self) -> str:
        return f"sto {_on_off(self.args.levels)}"


class StoDropout(StepKind):
    """`sto_dropout: {A: 5ms}`: STO channels off together, each back on after its width."""

    name = "sto_dropout"
    args: Widths

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> Widths:
        return Widths(fields.widths(v, obj, line, where, fields.STO, "STO channel"))

    def check(self, cc: CheckContext) -> None:
        fields.check_dio(cc)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        widths = sorted(self.args.widths.items(), key=lambda x: x[1])
        t0 = clock.monotonic_ns()
        for ch, _w in widths:
            d.set_line(d.spec.sto[ch], False)
        for ch, w in widths:
            left = t0 + w - clock.monotonic_ns()
            if left > 0:
                ctx.sleep(left)
            d.set_line(d.spec.sto[ch], True)
        return Outcome()

    def describe(self) -> str:
        return f"sto_dropout {_ms(self.args.widths)}"

    def imposed_ns(self) -> int:
        return max(self.args.widths.values())


KINDS = (Di, Pulse, Sto, StoDropout)

