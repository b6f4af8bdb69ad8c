"""Live progress of `hil run`: plan N of M, the current step, elapsed time and an ETA.

On a terminal it is a `rich` progress display on stderr; elsewhere (CI logs, pipes) one line
per plan with the same figures. The ETA counts steps: the time per step so far times the
steps still to run (plans are checked before the run, so every plan's step count is known).
"""

from __future__ import annotations

import sys
import time
from typing import TextIO

from rich.console import Console
from rich.progress import (
    BarColumn,
    MofNCompleteColumn,
    Progress,
    TextColumn,
    TimeElapsedColumn,
    TimeRemainingColumn,
)

from hil.plan.events import Listener, Note, PlanEnded, PlanStarted, StepEnded, StepStarted
from hil.terminal import terminal_lines, terminal_text


def _fmt(seconds: float) -> str:
    m, s = divmod(round(seconds), 60)
    return f"{m}:{s:02d}" if m else f"{s} s"


class RunProgress(Listener):
    """Plan N of M, current step, elapsed, ETA (rich on a TTY, plain lines otherwise)."""

    def __init__(self, total_steps: int, total_plans: int, stream: TextIO | None = None,
                 live: bool | None = None) -> None:
        self.stream = stream or sys.stderr
        self.total_steps = max(total_steps, 1)
        self.total_plans = total_plans
        self.done_steps = 0
        self.t0 = time.monotonic()
        self.live = self.stream.isatty() if live is None else live
        self._progress: Progress | None = None
        self._task = None
        self._plan_steps_done = 0

    # -- figures ---------------------------------------------------------------------------
    def eta_s(self) -> float | None:
        if not self.done_steps:
            return None
        per = (time.monotonic() - self.t0) / self.done_steps
        return per * (self.total_steps - self.done_steps)

    # -- events ----------------------------------------------------------------------------
    def plan_started(self, e: PlanStarted) -> None:
        self._plan_steps_done = 0
        if not self.live:
            return
        if self._progress is None:
            self._progress = Progress(
                TextColumn("[bold]{task.fields[plan]}[/] {task.fields[step]}"),
                BarColumn(), MofNCompleteColumn(), TextColumn("steps"),
                TimeElapsedColumn(), TextColumn("ETA"), TimeRemainingColumn(),
                console=Console(file=self.stream), transient=True)
            self._progress.start()
            self._task = self._progress.add_task("run", total=self.total_steps, plan="",
                                                 step="")
        self._progress.update(self._task, plan=terminal_text(
            f"plan {e.index}/{e.total} {e.plan.name}"),
                              step="")

    def step_started(self, e: StepStarted) -> None:
        if self._progress is not None:
            label = e.result.label if len(e.result.label) <= 40 else e.result.label[:37] + "..."
            self._progress.update(self._task, step=terminal_text(f"· {label}"))

    def step_ended(self, e: StepEnded) -> None:
        self.done_steps += 1
        self._plan_steps_done += 1
        if self._progress is not None:
            self._progress.update(self._task, completed=self.done_steps)

    def note(self, e: Note) -> None:
        self._print(f"  {e.plan.name}: {e.text}")

    def plan_ended(self, e: PlanEnded) -> None:
        # steps never reached (a failed plan) still count as done for the ETA
        self.done_steps += len(e.plan.steps) - self._plan_steps_done
        self._plan_steps_done = len(e.plan.steps)
        r = e.result
        eta = self.eta_s()
        tail = "" if e.index == e.total else f", ETA {_fmt(eta)}" if eta is not None else ""
        line = (f"[{e.index}/{e.total}] {r.plan:<28} {r.status.upper():<12} "
                f"{r.duration_ns / 1e9:6.2f} s  (elapsed {_fmt(time.monotonic() - self.t0)}"
                f"{tail})")
        self._print(line)
        if e.index == e.total:
            self.close()
        elif self._progress is not None:
            self._progress.update(self._task, completed=self.done_steps)

    def _print(self, text: str) -> None:
        text = terminal_lines(text)  # a plan's or step's name holds no escape sequence
        if self._progress is not None:
            self._progress.console.print(text, highlight=False, markup=False)
        else:
            print(text, file=self.stream, flush=True)

    def close(self) -> None:
        if self._progress is not None:
            self._progress.stop()
            self._progress = None
