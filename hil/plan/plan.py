"""Plan files: name, description, `bench_requires`, initial `params`, `steps`.

`load_plan(path)` validates the file alone; `check_plan(plan, bench)` validates it against a
bench (drives, wiring, virtual-only steps, motion, parameter access, timing specs). Both raise
`PlanFileError` (`file:line: field: problem`) before anything moves. Format: docs/plans.md.
"""

from __future__ import annotations

import difflib
from collections.abc import Mapping
from dataclasses import dataclass, field, fields, replace
from pathlib import Path
from typing import Any

from hil.bench import virtual_rules
from hil.bench.bench import Bench, DriveSpec, Wire, _params
from hil.bench.yamlio import Checker, LDict, PlanFileError, join, load_yaml_file, load_yaml_text
from hil.paths import plans_dir as _pd
from hil.plan.kinds import CheckContext
from hil.plan.kinds.timing import bind_line
from hil.plan.select import KEYWORDS, TAG_WORD, is_glob
from hil.plan.steps import Step, parse_steps
from hil.profile.dio import DI_FUNCTIONS, DI_PARAMS, DO_FUNCTIONS, DO_PARAMS, N_PHYSICAL_DI

__all__ = ["Plan", "bind_line", "check_plan", "find_plans", "load_plan", "loads_plan", "mapping_of",
           "plan_spec", "step_spec"]

_TOP = {"name", "description", "bench_requires", "drive", "params", "options", "steps", "tags"}
FEATURES = ("virtual", "real", "motion", "can", "sdo", "rs485", "modbus", "dio", "pulse")


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
    options: dict[str, Any] = field(default_factory=dict)  # virtual drives' model options
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
        pm = top["params"]
        plan._lines |= {f"params.{k}": pm.kline(k) for k in plan.params if hasattr(pm, "kline")}
    if "options" in top:
        om = v.mapping(top["options"], top.kline("options"), "options")
        options = virtual_rules().ModelOptions
        v.keys(om, {f.name for f in fields(options)}, "options")
        try:
            options.from_dict(dict(om), where="options")
        except (ValueError, TypeError) as e:
            raise v.err(om.line, "options", str(e)) from None
        plan.options = dict(om)
    _mapping_overlay(v, plan, top)
    if "tags" in top:
        plan.tags = _tags(v, top)
    return plan


def _tags(v: Checker, top: LDict) -> list[str]:
    """`tags:` words that `-m` can select: not a list, a null or `and` (docs/plans.md)."""
    seq = v.seq(top["tags"], top.kline("tags"), "tags")
    for i, t in enumerate(seq):
        if isinstance(t, int) and not isinstance(t, bool):
            t = seq[i] = str(t)
        if not isinstance(t, str) or not TAG_WORD.match(t) or t in KEYWORDS:
            raise v.err(seq.item_lines[i], f"tags[{i}]", f"{t!r}: a tag is one word "
                        "(letters, digits, _ . - : /) other than and, or, not")
    return list(seq)


# --- the plan's own DI/DO mapping ---------------------------------------------------------
_DI_CODES = {f.code: f.symbol for f in DI_FUNCTIONS.values()}
_DO_CODES = {f.code: f.symbol for f in DO_FUNCTIONS.values()}


def mapping_of(name: str, value: int) -> tuple[str, Wire | None] | None:
    """A plan parameter that maps a physical line (P2.010-P2.017/P2.036/P2.037 -> DI1-DI10,
    P2.018-P2.022/P2.041 -> DO1-DO6; value 0x01xx a-contact, 0x00xx b-contact, code 0 =
    no function; L9238-9256, L9323-9339): (line, Wire or None). None for other parameters.
    Raises ValueError for a code the manual's tables 8.1/8.2 do not list."""
    if name in DI_PARAMS[:N_PHYSICAL_DI]:
        line, codes = f"DI{DI_PARAMS.index(name) + 1}", _DI_CODES
    elif name in DO_PARAMS:
        line, codes = f"DO{DO_PARAMS.index(name) + 1}", _DO_CODES
    else:
        return None
    code = value & 0xFF
    if value & ~0x1FF or (code and code not in codes):
        raise ValueError(f"0x{value:04X} maps {line} to no function of table "
                         f"{'8.1' if line[1] == 'I' else '8.2'} (0x01xx a-contact, 0x00xx "
                         "b-contact)")
    if not code:
        return line, None
    return line, Wire(codes[code], line, "a" if value & 0x100 else "b")


