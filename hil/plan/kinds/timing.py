"""`check_timing`: judge a timing spec (fixtures/timing) on the recording as it stands."""

from __future__ import annotations

import logging
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import Checker, join
from hil.plan.context import Cancelled, Inconclusive, Outcome, StepFailed
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, StepKind
from hil.profile.dio import DI_SYMBOLS, DO_SYMBOLS
from hil.record import topics
from hil.timing.checker import check, constants_for, occurrences_since
from hil.timing.expr import MAX_MAGNITUDE
from hil.timing.registry import SpecRegistry
from hil.timing.source import ParamTimeline, RecordingSource
from hil.timing.spec import Spec, spec_params

if TYPE_CHECKING:
    from hil.bench.bench import DriveSpec
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

BIND_LINE_RE = re.compile(r"^(DI(?:10|[1-9])|DO[1-6])(:[ab])?\Z|^STO_[AB]\Z")  # A3 lines
SINCE = ("start", "last_check")
log = logging.getLogger(__name__)


def bind_line(value: str, d: DriveSpec) -> str:
    """A `check_timing` bind value as the spec wants it: a line (DI6:b) or a function wired on
    the drive, replaced by its line (ORGP -> DI9, NL -> DI6:b)."""
    wired = d.di | d.do
    return wired[value].binding if value in wired else value


def read_unrecorded(ctx: StepContext, spec: Spec, source: RecordingSource,
                    binding: Mapping[str, str], given: Mapping[str, Any],
                    constants: Mapping[str, Any]) -> dict[str, int]:
    """Read from the drive, once per plan, the parameters `spec` uses that the recording
    does not hold (a real bench, or a virtual one whose ground truth has no snapshot) and the
    step does not give, through the bench's parameter path (`param_via`, as `read:` steps),
    and record them on /drive/<drive>/params marked `"source": "read"` so that `hil check`
    judges the file alike. A parameter the bench cannot read stays missing: its constraints
    are inconclusive as before. Returns what was read and recorded now."""
    drive = binding.get("drive", "")
    topic = topics.drive_params(drive)
    recorded = ParamTimeline.from_source(source, topic).names()
    want = sorted(spec_params(spec, dict(constants)) - recorded - set(given))
    if not want:
        return {}
    try:
        d = ctx.session.drive(drive)
    except Exception:  # a binding to a drive the session does not know
        return {}
    cache = getattr(ctx, "param_reads", {})
    got: dict[str, int] = {}
    for p in want:
        key = (drive, p)
        if key not in cache:
            try:
                cache[key] = d.read_param(p)
            except Cancelled:
                raise
            except Exception as e:  # no line, refused, unknown: judged without it
                log.info("check_timing %s: cannot read %s from %s: %s", spec.id, p, drive, e)
                cache[key] = None
            else:
                got[p] = cache[key]
    if got:
        ctx.rec.drive_params(drive, got, source="read")
    return got


@dataclass(frozen=True)
class CheckTimingArgs:
    spec: str  # a timing spec's id
    params: dict[str, int] = field(default_factory=dict)  # parameter values to judge with
    bind: dict[str, str] = field(default_factory=dict)  # placeholder -> line or function
    constants: dict[str, float] = field(default_factory=dict)
    since: str = "start"  # start | last_check | the name of an earlier step


