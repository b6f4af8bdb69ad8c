"""The virtual bench's own knobs: `power_cycle` and `inject` (model options, alarms)."""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.bench import virtual_rules
from hil.bench.yamlio import Checker, join
from hil.plan.context import Outcome
from hil.plan.kinds import fields
from hil.plan.kinds.base import StepKind

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


@dataclass(frozen=True)
class PowerCycleArgs:
    battery: bool = True  # the absolute encoder's battery stays connected
    off: int = 0  # ns without power


@dataclass(frozen=True)
class InjectArgs:
    options: dict[str, Any] | None = None  # ModelOptions fields to change
    alarm: str | None = None  # an alarm to raise

    def given(self) -> dict[str, Any]:
        return {k: x for k, x in (("options", self.options), ("alarm", self.alarm))
                if x is not None}


class PowerCycle(StepKind):
    """`power_cycle: {battery: true, off: 100ms}`."""

    name = "power_cycle"
    args: PowerCycleArgs
    virtual_only = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PowerCycleArgs:
        if obj is None or obj is True:
            return PowerCycleArgs()
        m = v.mapping(obj, line, where)
        v.keys(m, {"battery", "off"}, where)
        return PowerCycleArgs(v.boolean(m, "battery", where, True),
                              v.duration(m, "off", where, 0))

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        ctx.session.world.power_cycle(d.name, battery=self.args.battery,
                                      off_ns=self.args.off)
        return Outcome()

    def describe(self) -> str:
        return "power_cycle"


class Inject(StepKind):
    """`inject: {options: {...}, alarm: AL009}`: change model options or raise an alarm."""

    name = "inject"
    args: InjectArgs
    virtual_only = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> InjectArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"options", "alarm"}, where)
        out: dict[str, Any] = {}
        if "options" in m:
            om = v.mapping(m["options"], m.kline("options"), join(where, "options"))
            options = virtual_rules().ModelOptions
            v.keys(om, {f.name for f in dataclasses.fields(options)}, join(where, "options"))
            try:  # the values too: a flag true/false, a time a finite number, a known choice
                options.from_dict(dict(om), join(where, "options"))
            except (ValueError, TypeError) as e:
                raise v.err(m.kline("options"), join(where, "options"), str(e)) from None
            out["options"] = dict(om)
        if "alarm" in m:
            a = m["alarm"]
            if not isinstance(a, str) or not fields.ALARM_RE.match(a.upper()):
                raise v.err(m.kline("alarm"), join(where, "alarm"),
                            f"{a!r}: an alarm code like AL009")
            out["alarm"] = a.upper()
        if not out:
            raise v.err(line, where, "inject options: {...} and/or alarm: ALnnn")
        return InjectArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        ctx.session.world.inject(d.name, options=self.args.options,
                                 alarm=self.args.alarm)
        ctx.rec.log("warning", f"injected into {d.name}: {self.args.given()}", name="hil.inject")
        return Outcome()

    def describe(self) -> str:
        return "inject " + ", ".join(f"{x}={y}" for x, y in self.args.given().items())


KINDS = (PowerCycle, Inject)
