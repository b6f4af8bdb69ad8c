"""CAPTURE / COMPARE: `capture_arm`, `compare_table`, `latch` (docs/capture.md).

Parsing and execution live in hil/plan/capture_steps.py; these classes give them the
step-kind interface."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker
from hil.plan import capture_steps
from hil.plan.context import Outcome
from hil.plan.kinds.base import StepKind

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


class _Capture(StepKind):
    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
        return capture_steps.PARSERS[cls.name](v, obj, line, where)

    def describe(self) -> str:
        return capture_steps.describe(self.name, self.args)


class CaptureArm(_Capture):
    """`capture_arm: {start: 100, count: 3, source: CN2}`: P5.036/P5.038/P5.039 (§7.2.2)."""

    name = "capture_arm"

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(capture_steps.x_capture_arm(ctx, step, d))


class CompareTable(_Capture):
    """`compare_table: {positions: [...], width: 10ms}`: data array + P5.056-P5.059 (§7.2.3)."""

    name = "compare_table"

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(capture_steps.x_compare_table(ctx, step, d))


class Mark(_Capture):
    """`mark: {width: 2ms, line: DI7}`: the capture sensor sees a mark (a raw line pulse)."""

    name = "mark"

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(capture_steps.x_mark(ctx, step, d))

    def imposed_ns(self) -> int:
        return self.args["width"]


class Latch(_Capture):
    """`latch: {tolerance: 20, window: ..., width: ..., edges: every}`: captured positions
    against the ground truth at the sensor's edges (hil/timing/latch.py)."""

    name = "latch"
    judge_only = True

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        text, verdicts = capture_steps.x_latch(ctx, step, d)
        return Outcome(text, verdicts)


KINDS = (CaptureArm, CompareTable, Mark, Latch)
