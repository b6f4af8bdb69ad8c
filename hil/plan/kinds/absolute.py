"""The absolute encoder's DI/DO handshake: `abs_read` and `abs_origin` (L16436-16521)."""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.bench.yamlio import Checker, join
from hil.drivers.abs_reader import AbsPositionReader, AbsReadError
from hil.plan.context import Outcome, StepFailed
from hil.plan.kinds import fields
from hil.plan.kinds.base import CheckContext, StepKind
from hil.plan.session import BenchError

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

_ABS_FIELDS = ("status", "turns", "position")


def abs_reader(d: DriveIO) -> AbsPositionReader:
    """The host-side reader on the drive's DI/DO port; lines from the (plan's) wiring:
    ABSE/ABSC/ABSW where wired, ABSQ = DI4, ABSR = DO2, ABSD = DO3 (L15143, L15409, L15413)."""
    if d.dio is None:
        raise BenchError(f"drive {d.name}: no DI/DO lines for the absolute handshake")
    w = d.spec.di | d.spec.do
    kw: dict[str, Any] = {"abse": w["ABSE"].line, "abse_active": w["ABSE"].contact == "a"}
    if "ABSC" in w:
        kw |= {"absc": w["ABSC"].line, "absc_active": w["ABSC"].contact == "a"}
    if "ABSW" in w:
        kw |= {"absw": w["ABSW"].line, "absw_active": w["ABSW"].contact == "a"}
    p2009 = d.read_param("P2.009") if d.spec.param_via else 2  # DI filter (L9229)
    return AbsPositionReader(d.dio, p2009_ms=p2009, **kw)


@dataclass(frozen=True)
class AbsReadArgs:
    expect: dict[str, int]  # status / turns / position to expect
    store: str | None  # keep the reading under this name
    same_as: str | None  # expect a reading stored earlier
    tolerance: int  # position tolerance (pulses)
    retries: int  # reads after a checksum error


@dataclass(frozen=True)
class AbsOriginArgs:
    hold: int | None = None  # ns ABSC is held (None: P2.009 + 250 ms)


class _Handshake(StepKind):
    need: tuple[str, ...] = ("ABSE",)

    def check(self, cc: CheckContext) -> None:
        d, dname = cc.drive, cc.dname
        fields.check_dio(cc)
        for f in self.need:
            if f not in d.di:
                raise cc.err(f"drive {dname} has no DI wired to {f}: wire it in the bench or "
                             f"map it in the plan's params (e.g. P2.011: 0x011D = ABSE on "
                             f"DI2); wired: {', '.join(d.di) or 'none'}")
        on_di4 = [f for f, w in d.di.items() if w.line == "DI4"]
        if on_di4:
            raise cc.err(f"DI4 is the handshake's ABSQ; drive {dname} has {on_di4[0]} on it "
                         "(map it to 0: P2.013: 0, L16504)")


class AbsRead(_Handshake):
    """`abs_read: {expect: {...}, tolerance, store, same_as, retries}`: the 80-bit DI/DO
    handshake (L16460-16521), checksum verified by the reader."""

    name = "abs_read"
    args: AbsReadArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> AbsReadArgs:
        m = fields.mapping_or_empty(v, obj, line, where)
        v.keys(m, {"expect", "tolerance", "store", "same_as", "retries"}, where)
        out: dict[str, Any] = {"expect": {}, "store": None, "same_as": None,
                               "tolerance": v.integer(m, "tolerance", where, 0, fields.INT32[1], 0),
                               "retries": v.integer(m, "retries", where, 0, 5, 2)}
        if "expect" in m:
            fw = join(where, "expect")
            em = v.mapping(m["expect"], m.kline("expect"), fw)
            v.keys(em, set(_ABS_FIELDS), fw)
            for k in em:
                out["expect"][k] = v.integer(em, k, fw, *fields.INT32)
        for k in ("store", "same_as"):
            if k in m:
                name = m[k]
                if not isinstance(name, str) or not fields.NAME_RE.match(name):
                    raise v.err(m.kline(k), join(where, k),
                                f"{name!r}: a name like before_cycle")
                out[k] = name
        return AbsReadArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        reader = abs_reader(d)
        reader.retries = a.retries
        try:
            r = reader.read()
        except AbsReadError as e:
            raise StepFailed(str(e)) from None
        got = {"status": r.status, "turns": r.turns, "position": r.position}
        text = (f"status 0x{r.status:02X}, turns {r.turns}, position {r.position} "
                f"(attempts {r.attempts})")
        ctx.rec.log("info", f"absolute read {d.name}: {text}", name="hil.abs_read")
        want = dict(a.expect)
        if a.same_as:
            want = ctx.store[a.same_as] | want
        tol = a.tolerance
        bad = [f"{k} {got[k]}, expected {x}" + (f" ± {tol}" if k == "position" and tol else "")
               for k, x in want.items()
               if (abs(got[k] - x) > tol if k == "position" else got[k] != x)]
        if r.violations:
            text += "; reader timing: " + "; ".join(r.violations[:3])
        if a.store:
            ctx.store[a.store] = got
        if bad:
            same = f" (as {a.same_as})" if a.same_as else ""
            raise StepFailed(f"{'; '.join(bad)}{same}: read {text}")
        return Outcome(text)

    def describe(self) -> str:
        a = self.args
        want = ", ".join(f"{x}={y}" for x, y in a.expect.items())
        same = f" same as {a.same_as}" if a.same_as else ""
        return f"absolute read (DI/DO){': ' + want if want else ''}{same}"


class AbsOrigin(_Handshake):
    """`abs_origin: {hold: 300ms}`: ABSE on, T_S, ABSC held T_Q (default P2.009 + 250 ms),
    both off (L16436-16450)."""

    name = "abs_origin"
    args: AbsOriginArgs
    need = ("ABSE", "ABSC")

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> AbsOriginArgs:
        m = fields.mapping_or_empty(v, obj, line, where)
        v.keys(m, {"hold"}, where)
        if "hold" not in m:
            return AbsOriginArgs()
        hold = v.duration(m, "hold", where)
        if hold <= 0:
            raise v.err(m.kline("hold"), join(where, "hold"), "must be > 0")
        return AbsOriginArgs(hold)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        reader = abs_reader(d)
        hold = self.args.hold
        reader.set_origin(None if hold is None else hold / 1e6)
        return Outcome(f"ABSC held {(hold / 1e6 if hold else reader.p2009_ms + 250):g} ms")

    def describe(self) -> str:
        return "absolute origin (ABSE + ABSC)"


KINDS = (AbsRead, AbsOrigin)
