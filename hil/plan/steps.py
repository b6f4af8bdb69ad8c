"""Plan steps: one YAML mapping per step, one *kind* key plus optional common keys.

Every kind is a class in hil/plan/kinds/ (found through `hil.plan.kinds.kinds()`, which
entry points extend); its `parse` returns the step's `args` and raises `PlanFileError` with
file, line and field. Formats: docs/plans.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

from hil.bench.yamlio import Checker, LList, join
from hil.plan.kinds import StepKind, kinds
from hil.plan.kinds.fields import Condition
from hil.plan.kinds.timing import SINCE

__all__ = ["COMMON", "Condition", "Step", "describe", "parse_step", "parse_steps"]

COMMON = {"name", "drive", "note", "timeout", "imposed"}


@dataclass
class Step:
    kind: str
    args: Any  # the kind's typed arguments (StepKind.Args)
    index: int
    line: int
    file: str
    name: str = ""
    drive: str | None = None
    timeout_ns: int | None = None
    note: str = ""
    imposed_by_manual_ns: int = 0  # `imposed:` the manual's own delay inside this step
    raw: dict[str, Any] = field(default_factory=dict)
    action: StepKind | None = None  # the kind's instance, holding `args`

    @property
    def label(self) -> str:
        return self.name or describe(self)

    @property
    def where(self) -> str:
        return f"steps[{self.index}]"

    @property
    def imposed_ns(self) -> int:
        """Delay the step imposes by design: waits, pulse widths, and the manual delay a
        plan names on a step with `imposed:` (e.g. the 1 s of AL501 in a wait_until)."""
        if self.imposed_by_manual_ns:
            return self.imposed_by_manual_ns
        return self.action.imposed_ns() if self.action else 0


def describe(step: Step) -> str:
    return step.action.describe() if step.action else step.kind


def parse_step(v: Checker, obj: Any, index: int, line: int) -> Step:
    where = f"steps[{index}]"
    m = v.mapping(obj, line, where)
    table = kinds()
    found = [k for k in m if k in table]
    unknown = [k for k in m if k not in table and k not in COMMON]
    if unknown:
        k = unknown[0]
        raise v.err(m.kline(k), join(where, k),
                    f"unknown step kind; known: {', '.join(table)} (common keys: "
                    f"{', '.join(sorted(COMMON))})")
    if len(found) != 1:
        problem = ("no step kind" if not found else f"one kind per step, found {', '.join(found)}")
        raise v.err(m.line, where, f"{problem}; known: {', '.join(table)}")
    kind = found[0]
    cls = table[kind]
    args = cls.parse(v, m[kind], m.kline(kind), join(where, kind))
    step = Step(kind, args, index, m.kline(kind), v.file, raw=dict(m), action=cls(args))
    if "name" in m:
        step.name = v.text(m, "name", where)
    if "note" in m:
        step.note = v.text(m, "note", where)
    if "drive" in m:
        step.drive = v.text(m, "drive", where)
    if "imposed" in m:
        step.imposed_by_manual_ns = v.duration(m, "imposed", where)
        if step.imposed_by_manual_ns < 0:
            raise v.err(m.kline("imposed"), join(where, "imposed"), "must be >= 0")
    if "timeout" in m:
        if kind == "wait_until":
            raise v.err(m.kline("timeout"), join(where, "timeout"),
                        "give wait_until its timeout inside: wait_until: {..., timeout: 1s}")
        step.timeout_ns = v.duration(m, "timeout", where)
        if step.timeout_ns <= 0:  # 0 would be no timeout at all, or the bench's: neither said
            raise v.err(m.kline("timeout"), join(where, "timeout"), "must be > 0")
    return step


def parse_steps(v: Checker, obj: Any, line: int) -> list[Step]:
    lst: LList = v.seq(obj, line, "steps")
    if not lst:
        raise v.err(line, "steps", "a plan needs at least one step")
    steps = [parse_step(v, item, i, lst.item_lines[i]) for i, item in enumerate(lst)]
    stored: set[str] = set()
    names: dict[str, list[int]] = {}  # step name -> the lines of the steps so named
    for st, line_ in zip(steps, lst.item_lines, strict=True):
        since = st.args.since if st.kind == "check_timing" else None
        if since is not None and since not in SINCE and since not in names:
            raise v.err(st.raw[st.kind].kline("since"), join(st.where, "check_timing.since"),
                        f"{since!r}: start, last_check or the name of an earlier step "
                        f"(named so far: {', '.join(sorted(names)) or 'none'})")
        if since is not None and len(names.get(since, ())) > 1:
            raise v.err(st.raw[st.kind].kline("since"), join(st.where, "check_timing.since"),
                        f"{since!r} names {len(names[since])} earlier steps (lines "
                        f"{', '.join(map(str, names[since]))}): give one of them its own name")
        if st.name:
            names.setdefault(st.name, []).append(line_)
        if st.kind != "abs_read":  # `same_as` names a reading an earlier `abs_read` stored
            continue
        same = st.args.same_as
        if same is not None and same not in stored:
            raise v.err(st.raw[st.kind].kline("same_as"), join(st.where, "abs_read.same_as"),
                        f"no earlier abs_read stored {same!r} (stored so far: "
                        f"{', '.join(sorted(stored)) or 'none'})")
        if st.args.store:
            stored.add(st.args.store)
    return steps
