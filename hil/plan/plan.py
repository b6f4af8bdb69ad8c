"""Plan files: name, description, `bench_requires`, initial `params`, `steps`.

`load_plan(path)` validates the file alone; `check_plan(plan, bench)` validates it against a
bench (drives, wiring, virtual-only steps, motion, parameter access, timing specs). Both raise
`PlanFileError` (`file:line: field: problem`) before anything moves. Format: docs/plans.md.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.plan.bench import Bench
from hil.plan.steps import MOTION, VIRTUAL_ONLY, Step, parse_steps
from hil.plan.yamlio import Checker, LDict, PlanFileError, join, load_yaml_file, load_yaml_text

_TOP = {"name", "description", "bench_requires", "drive", "params", "steps", "tags"}
FEATURES = ("virtual", "real", "motion", "can", "sdo", "rs485", "modbus", "dio")


@dataclass
class Plan:
    name: str
    path: str
    text: str
    steps: list[Step]
    description: str = ""
    bench_requires: list[str] = field(default_factory=list)
    drive: str | None = None
    params: dict[str, int] = field(default_factory=dict)
    tags: list[str] = field(default_factory=list)
    line: int = 1
    _lines: dict[str, int] = field(default_factory=dict)

    def key_line(self, key: str) -> int:
        return self._lines.get(key, self.line)


def load_plan(path: str | Path) -> Plan:
    p = Path(path)
    return parse_plan(load_yaml_file(p), str(p), p.read_text(encoding="utf-8"))


def loads_plan(text: str, file: str = "<string>") -> Plan:
    return parse_plan(load_yaml_text(text, file), file, text)


def parse_plan(data: Any, file: str, text: str = "") -> Plan:
    from hil.plan.bench import _params

    v = Checker(file)
    top: LDict = v.mapping(data, 1, "(top)")
    v.keys(top, _TOP, "", required=("name", "steps"))
    plan = Plan(name=v.text(top, "name", ""), path=file, text=text,
                steps=parse_steps(v, top["steps"], top.kline("steps")),
                description=str(top.get("description") or ""), line=top.line,
                _lines=dict(top.key_lines))
    if "bench_requires" in top:
        lst = v.seq(top["bench_requires"], top.kline("bench_requires"), "bench_requires")
        for i, f in enumerate(lst):
            if not isinstance(f, str):
                raise v.err(lst.item_lines[i], f"bench_requires[{i}]", "must be a feature name")
            plan.bench_requires.append(f)
    if "drive" in top:
        plan.drive = v.text(top, "drive", "")
    if "params" in top:
        plan.params = _params(v, top["params"], top.kline("params"), "params")
    if "tags" in top:
        plan.tags = [str(t) for t in v.seq(top["tags"], top.kline("tags"), "tags")]
    return plan


def check_plan(plan: Plan, bench: Bench, spec_ids: set[str] | None = None) -> None:
    """Everything a plan needs from a bench, checked before anything moves."""
    v = Checker(plan.path)
    have = bench.provides()
    for i, f in enumerate(plan.bench_requires):
        if f not in have:
            raise v.err(plan.key_line("bench_requires"), f"bench_requires[{i}]",
                        f"bench {bench.name!r} does not provide {f!r} (it provides: "
                        f"{', '.join(sorted(have))})")
    if plan.drive is not None and plan.drive not in bench.drives:
        raise v.err(plan.key_line("drive"), "drive",
                    f"bench {bench.name!r} has no drive {plan.drive!r} "
                    f"(drives: {', '.join(bench.drives)})")
    if plan.params and not any(d.param_via for d in bench.drives.values()):
        raise v.err(plan.key_line("params"), "params",
                    f"bench {bench.name!r} has no parameter access (rs485 or can)")
    for s in plan.steps:
        _check_step(v, s, plan, bench, spec_ids)


def _check_step(v: Checker, s: Step, plan: Plan, bench: Bench, spec_ids: set[str] | None):
    w = s.where
    dname = s.drive or plan.drive or bench.default_drive
    if dname not in bench.drives:
        raise v.err(s.line, join(w, "drive"),
                    f"bench {bench.name!r} has no drive {dname!r} (drives: "
                    f"{', '.join(bench.drives)})")
    d = bench.drives[dname]
    kw = join(w, s.kind)
    if s.kind in VIRTUAL_ONLY and not bench.virtual:
        raise v.err(s.line, kw, f"only on a virtual bench; bench {bench.name!r} is real")
    if s.kind in MOTION and not bench.motion_allowed:
        raise v.err(s.line, kw, f"motion is not allowed on bench {bench.name!r} "
                                "(motion_allowed: false)")
    if s.kind in ("di", "pulse"):
        names = s.args.get("levels") or s.args.get("widths")
        for f in names:
            if f not in d.di:
                raise v.err(s.line, join(kw, f), f"drive {dname} has no DI wired to {f} "
                            f"(wired: {', '.join(d.di) or 'none'})")
    if s.kind in ("sto", "sto_dropout") and not d.dio:
        raise v.err(s.line, kw, f"drive {dname} has no DI/DO lines (dio:)")
    if s.kind in ("state", "mode", "move", "home", "fault_reset") and not d.can:
        raise v.err(s.line, kw, f"drive {dname} has no CAN bus: CiA 402 needs `can:`")
    if s.kind in ("write", "read"):
        _check_via(v, s.line, kw, s.args["via"], d, dname)
    if s.kind == "write" and s.args.get("expect_error") is not None:
        from hil.plan.steps import check_expect_error

        via = s.args["via"] or d.param_via
        line = s.raw[s.kind].kline("expect_error") if hasattr(s.raw[s.kind], "kline") else s.line
        check_expect_error(v, line, join(kw, "expect_error"), s.args["expect_error"], via)
    if s.kind in ("wait_until", "expect"):
        for c in s.args["conditions"]:
            if c.kind == "do" and c.key not in d.do:
                raise v.err(s.line, join(kw, f"do.{c.key}"), f"drive {dname} has no DO wired "
                            f"to {c.key} (wired: {', '.join(d.do) or 'none'})")
            if c.kind == "fdbk" and not d.dio:
                raise v.err(s.line, join(kw, "fdbk"), f"drive {dname} has no DI/DO lines")
            if c.kind == "state" and not d.can:
                raise v.err(s.line, join(kw, "state"), f"drive {dname} has no CAN bus")
            if c.kind in ("param", "alarm"):
                _check_via(v, s.line, join(kw, c.kind), c.via, d, dname)
    if s.kind == "check_timing" and spec_ids is not None and s.args["spec"] not in spec_ids:
        from hil.plan.runner import BROKEN_SPECS

        if s.args["spec"] in BROKEN_SPECS:
            raise v.err(s.line, kw, f"timing spec {s.args['spec']!r} does not load: "
                        f"{BROKEN_SPECS[s.args['spec']]}")
        raise v.err(s.line, kw, f"no timing spec {s.args['spec']!r}; known: "
                    f"{', '.join(sorted(spec_ids))}")


def _check_via(v: Checker, line: int, field: str, via: str | None, d: Any, dname: str) -> None:
    via = via or d.param_via
    if not via:
        raise v.err(line, field, f"drive {dname} has no parameter access (rs485 or can)")
    if via == "modbus" and not d.rs485:
        raise v.err(line, field, f"drive {dname} has no RS-485 line for via: modbus")
    if via == "sdo" and not d.can:
        raise v.err(line, field, f"drive {dname} has no CAN bus for via: sdo")


def find_plans(names: list[str] | None = None, plans_dir: Path | None = None) -> list[Path]:
    """Plan files by path or by name (`servo_on_brake` -> plans/servo_on_brake.yaml);
    no names: every plan in the plans directory, sorted."""
    if plans_dir is None:
        from hil.paths import plans_dir as _pd

        plans_dir = _pd()
    if not names:
        return sorted(p for p in plans_dir.glob("*.yaml"))
    out = []
    for n in names:
        p = Path(n)
        if p.suffix in (".yaml", ".yml") and p.exists():
            out.append(p)
            continue
        cand = plans_dir / f"{n}.yaml"
        if cand.exists():
            out.append(cand)
            continue
        known = ", ".join(sorted(x.stem for x in plans_dir.glob("*.yaml")))
        raise PlanFileError(n, 0, "(plan)", f"no such plan file or shipped plan; shipped: {known}")
    return out
