"""A step kind: one class per YAML key (`di`, `write`, `check_timing`, ...).

Each kind parses its YAML value once into its own typed arguments (`parse` -> a frozen
dataclass `Args`, every field error as file:line:field through the `Checker`), checks itself
against the bench before anything moves (`check`), runs (`run` -> `Outcome`) and describes
itself for reports (`describe`). The runner, the plan checker and the reports call these and nothing
else; a new kind is a new class (hil/plan/kinds/__init__.py finds them, and entry points in
the group `hil.steps` add more, the way python-can finds interfaces).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, ClassVar

from hil.bench.yamlio import Checker, PlanFileError, join

if TYPE_CHECKING:
    from hil.bench.bench import Bench, DriveSpec
    from hil.plan.context import Outcome, StepContext
    from hil.plan.plan import Plan
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step


@dataclass(frozen=True)
class NoArgs:
    """The arguments of a kind that takes none (`fault_reset: true`, `group_stop: {}`)."""


@dataclass
class CheckContext:
    """What `StepKind.check` sees: the plan, the bench, the step's drive and its wiring."""

    v: Checker
    step: Step
    plan: Plan
    bench: Bench
    drive: DriveSpec  # the step's drive, with the plan's own DI/DO mapping applied
    dname: str
    specs: Any  # timing specs by id (or None: not checked)

    @property
    def field(self) -> str:
        return join(self.step.where, self.step.kind)

    def err(self, message: str, field: str | None = None, line: int | None = None
            ) -> PlanFileError:
        return self.v.err(line or self.step.line, join(self.field, field) if field
                          else self.field, message)


class StepKind:
    """Base class of every step kind. Instances hold one step's parsed `args`: an instance of
    the kind's `Args` dataclass (a kind an entry point adds may keep any value)."""

    name: ClassVar[str] = ""
    #: only on a virtual bench (the model's own knobs: power, injections)
    virtual_only: ClassVar[bool] = False
    #: moves the axis: refused on a bench with `motion_allowed: false`
    motion: ClassVar[bool] = False
    #: only judges what already happened: its failure does not end the plan
    judge_only: ClassVar[bool] = False

    def __init__(self, args: Any) -> None:
        self.args = args

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> Any:
        """The step's `args` from its YAML value; raises PlanFileError (file, line, field)."""
        raise NotImplementedError

    def own_timeout_ns(self, step: Step, bench: Bench) -> int | None:
        """How long the step may take by what the plan wrote inside it (a `timeout:` in its
        arguments, a `wait`'s duration): with no step-level `timeout:` the step's watchdog
        gives it at least this long, so a long wait fails at its own timeout saying what it
        saw, or ends, rather than at the bench's step timeout. A kind's default inner
        timeout, not written, does not count."""
        raw = step.raw.get(step.kind)
        if not (isinstance(raw, Mapping) and "timeout" in raw):
            return None
        own = getattr(self.args, "timeout", None)
        return own if isinstance(own, int) and not isinstance(own, bool) and own > 0 else None

    def check(self, cc: CheckContext) -> None:
        """Refuse, before anything moves, what this bench cannot do for this step."""

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        raise NotImplementedError

    def describe(self) -> str:
        return self.name

    def imposed_ns(self) -> int:
        """Delay the step imposes by design (waits, pulse widths)."""
        return 0
