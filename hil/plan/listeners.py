"""The runner's standard listeners: step records in the recording, reports, step lines.

`StepRecords` writes each step's start and end on the recording's `/plan/steps` topic (the
runner adds it to every run); `Reports` writes `<plan>.junit.xml` and `<plan>.html` once the
recording is closed; `StepLines` prints one line per step (`hil run -v`, and the library
default of `run_plans`). The live progress display is `hil/plan/progress.py`.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, TextIO

from hil.plan.events import Listener, Note, PlanEnded, PlanStarted, StepEnded, StepStarted
from hil.report.html import write_html
from hil.report.junit import write_junit
from hil.terminal import terminal_lines

PASS, SKIPPED = "pass", "skipped"


def recorded_file(path: str | None) -> str | None:
    """A plan file as the recording names it: absolute, so that one plan gives the same
    messages whether it was named by a relative or an absolute path."""
    return os.path.abspath(path) if path else path


class StepRecords(Listener):
    """Step start/end records on the recording (read by reports, `hil check`, `hil diff`)."""

    def step_started(self, e: StepStarted) -> None:
        s = e.step
        e.recorder.plan_step(e.result.label, "start", plan=e.plan.name, index=s.index,
                             kind=s.kind, line=s.line, drive=e.drive)

    def step_ended(self, e: StepEnded) -> None:
        s, r = e.step, e.result
        e.recorder.plan_step(r.label, "end", plan=e.plan.name, index=s.index, kind=s.kind,
                             line=s.line, drive=e.drive, status=r.status, message=r.message,
                             duration_ns=r.duration_ns, file=recorded_file(s.file))


class Reports(Listener):
    """JUnit XML and HTML for one plan, written when its recording is complete."""

    def __init__(self, out_dir: Path, stem: str) -> None:
        self.out_dir, self.stem = out_dir, stem
        self._rec: Any = None

    def plan_started(self, e: PlanStarted) -> None:
        self._rec = e.recorder

    def plan_ended(self, e: PlanEnded) -> None:
        res = e.result
        # the HTML first: it reads the recording whole (ground truth too), and the JUnit then
        # finds that read in `load_run`'s cache rather than reading the file again. The
        # messages come from the recorder's mirror when it kept one (`written`), not from the
        # file again
        html_error = junit_error = ""
        try:
            # the diagrams draw from the plan's live checks' source when it kept one: the
            # same messages, decoded once, with what the checks derived from them
            src = e.source.refresh(self._rec) if e.source is not None else None
            res.html = str(write_html(res.recording, self.out_dir / f"{self.stem}.html",
                                      index=True,  # the run writes index.html beside it
                                      messages=written(self._rec), source=src))
        except Exception as exc:
            html_error = f"HTML report failed: {exc}"
        try:
            res.junit = str(write_junit([res.recording], self.out_dir / f"{self.stem}.junit.xml"))
        except Exception as exc:
            junit_error = f"JUnit report failed: {exc}"
        res.error = res.error or junit_error or html_error


def written(rec: Any) -> Iterator[tuple[str, int, int, bytes | dict]] | None:
    """What `rec` wrote, from its mirror (`Recorder.keep_messages`), as (topic, log time,
    publish time, the decoded payload where the mirror has it, else the bytes); None without
    a mirror."""
    mirror = getattr(rec, "mirror", None)
    if mirror is None:
        return None
    names = rec.topic_of
    return ((names.get(cid) or f"?{cid}", lt, pt, data if obj is None else obj)
            for cid, lt, pt, data, obj in mirror)


class StepLines(Listener):
    """One line per step with status and duration; messages of steps that did not pass."""

    def __init__(self, stream: TextIO | None = None) -> None:
        self.stream = stream

    def _w(self, text: str) -> None:
        print(terminal_lines(text), file=self.stream or sys.stderr, flush=True)

    def plan_started(self, e: PlanStarted) -> None:
        of = f"[{e.index}/{e.total}] " if e.total > 1 else ""
        self._w(f"== {of}{e.plan.name} ({len(e.plan.steps)} steps) on bench {e.bench.name}")

    def step_ended(self, e: StepEnded) -> None:
        r = e.result
        total = len(e.plan.steps)
        label = r.label if len(r.label) <= 52 else r.label[:49] + "..."
        took = "" if r.status == SKIPPED else f"{r.duration_ns / 1e6:8.1f} ms"
        msg = f"  [{r.index + 1:>2}/{total}] {label:<52} {r.status.upper():<12} {took}".rstrip()
        if r.status != PASS and r.message:
            msg += f"\n         {r.message}"
        self._w(msg)

    def note(self, e: Note) -> None:
        self._w(f"  {e.text}")
