"""CAPTURE / COMPARE step kinds: `capture_arm`, `compare_table`, `mark`, `latch`
(docs/capture.md).

    - capture_arm: {start: 100, count: 3, source: CN2, trigger: closing, min_interval: 2ms,
                    reset: 0, cyclic: false, run_pr50: false, start_compare: false, mask: 0}
    - compare_table: {start: 50, positions: [20000, 30000], width: 10ms, source: capture,
                      pulse: closed, cyclic: false, zero_after: false, run_pr45: false,
                      start_capture: false, shift: 0, axis: 0}   # axis: P5.057 (CN5/CN1)
    - mark: {width: 2ms}          # the sensor sees a mark: DI7 leaves its level for 2 ms
    - latch: {tolerance: 20, window: {min: 0, max: 50000}, width: {min: 100, max: 5000},
              edges: every}

`capture_arm` writes P5.036, P5.038, P5.076, P1.019, P1.020 and P5.039 (L11471-11542, L8122,
L8149); `compare_table` writes the data array through P5.011/P5.012 (L5104-5114), P5.056,
P5.058, P1.023 and P5.059 (L11692-11781). `latch` reads the captured values back and judges
them against the recording's ground truth (hil/timing/latch.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil import clock
from hil.bench.yamlio import PARAM_ROUTES, Checker, join
from hil.plan.context import Inconclusive, Outcome, StepFailed
from hil.plan.kinds.base import StepKind
from hil.record import topics
from hil.timing.latch import Reference, edges_from, judge
from hil.timing.source import RecordingSource
from hil.units import s32

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

SOURCES = {"CN5": 1, "CN1": 2, "CN2": 3}  # P5.039.Y (L11524-11528; 0 = off)
CMP_SOURCES = {"capture": 0, "CN5": 1, "CN1": 2, "CN2": 3}  # P5.059.Y (L11751-11756)
# P5.039.Z / P5.059.Z 0 NO / 1 NC (L11530, L11758), named by what they do (YAML reads
# a bare `no` as false): CAPTURE latches on the contact `closing` (NO) or `opening` (NC);
# the COMPARE pulse makes DO4 `closed` (NO) or `open` (NC).
TRIGGER = {"closing": 0, "opening": 1}
PULSE = {"closed": 0, "open": 1}
ARRAY = 800  # L5097
STORE = "capture_armed:"


def _choice(v: Checker, m: Any, key: str, where: str, table: dict[str, int], default: str
            ) -> int:
    x = m.get(key, default)
    if not isinstance(x, str) or x not in table:  # a list / mapping is no name either
        raise v.err(m.kline(key), join(where, key), f"{x!r}: one of {', '.join(table)}")
    return table[x]


def _ms(v: Checker, m: Any, key: str, where: str, default: int, hi: int) -> int:
    ns = v.duration(m, key, where, default * 1_000_000)
    if ns % 1_000_000 or not 0 <= ns // 1_000_000 <= hi:
        raise v.err(m.kline(key), join(where, key), f"whole ms 0..{hi} (the drive counts ms)")
    return ns // 1_000_000


def _axis(v: Checker, m: Any, where: str) -> int | None:
    """`axis:` P5.057 before the start (CN5 / CN1 only, L11703-11712)."""
    if "axis" not in m:
        return None
    x = v.integer(m, "axis", where, -2**31, 2**31 - 1)
    if m.get("source", "capture") not in ("CN5", "CN1"):
        raise v.err(m.kline("axis"), join(where, "axis"), "P5.057 is writable only with "
                    "source CN5 or CN1 (L11708-11712)")
    return x


def _range(v: Checker, m: Any, key: str, where: str) -> tuple[float, float] | None:
    if key not in m:
        return None
    r = v.mapping(m[key], m.kline(key), join(where, key))
    v.keys(r, {"min", "max"}, join(where, key))
    lo, hi = r.get("min", float("-inf")), r.get("max", float("inf"))
    for k, x in (("min", lo), ("max", hi)):
        if isinstance(x, bool) or not isinstance(x, int | float):
            raise v.err(r.kline(k), join(join(where, key), k), f"{x!r}: a number (counts)")
        if k in r and not -1e15 <= x <= 1e15:  # NaN and inf too
            raise v.err(r.kline(k), join(join(where, key), k),
                        f"{x!r}: a finite number of counts")
    if lo > hi:
        raise v.err(r.line, join(where, key), f"min {lo} > max {hi}")
    return float(lo), float(hi)


def arm_capture(ctx: Any, d: Any, *, start: int, count: int, nc: int, source: int,
                via: str | None, reset: int | None = None, cyclic: bool = False,
                mask: int = 0, min_interval: int = 0, start_compare: bool = False,
                run_pr50: bool = False) -> int:
    """Arm the drive's CAPTURE (P5.036-P5.039, P1.019/P1.020, L11471-11542) and note it for
    `latch`; returns the P5.039 written. Stopped first: P5.036/P5.038 need it (L11476)."""
    old = d.read_param("P5.039", via)
    d.write_param("P5.039", old & ~1, via)
    d.write_param("P5.036", start, via)
    d.write_param("P5.038", count, via)
    if reset is not None:
        d.write_param("P5.076", reset, via)
    p1019 = d.read_param("P1.019", via)
    d.write_param("P1.019", (p1019 & ~1) | int(cyclic), via)
    d.write_param("P1.020", mask, via)
    x = 1 | (2 if reset is not None else 0) | (4 if start_compare else 0) \
        | (8 if run_pr50 else 0)
    value = min_interval << 12 | nc << 8 | source << 4 | x
    ctx.store[STORE + d.name] = {"t": clock.time_ns(), "start": start, "count": count,
                                 "nc": nc}
    d.write_param("P5.039", value, via)
    return value


def read_array(d: Any, start: int, count: int, via: str | None) -> list[int]:
    d.write_param("P5.011", start, via)
    return [s32(d.read_param("P5.012", via)) for _ in range(count)]


@dataclass(frozen=True)
class CaptureArmArgs:
    start: int  # P5.036: the first data-array entry
    count: int  # P5.038
    source: int  # P5.039.Y
    nc: int  # P5.039.Z: 0 latch on closing, 1 on opening
    min_interval: int  # P5.039.U, ms
    reset: int | None  # P5.076, the capture axis at the first point (bit1)
    cyclic: bool  # P1.019 bit0
    run_pr50: bool  # bit3
    start_compare: bool  # bit2
    mask: int  # P1.020
    via: str | None


@dataclass(frozen=True)
class CompareTableArgs:
    start: int  # P5.056
    positions: list[int]  # the data array from `start`
    width: int  # P5.059.CBA, ms
    source: int  # P5.059.Y
    nc: int  # P5.059.Z: 0 DO4 closed during the pulse, 1 open
    cyclic: bool
    zero_after: bool
    run_pr45: bool
    start_capture: bool
    shift: int  # P1.023
    axis: int | None  # P5.057 before the start (CN5 / CN1)
    via: str | None


@dataclass(frozen=True)
class MarkArgs:
    width: int  # ns
    line: str  # DI1..DI10


@dataclass(frozen=True)
class LatchArgs:
    tolerance: float  # counts of the capture source
    window: tuple[float, float] | None
    width: tuple[float, float] | None
    every: bool  # every edge (else the first)
    trigger: str  # DI7 | Z
    start: int | None
    count: int | None
    reference: tuple[str, str] | None  # (topic, field) of the ground truth
    via: str | None


class CaptureArm(StepKind):
    """`capture_arm: {start: 100, count: 3, source: CN2}`: P5.036/P5.038/P5.039 (§7.2.2)."""

    name = "capture_arm"
    args: CaptureArmArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> CaptureArmArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"start", "count", "source", "trigger", "min_interval", "reset", "cyclic",
                   "run_pr50", "start_compare", "mask", "via"}, where)
        start = v.integer(m, "start", where, 0, ARRAY - 1, 0)
        count = v.integer(m, "count", where, 1, ARRAY, 1)
        if start + count > ARRAY:
            raise v.err(m.kline("count"), join(where, "count"), f"start {start} + count {count} "
                        "exceeds the 800-entry data array (L11494)")
        out = {"start": start, "count": count,
               "source": _choice(v, m, "source", where, SOURCES, "CN2"),
               "nc": _choice(v, m, "trigger", where, TRIGGER, "closing"),
               "min_interval": _ms(v, m, "min_interval", where, 0, 15),
               "reset": m.get("reset"), "cyclic": v.boolean(m, "cyclic", where, False),
               "run_pr50": v.boolean(m, "run_pr50", where, False),
               "start_compare": v.boolean(m, "start_compare", where, False),
               "mask": v.integer(m, "mask", where, 0, 100_000_000, 0),
               "via": v.choice(m, "via", where, PARAM_ROUTES)}
        if out["reset"] is not None and (isinstance(out["reset"], bool)
                                         or not isinstance(out["reset"], int)):
            raise v.err(m.kline("reset"), join(where, "reset"), "an integer (P5.076)")
        return CaptureArmArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        value = arm_capture(ctx, d, start=a.start, count=a.count, nc=a.nc,
                            source=a.source, via=a.via, reset=a.reset, cyclic=a.cyclic,
                            mask=a.mask, min_interval=a.min_interval,
                            start_compare=a.start_compare, run_pr50=a.run_pr50)
        return Outcome(f"P5.039 = 0x{value:04X}: {a.count} point(s) into Array[{a.start}]")

    def describe(self) -> str:
        return f"capture_arm {self.args.count} -> Array[{self.args.start}]"


class CompareTable(StepKind):
    """`compare_table: {positions: [...], width: 10ms}`: data array + P5.056-P5.059 (§7.2.3)."""

    name = "compare_table"
    args: CompareTableArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> CompareTableArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"start", "positions", "width", "source", "pulse", "cyclic", "zero_after",
                   "run_pr45", "start_capture", "shift", "axis", "via"}, where,
               required=("positions",))
        start = v.integer(m, "start", where, 0, ARRAY - 1, 50)
        pos = v.seq(m["positions"], m.kline("positions"), join(where, "positions"))
        for i, x in enumerate(pos):
            if isinstance(x, bool) or not isinstance(x, int) or not -2**31 <= x < 2**31:
                raise v.err(m.kline("positions"), join(where, f"positions[{i}]"),
                            f"{x!r}: a 32-bit integer position")
        if not pos or start + len(pos) > ARRAY:
            raise v.err(m.kline("positions"), join(where, "positions"),
                        f"1..{ARRAY - start} positions from start {start} (L11717)")
        return CompareTableArgs(**{"start": start, "positions": list(pos),
                "width": _ms(v, m, "width", where, 100, 0xFFF),
                "source": _choice(v, m, "source", where, CMP_SOURCES, "capture"),
                "nc": _choice(v, m, "pulse", where, PULSE, "closed"),
                "cyclic": v.boolean(m, "cyclic", where, False),
                "zero_after": v.boolean(m, "zero_after", where, False),
                "run_pr45": v.boolean(m, "run_pr45", where, False),
                "start_capture": v.boolean(m, "start_capture", where, False),
                "shift": v.integer(m, "shift", where, -10_000_000, 100_000_000, 0),
                "axis": _axis(v, m, where), "via": v.choice(m, "via", where, PARAM_ROUTES)})

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        via = a.via
        old = d.read_param("P5.059", via)
        d.write_param("P5.059", old & ~1, via)
        d.write_param("P5.011", a.start, via)  # window #1 advances on every write (L5111)
        for x in a.positions:
            d.write_param("P5.012", x, via)
        d.write_param("P5.011", a.start, via)
        back = [d.read_param("P5.012", via) for _ in a.positions]
        if back != a.positions:
            raise StepFailed(f"data array read back {back}, wrote {a.positions}")
        d.write_param("P5.056", a.start, via)
        d.write_param("P5.058", len(a.positions), via)
        d.write_param("P1.023", a.shift, via)
        if a.axis is not None:
            d.write_param("P5.059", (old & ~0xF1) | a.source << 4, via)  # Y first, stopped
            d.write_param("P5.057", a.axis, via)
        x = 1 | (2 if a.cyclic else 0) | (4 if a.start_capture else 0) \
            | (8 if a.zero_after else 0)
        value = a.width << 16 | int(a.run_pr45) << 12 | a.nc << 8 | a.source << 4 | x
        d.write_param("P5.059", value, via)
        return Outcome(f"P5.059 = 0x{value:08X}: {len(a.positions)} point(s) from Array[{a.start}]")

    def describe(self) -> str:
        return f"compare_table {len(self.args.positions)} point(s), {self.args.width} ms"


class Mark(StepKind):
    """`mark: {width: 2ms, line: DI7}`: the capture sensor sees a mark (a raw line pulse)."""

    name = "mark"
    args: MarkArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> MarkArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"width", "line"}, where)
        ln = m.get("line", "DI7")
        if not isinstance(ln, str) or re.fullmatch(r"DI(10|[1-9])", ln) is None:  # DI07: no line
            raise v.err(m.kline("line"), join(where, "line"), f"{ln!r}: a DI line DI1..DI10")
        return MarkArgs(v.duration(m, "width", where, 2_000_000), ln)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        """The sensor sees a mark: the line leaves its level for `width`, then returns."""
        ln = self.args.line
        idle = d.line(ln)
        d.set_line(ln, not idle)
        ctx.sleep(self.args.width)
        d.set_line(ln, idle)
        return Outcome(f"{ln} {'opened' if idle else 'closed'} for {self.args.width / 1e6:g} ms")

    def describe(self) -> str:
        return f"mark {self.args.line} {self.args.width / 1e6:g} ms"

    def imposed_ns(self) -> int:
        return self.args.width


class Latch(StepKind):
    """`latch: {tolerance: 20, window: ..., width: ..., edges: every}`: captured positions
    against the ground truth at the sensor's edges (hil/timing/latch.py)."""

    name = "latch"
    judge_only = True
    args: LatchArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> LatchArgs:
        m = v.mapping(obj, line, where)
        v.keys(m, {"tolerance", "window", "width", "edges", "trigger", "start", "count",
                   "reference", "via"}, where, required=("tolerance",))
        tol = v.number(m, "tolerance", where, 0, 1e15)  # counts (capture-source pulses)
        edges = v.choice(m, "edges", where, ("first", "every"), "every")
        trig = v.choice(m, "trigger", where, ("DI7", "Z"), "DI7")
        ref = None
        if "reference" in m:
            r = v.mapping(m["reference"], m.kline("reference"), join(where, "reference"))
            v.keys(r, {"topic", "field"}, join(where, "reference"), required=("topic", "field"))
            ref = (v.text(r, "topic", where), v.text(r, "field", where))
        return LatchArgs(**{"tolerance": float(tol), "window": _range(v, m, "window", where),
                "width": _range(v, m, "width", where), "every": edges == "every",
                "trigger": trig, "start": v.integer(m, "start", where, 0, ARRAY - 1, None)
                if "start" in m else None,
                "count": v.integer(m, "count", where, 1, ARRAY) if "count" in m else None,
                "reference": ref, "via": v.choice(m, "via", where, PARAM_ROUTES)})

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        armed = ctx.store.get(STORE + d.name, {})
        start = a.start if a.start is not None else armed.get("start", 0)
        count = a.count if a.count is not None else armed.get("count", 1)
        captured = read_array(d, start, count, a.via)
        remaining = d.read_param("P5.038", a.via)
        sample = getattr(ctx.session.world, "sample_truth", None)
        if sample is not None:
            sample()
        ctx.rec.flush()
        src = RecordingSource(ctx.rec.path)
        edges = edges_from(src, d.name, z=a.trigger == "Z", since_ns=armed.get("t"))
        topic, field = a.reference or (topics.drive_state(d.name), "position_puu")
        ref = Reference.from_source(src, topic, field)
        # P5.038 counts down while armed: only the points already stored are the drive's
        done = count - remaining if remaining < count else count
        results = judge(edges, ref, captured[:done] if done else captured,
                        trigger_level=not armed.get("nc", 0) or a.trigger == "Z",
                        tolerance=a.tolerance, window=a.window, width=a.width,
                        every=a.every)
        out = []
        for r in results:
            if r.status not in ("pass", "fail", "inconclusive"):
                continue
            msg = (f"edge {r.index}: true {r.true_counts:.1f}, captured {r.captured}, error "
                   + ("-" if r.error_counts is None else f"{r.error_counts:+.1f}")
                   + f" ± {r.uncertainty_counts:.1f} counts (tolerance ±{a.tolerance:g})"
                   + (f": {r.reason}" if r.reason else ""))
            vd = {"spec": "latch", "constraint": f"latch edge {r.index}", "status": r.status,
                  "message": msg, "t_ns": r.t_ns, "latch": r.to_dict(),
                  "tolerance_counts": a.tolerance,
                  "source": "L5150 (5 µs); 003:454-505 (window, width, edges)"}
            ctx.rec.verdict(vd, plan=ctx.plan.name, step=step.index)
            out.append(vd)
        judged = [r for r in results if r.status in ("pass", "fail", "inconclusive")]
        if not judged:
            raise StepFailed(f"latch: no accepted sensor edge to judge ({len(edges)} edge(s) "
                             f"seen, {sum(r.status == 'rejected' for r in results)} rejected)")
        errs = ", ".join(f"{r.error_counts:+.1f}±{r.uncertainty_counts:.1f}"
                         if r.error_counts is not None else "none" for r in judged)
        rejected = sum(r.status == "rejected" for r in results)
        text = f"{len(judged)} edge(s) judged, errors [{errs}] counts" + \
            (f", {rejected} rejected" if rejected else "")
        bad = [v["message"] for v in out if v["status"] == "fail"]
        if bad:
            raise StepFailed(f"{text}; " + "; ".join(bad[:3]), out)
        if any(v["status"] == "inconclusive" for v in out):
            raise Inconclusive(text, out)
        return Outcome(text, out)

    def describe(self) -> str:
        a = self.args
        opts = [f"±{a.tolerance:g}"]
        if a.window:
            opts.append(f"window {a.window[0]:g}..{a.window[1]:g}")
        if a.width:
            opts.append(f"width {a.width[0]:g}..{a.width[1]:g}")
        opts.append("every edge" if a.every else "first edge")
        return f"latch {a.trigger} (" + ", ".join(opts) + ")"


KINDS = (CaptureArm, CompareTable, Mark, Latch)