def _mapping_overlay(v: Checker, plan: Plan, top: LDict) -> None:
    """Validate the DI/DO mapping parameters among the plan's `params`."""
    pm = top.get("params")
    for name, value in plan.params.items():
        try:
            mapping_of(name, value)
        except ValueError as e:
            line = pm.kline(name) if isinstance(pm, LDict) else top.kline("params")
            raise v.err(line, join("params", name), str(e)) from None


def plan_spec(plan: Plan, spec: DriveSpec) -> DriveSpec:
    """The drive's wiring as this plan leaves it: the bench wiring with the plan's mapping
    parameters applied (a line mapped by the plan loses the bench's function; e.g.
    `P2.037: 0x0127` puts SHOM on DI10, `P2.011: 0x011D` ABSE on DI2 instead of CCLR)."""
    over = [m for p, x in plan.params.items() if (m := mapping_of(p, x)) is not None]
    if not over:
        return spec
    di = {f: w for f, w in spec.di.items() if w.line not in {ln for ln, _ in over}}
    do = {f: w for f, w in spec.do.items() if w.line not in {ln for ln, _ in over}}
    for _line, w in over:
        if w is not None:
            (di if w.kind == "DI" else do)[w.function] = w
    return replace(spec, di=di, do=do)


def step_spec(plan: Plan, bench: Bench, step: Step) -> DriveSpec:
    """Wiring seen by a step: the plan's mapping applies to the plan's default drive."""
    dname = step.drive or plan.drive or bench.default_drive
    spec = bench.drives[dname]
    return plan_spec(plan, spec) if dname == (plan.drive or bench.default_drive) else spec


def check_plan(plan: Plan, bench: Bench, spec_ids: set[str] | None = None) -> None:
    """Everything a plan needs from a bench, checked before anything moves."""
    v = Checker(plan.path)
    have = bench.provides()
    if plan.options and not bench.virtual:
        raise v.err(plan.key_line("options"), "options",
                    f"model options are for a virtual bench only; bench {bench.name!r} is real")
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
    if bench.virtual:  # the virtual drive refuses a DI function it does not model
        for name, value in plan.params.items():
            if why := virtual_rules().inert_mapping(name, value):
                raise v.err(plan._lines.get(f"params.{name}", plan.key_line("params")),
                            join("params", name),
                            f"0x{value:04X} maps {why} (bench {bench.name!r} is virtual)")
        # ... and each write of `params:` as the drive takes it, in order (a ratio P1.044
        # / P1.045 in a PT mode is judged against the other half as it stands then)
        target = bench.drives.get(plan.drive or bench.default_drive)
        if plan.params and target is not None:
            bad = virtual_rules().param_writes_problem(
                target, dict(target.options) | dict(plan.options), plan.params.items())
            if bad is not None:
                raise v.err(plan._lines.get(f"params.{bad[0]}", plan.key_line("params")),
                            join("params", bad[0]),
                            f"{bad[1]} (the virtual drive refuses it at the run's start)")
    for s in plan.steps:
        _check_step(v, s, plan, bench, spec_ids)


