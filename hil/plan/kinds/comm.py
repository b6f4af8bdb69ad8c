"""Faults on the wire and raw bus traffic: `fault`, `produce`, `sdo`, `nmt` (docs/faults.md).

Parsing and execution live in hil/plan/fault_steps.py; these classes give them the step-kind
interface."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker
from hil.plan import fault_steps
from hil.plan.context import Outcome
from hil.plan.kinds.base import CheckContext, StepKind

DI_LINES = 10  # physical DI1..DI10 of CN1

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


class _Comm(StepKind):
    _parse: Any
    _run: Any

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
        return cls._parse(v, obj, line, where)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(type(self)._run(ctx, step, d))

    def describe(self) -> str:
        return fault_steps.describe(self.name, self.args)


class Fault(_Comm):
    """`fault: {can: drop, match: {...}, for: 2s}` and the RS-485 / DI/DO faults."""

    name = "fault"
    _parse = staticmethod(fault_steps.p_fault)
    _run = staticmethod(fault_steps.x_fault)

    def check(self, cc: CheckContext) -> None:
        if not cc.bench.faults_allowed:
            raise cc.err(f"fault injection is not allowed on bench {cc.bench.name!r} "
                         "(faults_allowed: false; docs/faults.md)")
        a, d = self.args, cc.drive
        t = a["transport"]
        if t == "can":
            bus = a.get("bus") or d.can
            if bus is None:
                raise cc.err(f"drive {cc.dname} has no CAN bus on bench {cc.bench.name!r}")
            if bus not in cc.bench.can:
                raise cc.err(f"no CAN bus {bus!r} on bench {cc.bench.name!r} (buses: "
                             f"{', '.join(cc.bench.can) or 'none'})", "bus")
        elif t == "rs485" and d.rs485 is None:
            raise cc.err(f"drive {cc.dname} has no RS-485 line on bench {cc.bench.name!r}")
        elif t == "dio":
            line = a["line"]
            if d.dio is None:
                raise cc.err(f"drive {cc.dname} has no DI/DO lines on bench "
                             f"{cc.bench.name!r}", "line")
            if line.startswith("DI") and not 1 <= int(line[2:]) <= DI_LINES:
                raise cc.err(f"{line!r}: the A3 has DI1..DI{DI_LINES} on CN1", "line")


class Produce(_Comm):
    """`produce: {heartbeat: 100ms, sync: off}`: the master's periodic frames."""

    name = "produce"
    _parse = staticmethod(fault_steps.p_produce)
    _run = staticmethod(fault_steps.x_produce)


class Sdo(_Comm):
    """`sdo: {1016h:1: 0x000A0064}`: raw object writes."""

    name = "sdo"
    _parse = staticmethod(fault_steps.p_sdo)
    _run = staticmethod(fault_steps.x_sdo)


class Nmt(_Comm):
    """`nmt: stop`: an NMT command to the drive's node."""

    name = "nmt"
    _parse = staticmethod(fault_steps.p_nmt)
    _run = staticmethod(fault_steps.x_nmt)


KINDS = (Fault, Produce, Sdo, Nmt)
