"""PR mode: `pr_table`, `pr_trigger`, `pr_wait` (docs/pr.md).

Parsing and execution live in hil/plan/pr_steps.py; these classes give them the step-kind
interface."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker
from hil.plan import pr_steps
from hil.plan.context import Outcome
from hil.plan.kinds.base import StepKind

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


class _Pr(StepKind):
    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
        return pr_steps.PARSERS[cls.name](v, obj, line, where)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(pr_steps.EXECUTORS[self.name](ctx, step, d))

    def describe(self) -> str:
        return pr_steps.describe(self.name, self.args)


class PrTable(_Pr):
    """`pr_table: {paths: {1: {...}}, via: modbus}`: write PR definitions and read them back."""

    name = "pr_table"


class PrTrigger(_Pr):
    """`pr_trigger: {path: 3, by: di}`: start a PR path (CTRG + POS bits or P5.007)."""

    name = "pr_trigger"
    motion = True


class PrWait(_Pr):
    """`pr_wait: {path: 3, timeout: 5s}`: wait until the path completes."""

    name = "pr_wait"


KINDS = (PrTable, PrTrigger, PrWait)