def bench_constant_warnings(bench: Bench, specs: Any) -> list[str]:
    """`file:line: field: problem` for each of a bench's `timing.constants` that no spec of
    `specs` defines: a misspelt `fw_tl` is otherwise ignored and every verdict judged with
    the default. A warning, not an error: the constant may be for a project's own spec that
    only `hil check --spec FILE` reads (the bench's constants are recorded for it)."""
    if not bench.timing_constants or not isinstance(specs, Mapping):
        return []
    known: set[str] = set()
    for sid in specs:
        known |= set(getattr(specs[sid], "constants", None) or ())
    out = []
    for name in bench.timing_constants:
        if name not in known:
            near = difflib.get_close_matches(name, sorted(known), n=1)
            hint = f"did you mean {near[0]!r}? " if near else ""
            line = bench.timing_constant_lines.get(name, 0)
            out.append(f"{bench.path}:{line}: {join('timing.constants', name)}: no shipped "
                       f"timing spec has a constant {name!r} ({hint}it applies only to a "
                       "spec of your own that defines it)")
    return out


def _check_step(v: Checker, s: Step, plan: Plan, bench: Bench, spec_ids: Any) -> None:
    """The bench's policy (drive, virtual only, motion), then the kind's own check."""
    dname = s.drive or plan.drive or bench.default_drive
    if dname not in bench.drives:
        raise v.err(s.line, join(s.where, "drive"),
                    f"bench {bench.name!r} has no drive {dname!r} (drives: "
                    f"{', '.join(bench.drives)})")
    cc = CheckContext(v, s, plan, bench, step_spec(plan, bench, s), dname, spec_ids)
    action = s.action
    assert action is not None, "steps come from parse_steps"
    if action.virtual_only and not bench.virtual:
        raise cc.err(f"only on a virtual bench; bench {bench.name!r} is real")
    if action.motion and not bench.motion_allowed:
        raise cc.err(f"motion is not allowed on bench {bench.name!r} (motion_allowed: false)")
    action.check(cc)


def _glob(n: str, plans_dir: Path) -> list[Path]:
    """Plans a glob names: with a `/` from the working directory (or the root, for an
    absolute one), else in the plans directory."""
    pattern = n if n.endswith((".yaml", ".yml")) else f"{n}.yaml"
    base, p = plans_dir if "/" not in n else Path(), Path(pattern)
    if p.is_absolute():  # pathlib globs relative patterns only
        base, pattern = Path(p.anchor), str(p.relative_to(p.anchor))
    try:  # `**` inside a component (x**.yaml) is refused
        return sorted(base.glob(pattern))
    except (ValueError, NotImplementedError) as exc:
        raise PlanFileError(n, 0, "(plan)", f"{n!r}: not a usable glob ({exc})") from None


def find_plans(names: list[str] | None = None, plans_dir: Path | None = None) -> list[Path]:
    """Plan files by path, by name (`servo_on_brake` -> plans/servo_on_brake.yaml) or by glob
    (`pr_*`); no names: every plan in the plans directory, sorted."""
    if plans_dir is None:
        plans_dir = _pd()
    if not names:
        return sorted(p for p in plans_dir.glob("*.yaml"))
    out: list[Path] = []
    for n in names:
        p = Path(n)
        if p.suffix in (".yaml", ".yml") and p.exists():
            out.append(p)
            continue
        if is_glob(n):  # `pr_*` or `plans/fault_*.yaml`: every plan it matches, sorted
            found = _glob(n, plans_dir)
            if not found:
                raise PlanFileError(n, 0, "(plan)", f"no plan matches {n!r} in "
                                    f"{plans_dir if '/' not in n else Path.cwd()}")
            out += [f for f in found if f not in out]
            continue
        cand = plans_dir / f"{n}.yaml"
        if cand.exists():
            out.append(cand)
            continue
        if p.exists():  # there, but not a plan file: say what it is, not that it is missing
            what = "a directory" if p.is_dir() else "not a .yaml file"
            raise PlanFileError(n, 0, "(plan)", f"{what}: a plan is a .yaml file, or the name "
                                f"of one in {plans_dir}")
        known = ", ".join(sorted(x.stem for x in plans_dir.glob("*.yaml")))
        raise PlanFileError(n, 0, "(plan)", f"no such plan file, nor a plan of that name in "
                            f"{plans_dir} ({known or 'none there'})")
    return out