class CheckTiming(StepKind):
    """`check_timing: {spec: brake_servo_off, bind: {...}, constants: {...}, since: ...}`."""

    name = "check_timing"
    args: CheckTimingArgs
    judge_only = True

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> CheckTimingArgs:
        if isinstance(obj, str):
            return CheckTimingArgs(obj)
        m = v.mapping(obj, line, where)
        v.keys(m, {"spec", "params", "bind", "constants", "since"}, where, required=("spec",))
        since = m.get("since", "start")
        if not isinstance(since, str) or not since.strip():
            raise v.err(m.kline("since"), join(where, "since"), f"{since!r}: start (every "
                        "occurrence in the recording), last_check (only occurrences after the "
                        "previous check of this spec) or the name of an earlier step")
        params = {}
        if "params" in m:
            pm = v.mapping(m["params"], m.kline("params"), join(where, "params"))
            params = dict(fields.param_values(v, pm, join(where, "params"), False))
        bind: dict[str, str] = {}
        if "bind" in m:
            fw = join(where, "bind")
            bm = v.mapping(m["bind"], m.kline("bind"), fw)
            for k, x in bm.items():
                if not fields.NAME_RE.match(str(k)):
                    raise v.err(bm.kline(k), join(fw, str(k)), "a placeholder name like REF")
                if not isinstance(x, str) or not (BIND_LINE_RE.match(x) or x in DI_SYMBOLS
                                                   or x in DO_SYMBOLS):
                    raise v.err(bm.kline(k), join(fw, k), f"{x!r}: a line (DI9, DI6:b, DO4) "
                                "or a wired DI/DO function (ORGP, NL)")
                bind[k] = x
        constants: dict[str, float] = {}
        if "constants" in m:
            fw = join(where, "constants")
            cm = v.mapping(m["constants"], m.kline("constants"), fw)
            for k, x in cm.items():
                if isinstance(x, bool) or not isinstance(x, int | float) or not (
                        abs(x) <= MAX_MAGNITUDE):  # False for NaN and inf too
                    # a NaN judged every constraint that reads it "cannot judge"
                    raise v.err(cm.kline(k), join(fw, str(k)),
                                f"{x!r}: a number (ms, rpm, ...), finite and within ±2**64")
                constants[str(k)] = x
        return CheckTimingArgs(v.text(m, "spec", where), params, bind, constants, since)

    def check(self, cc: CheckContext) -> None:
        """`bind:` functions must be wired; `constants:` / `bind:` names must be the spec's;
        the spec must exist and load."""
        a, d = self.args, cc.drive
        wired = d.di | d.do
        for name, x in a.bind.items():
            if not BIND_LINE_RE.match(x) and x not in wired:
                raise cc.err(f"drive {cc.dname} has no line wired to {x} (wired: "
                             f"{', '.join(wired) or 'none'})", f"bind.{name}")
        specs = cc.specs
        spec = specs.get(a.spec) if isinstance(specs, Mapping) else None
        if spec is not None:
            known = set(spec.binding()) | set(spec.bind)
            for name in a.bind:
                if name not in known:
                    raise cc.err(f"spec {spec.id!r} binds no {name!r}; it binds: "
                                 f"{', '.join(sorted(spec.bind)) or 'none'} (and the factory "
                                 "functions)", f"bind.{name}")
            for name in a.constants:
                if name not in spec.constants:
                    raise cc.err(f"spec {spec.id!r} has no constant {name!r}; it has: "
                                 f"{', '.join(sorted(spec.constants)) or 'none'}",
                                 f"constants.{name}")
        if specs is not None and a.spec not in specs:
            if isinstance(specs, SpecRegistry):
                raise cc.err(specs.why_missing(a.spec))
            raise cc.err(f"no timing spec {a.spec!r}; known: {', '.join(sorted(specs))}")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        spec = ctx.specs[a.spec]
        sample = getattr(ctx.session.world, "sample_truth", None)
        if sample is not None:  # the model's state as of now, not as of its last sample
            sample()
        ctx.rec.flush()
        source = ctx.live_source()
        binding = d.spec.binding() | {k: bind_line(x, d.spec)
                                      for k, x in a.bind.items()}
        constants = constants_for(spec, ctx.bench.timing_constants) | a.constants
        if read_unrecorded(ctx, spec, source, binding, a.params, constants):
            ctx.rec.flush()
            source = ctx.live_source()  # with the values just read
        until = clock.time_ns()  # the recording as it stands now (`hil check` re-checks alike)
        verdicts = check(spec, source, params=a.params or None, binding=binding,
                         constants=constants or None)
        since = a.since
        since_ns = None
        if since == "last_check":
            since_ns = ctx.checked.get(spec.id)
        elif since != "start":
            since_ns = ctx.started.get(since)
        verdicts = occurrences_since(verdicts, since_ns)
        ctx.checked[spec.id] = clock.time_ns()
        counts: dict[str, int] = {}
        out = []
        for v in verdicts:
            vd = v.to_dict()
            counts[v.status] = counts.get(v.status, 0) + 1
            if v.status in ("pass", "fail", "inconclusive"):
                # binding + check_params: what `hil report` needs to redraw the diagram
                ctx.rec.verdict(vd, plan=ctx.plan.name, step=step.index, binding=binding,
                                check_params=a.params or {},
                                check_constants=constants or {},
                                check_since_ns=since_ns, check_until_ns=until)
            out.append(vd)
        text = ", ".join(f"{n} {k}" for k, n in sorted(counts.items())) or "no occurrence"
        if not verdicts:
            raise StepFailed(f"spec {spec.id}: nothing to judge (no occurrence in the "
                             "recording)")
        if all(v.status == "skipped" for v in verdicts):  # nothing judged is not a pass
            why = "; ".join(dict.fromkeys(v.message for v in verdicts))
            raise StepFailed(f"spec {spec.id}: nothing judged ({text}): {why}", out)
        if counts.get("fail"):
            bad = [f"{v.constraint}: {v.message}" for v in verdicts if v.status == "fail"]
            raise StepFailed(f"{text}; " + "; ".join(bad[:3]), out)
        if counts.get("inconclusive"):
            bad = [f"{v.constraint}: {v.message}" for v in verdicts
                   if v.status == "inconclusive"]
            raise Inconclusive(f"{text}; " + "; ".join(bad[:3]), out)
        return Outcome(text, out)

    def describe(self) -> str:
        a = self.args
        extra = ", ".join(f"{x}={y}" for x, y in (a.bind or {}).items())
        return f"check_timing {a.spec}" + (f" ({extra})" if extra else "")


KINDS = (CheckTiming,)
