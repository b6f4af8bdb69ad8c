"""What the runner tells its listeners: plan and step events (python-can's Notifier/Listener
shape). Progress displays, the recorder's step records and the reports are listeners; the
runner knows none of them.

    class Mine(Listener):
        def step_ended(self, e: StepEnded) -> None: ...
    run_plan(plan, bench, out, listeners=[Mine()])
"""

from __future__ import annotations

import logging
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

if TYPE_CHECKING:
    from hil.bench.bench import Bench
    from hil.plan.plan import Plan
    from hil.plan.runner import PlanResult, StepResult
    from hil.plan.steps import Step

log = logging.getLogger(__name__)


@dataclass
class PlanStarted:
    plan: Plan
    bench: Bench
    index: int = 1  # plan N of `total` in this run
    total: int = 1
    recorder: Any = None


@dataclass
class StepStarted:
    plan: Plan
    step: Step
    result: StepResult
    drive: str
    recorder: Any = None


@dataclass
class StepEnded:
    plan: Plan
    step: Step
    result: StepResult
    drive: str
    recorder: Any = None


@dataclass
class Note:
    """Something a person should see now (an error, the safe state)."""

    plan: Plan
    text: str


@dataclass
class PlanEnded:
    plan: Plan
    result: PlanResult
    index: int = 1
    total: int = 1
    #: the plan's recording as a timing source, when its checks kept one (`LiveSource`):
    #: a report draws from it instead of reading the file again
    source: Any = None


Event = PlanStarted | StepStarted | StepEnded | Note | PlanEnded

_METHODS = {PlanStarted: "plan_started", StepStarted: "step_started", StepEnded: "step_ended",
            Note: "note", PlanEnded: "plan_ended"}


class Listener:
    """Receives runner events; override the methods you need."""

    def on_event(self, event: Event) -> None:
        getattr(self, _METHODS[type(event)])(event)

    def plan_started(self, e: PlanStarted) -> None: ...

    def step_started(self, e: StepStarted) -> None: ...

    def step_ended(self, e: StepEnded) -> None: ...

    def note(self, e: Note) -> None: ...

    def plan_ended(self, e: PlanEnded) -> None: ...


class Notifier:
    """Fans events out to listeners; a listener that raises is logged, never stops a plan."""

    def __init__(self, listeners: list[Listener] | None = None) -> None:
        self.listeners = list(listeners or [])

    def emit(self, event: Event) -> None:
        for lst in self.listeners:
            try:
                lst.on_event(event)
            except Exception:
                log.exception("listener %s failed on %s", type(lst).__name__,
                              type(event).__name__)
