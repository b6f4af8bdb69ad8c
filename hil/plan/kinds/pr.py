"""PR mode step kinds: `pr_table`, `pr_trigger`, `pr_wait` (docs/pr.md).

    - pr_table:                 # written by name, read back; checked by the model's decoder
        1: {type: auto, data: 100000, spd: 4, dly: 1}
        2: {type: jump, data: 1, ins: true}
        via: modbus             # optional (bench default)
    - pr_trigger: 1             # P5.007 = 1 (L11174); or {pr: 3, by: di} (POS0-6 + CTRG)
    - pr_wait: {pr: 1, state: in_position, timeout: 5s}   # P5.007 read-back (L11185)

The parsers reject, at load time (so `hil run --check` too), any path the drive would refuse
(jump > 99, undefined TYPE, speed beyond ±6000 rpm, unknown write destination...), with
`file:line: field: problem`.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import PARAM_ROUTES, Checker, LDict, join
from hil.drivers.delta_pr import STATES, DeltaPr, PrTableError, table_words
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds.base import StepKind

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

PATH_KEYS = {"type", "data", "ins", "auto", "ovlp", "cmd", "unit_pps", "acc", "dec", "spd",
             "dly", "dest", "dest_array", "source", "rom", "direction", "s_low"}
# the YAML type of each path field (hil.profile.pr.encode): a quoted "false" is no false
_FLAGS = ("ins", "auto", "ovlp", "unit_pps", "dest_array", "rom", "s_low")
_FIELD_TYPES: dict[str, tuple[type, ...]] = (
    {k: (bool,) for k in _FLAGS} | {k: (int,) for k in ("data", "acc", "dec", "spd", "dly")}
    | {k: (str,) for k in ("cmd", "source", "direction")}
    | {"type": (str, int), "dest": (str, int)})
BY = ("p5007", "di")
POS = ("POS0", "POS1", "POS2", "POS3", "POS4", "POS5", "POS6")


@dataclass(frozen=True)
class PrTableArgs:
    table: dict[int, dict[str, Any]]  # PR number -> path fields (hil.profile.pr.encode)
    via: str | None  # sdo | modbus | None (the bench's route)


@dataclass(frozen=True)
class PrTriggerArgs:
    pr: int  # 0..99
    by: str  # p5007 | di (POS0-6 + CTRG)
    via: str | None
    width: int  # ns of the POS set-up and the CTRG pulse


@dataclass(frozen=True)
class PrWaitArgs:
    pr: int
    state: str  # a P5.007 read-back state (delta_pr.STATES)
    timeout: int  # ns
    via: str | None


def _field_types(v: Checker, pm: LDict, where: str) -> None:
    for key, x in pm.items():
        want = _FIELD_TYPES[key]
        if (isinstance(x, bool) and bool not in want) or not isinstance(x, want):
            names = " or ".join({bool: "true/false", int: "an integer", str: "a name"}[t]
                                for t in want)
            raise v.err(pm.kline(key), join(where, key), f"{x!r}: {names}")


class _Access:
    """DeltaPr's parameter access through a plan's DriveIO (bench route or `via`)."""

    def __init__(self, d: Any, via: str | None) -> None:
        self.d, self.via = d, via

    def read_param(self, name: str) -> int:
        return self.d.read_param(name, self.via)

    def write_param(self, name: str, value: int) -> None:
        self.d.write_param(name, value, self.via)


class PrTable(StepKind):
    """`pr_table: {paths: {1: {...}}, via: modbus}`: write PR definitions and read them back."""

    name = "pr_table"
    args: PrTableArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PrTableArgs:
        m = v.mapping(obj, line, where)
        via = None
        table: dict[int, dict[str, Any]] = {}
        for k in m:
            kl, fw = m.kline(k), join(where, str(k))
            if k == "via":
                via = v.choice(m, "via", where, PARAM_ROUTES)
                continue
            n = int(k) if isinstance(k, str) and k.isascii() and k.isdigit() else k
            if isinstance(n, bool) or not isinstance(n, int) or not 1 <= n <= 99:
                raise v.err(kl, fw, "a PR number 1..99 (PR#0 is homing: P5.004/P6.000)")
            if n in table:  # `1` and `01` (or "1") name one path: one would be lost
                raise v.err(kl, fw, f"PR#{n} is named twice in this table")
            pm = v.mapping(m[k], kl, fw)
            v.keys(pm, PATH_KEYS, fw, required=("type",))
            _field_types(v, pm, fw)
            fields = dict(pm)
            try:
                table_words({n: fields})
            except PrTableError as exc:
                raise v.err(kl, fw, str(exc)) from None
            table[n] = fields
        if not table:
            raise v.err(m.line, where,
                        "name at least one path, e.g. 1: {type: single, data: 1000}")
        return PrTableArgs(table, via)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        pr = DeltaPr(_Access(d, self.args.via))
        try:
            words = pr.write_table(self.args.table)
        except PrTableError as exc:
            raise StepFailed(str(exc)) from None
        ctx.written(d.name, words)
        return Outcome(f"{len(self.args.table)} path(s) written and read back")

    def describe(self) -> str:
        return "pr_table " + ", ".join(f"#{n} {f['type']}" for n, f in self.args.table.items())


class PrTrigger(StepKind):
    """`pr_trigger: {path: 3, by: di}`: start a PR path (CTRG + POS bits or P5.007)."""

    name = "pr_trigger"
    motion = True
    args: PrTriggerArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PrTriggerArgs:
        if isinstance(obj, int) and not isinstance(obj, bool):
            m = LDict({"pr": obj})
            m.line, m.key_lines = line, {"pr": line}
        else:
            m = v.mapping(obj, line, where)
        v.keys(m, {"pr", "by", "via", "width"}, where, required=("pr",))
        return PrTriggerArgs(v.integer(m, "pr", where, 0, 99),
                             v.choice(m, "by", where, BY, "p5007"),
                             v.choice(m, "via", where, PARAM_ROUTES),
                             v.duration(m, "width", where, 20_000_000))

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        n = a.pr
        if a.by == "p5007":
            DeltaPr(_Access(d, a.via)).trigger(n)
            return Outcome(f"P5.007 = {n}")
        for i, f in enumerate(POS):  # POS0-6 = n, then a CTRG pulse (L4834-4840, L15098)
            if f in d.spec.di:
                d.set_function(f, bool(n >> i & 1))
            elif n >> i & 1:
                raise StepFailed(f"PR#{n} needs {f}, which the bench does not wire")
        ctx.sleep(a.width)
        d.set_function("CTRG", True)
        ctx.sleep(a.width)
        d.set_function("CTRG", False)
        return Outcome(f"POS = {n}, CTRG pulse")

    def describe(self) -> str:
        return f"pr_trigger PR#{self.args.pr} by {self.args.by}"


class PrWait(StepKind):
    """`pr_wait: {path: 3, timeout: 5s}`: wait until the path completes."""

    name = "pr_wait"
    args: PrWaitArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> PrWaitArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"pr", "state", "timeout", "via"}, where, required=("pr",))
        state = m.get("state", "in_position")
        pr = v.integer(m, "pr", where, 0, 99)
        timeout = v.duration(m, "timeout", where, 5_000_000_000)
        via = v.choice(m, "via", where, PARAM_ROUTES)
        if not isinstance(state, str) or state not in STATES:
            raise v.err(m.kline("state"), join(where, "state"), f"{state!r}: one of "
                        f"{', '.join(STATES)}")
        return PrWaitArgs(pr, state, timeout, via)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        pr = DeltaPr(_Access(d, a.via), sleep=lambda t: ctx.sleep(int(t * 1e9)))
        t0 = clock.monotonic()
        try:
            waited = pr.wait(a.pr, a.state, a.timeout / 1e9)
        except TimeoutError as exc:
            raise StepFailed(str(exc)) from None
        return Outcome(f"PR#{a.pr} {a.state} after {waited * 1e3:.0f} ms "
                       f"({(clock.monotonic() - t0) * 1e3:.0f} ms)")

    def describe(self) -> str:
        return f"pr_wait PR#{self.args.pr} {self.args.state}"


KINDS = (PrTable, PrTrigger, PrWait)
