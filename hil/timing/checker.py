"""Evaluate a timing spec on recorded signals: pass / fail / inconclusive per constraint.

Observation model: a change observed at t on a signal with resolution r happened in [t - r, t]
(sampled or quantised late, never early). An interval d = t_to - t_from therefore lies in
[d - r_to, d + r_from]; a verdict is `pass` when that whole range is inside the window,
`fail` when it is wholly outside, otherwise `inconclusive`. Windows of `forbid`/`absent`/
`present` are half-open [from + min, from + max). Times are integer ns; messages use ms.

Under load (docs/timing.md): a DI/STO edge the harness stamped at t reached a virtual drive
`lag` later (recorded per edge on /drive/{drive}/inputs), so the drive saw it in [t, t + lag];
a change first seen in a periodic state sample at t (no model event then) happened after the
previous sample, up to `early` before t. A failure whose excess over the limit fits within
these delays of the edges involved is `inconclusive` (the message names them); passes and
larger failures are unchanged.
"""

from __future__ import annotations

import bisect
import fnmatch
import itertools
import math
import operator
import re
from array import array
from collections.abc import Callable, Iterator, Mapping, Sequence
from dataclasses import asdict, dataclass, field, replace
from typing import Any

from hil.record import topics
from hil.timing.expr import ExprError, check_number, is_param
from hil.timing.source import MemorySource, ParamTimeline, SampleList, SignalSource, samples
from hil.timing.spec import ConstraintDef, EventDef, SignalDef, Spec, WindowDef
from hil.units import MS

NEG_INF = -(2**62)
POS_INF = 2**62


def _short(x: Any, n: int = 40) -> str:
    text = repr(x)
    return text if len(text) <= n else text[:n] + "..."


def _duration_ns(e: Any, env: dict[str, Any], what: str) -> int:
    """A duration the spec gives (within, held, resolution) in ns; negative by a parameter or
    a --const is an ExprError (the load refuses a negative literal): cannot judge."""
    ms = e.eval(env)
    if check_number(ms, "a time in ms") < 0:
        raise ExprError(f"{what} = {e.text} is {ms:g} ms: a duration cannot be negative")
    return _ns(ms)


def _ms(ns: float) -> float:
    return ns / MS


def _dur(ns: int) -> str:
    return f"{ns / 1e9:.1f} s" if ns >= 1_000_000_000 else f"{ns / MS:.1f} ms"


def _ns(ms: float) -> int:
    """ms -> ns; a value that is not a finite number within the magnitude limit (a NaN or inf
    parameter, a text) is an ExprError: the constraint is `cannot judge`, never a crash."""
    return round(check_number(ms, "a time in ms") * MS)


@dataclass
class Verdict:
    """One judged constraint (one occurrence of its trigger)."""

    spec: str
    constraint: str
    status: str  # pass | fail | inconclusive | skipped
    message: str
    occurrence: int = 0
    kind: str = "window"
    t_ns: int | None = None  # the trigger (or from-event) time
    from_ns: int | None = None
    to_ns: int | None = None
    measured_ms: float | None = None
    uncertainty_ms: tuple[float, float] = (0.0, 0.0)  # measured can be this much lower/higher
    window_ms: tuple[float | None, float | None] = (None, None)
    window_expr: str = ""
    values: dict[str, Any] = field(default_factory=dict)  # parameters/constants used
    margin_ms: float | None = None
    source: str = ""

    @property
    def passed(self) -> bool:
        return self.status in ("pass", "skipped")

    def to_dict(self) -> dict[str, Any]:
        d = asdict(self)
        d["uncertainty_ms"] = list(self.uncertainty_ms)
        d["window_ms"] = list(self.window_ms)
        return d


@dataclass(frozen=True)
class Occ:
    """An event occurrence observed at t (ns); it really happened in [t - res, t]. When it
    comes from an input edge, the drive saw that edge up to `lag` ns after t; when it was
    first seen in a periodic state sample, it may have happened up to `early` ns before t."""

    t: int
    res: int = 0
    lag: int = 0
    early: int = 0


@dataclass(frozen=True)
class Missing:
    why: str
    root: bool = False  # an event with no `after`/`before` never happened: no such scenario
    # the search ran past the end of what a damaged recording let be read: unknown, not absent
    cut: bool = False


@dataclass
class Trace:
    """A piecewise-constant signal: change points (times, values) and its resolution (ns)."""

    name: str
    times: list[int]
    values: list[Any]
    res: int
    # change time -> (input delivery lag, state sampling gap): delays under load
    lags: dict[int, tuple[int, int]] = field(default_factory=dict)

    def occ(self, t: int) -> Occ:
        lag, early = self.lags.get(t, (0, 0))
        return Occ(t, self.res, lag, early)

    def value_before(self, t: int) -> Any:
        """Value just before t (or at t when nothing earlier); None when unknown."""
        i = bisect.bisect_left(self.times, t)
        if i > 0:
            return self.values[i - 1]
        return self.values[0] if self.times and self.times[0] == t else None

    def value_at(self, t: int) -> Any:
        i = bisect.bisect_right(self.times, t)
        return self.values[i - 1] if i > 0 else None

    def edges(self, kind: str, value: Any = None) -> list[int]:
        out = []
        for i in range(1, len(self.times)):
            a, b = self.values[i - 1], self.values[i]
            if ((kind == "rise" and not a and b) or (kind == "fall" and a and not b)
                    or (kind == "change" and a != b) or (kind == "becomes" and a != b
                                                         and _eq(b, value))):
                out.append(self.times[i])
        return out


def _eq(a: Any, b: Any) -> bool:
    if a == b:
        return True
    return isinstance(a, str) and isinstance(b, str) and a.strip().lower() == b.strip().lower()


class Context:
    """Resolves a spec's signals and events on one source with one binding."""

    def __init__(self, spec: Spec, source: SignalSource, params: ParamTimeline,
                 binding: Mapping[str, str], constants: Mapping[str, Any] | None = None,
                 resolution: Mapping[str, float] | None = None) -> None:
        self.spec, self.source, self.params = spec, source, params
        self.binding = dict(binding)
        self.res_override = dict(resolution or {})  # topic glob -> ms (highest precedence)
        self.const_over = dict(constants or {})
        self._traces: dict[str, Trace] = {}
        self._occs: dict[str, list[Occ]] = {}
        self._deliveries: dict[str, list[tuple[int, bool, int]]] | None = None
        self._topic_sampling: dict[str, tuple[int, set[int], set[int], list[int]]] = {}
        self._thr: dict[int, Any] = {}  # id(transforms) -> `_thresholds`
        end = source.end_time()
        self.end = end if end is not None else 0
        start = source.start_time()  # first timestamp (for "never in <span>")
        self.start = start if start is not None else 0

    # --- names ------------------------------------------------------------------------
    def env(self, t: int | None, only: set[str] | None = None) -> dict[str, Any]:
        """Parameters in force at t plus the spec's constants (overrides win); `only`: of
        the constants, just these (what one expression reads: `_reads`)."""
        env: dict[str, Any] = dict(self.params.at(t))
        for name, e in self.spec.constants.items():
            if only is not None and name not in only:
                continue
            if name in self.const_over:
                env[name] = self.const_over[name]
            else:
                env[name] = e.eval(env)
        env.update(self.const_over)
        return env

    def _reads(self, exprs: list[Any]) -> tuple[set[str], set[str]]:
        """The parameters and the spec constants `exprs` read, directly or through other
        constants (one given in `constants` is a number: nothing read through it)."""
        params: set[str] = set()
        consts: set[str] = set()
        todo = list(exprs)
        while todo:
            e = todo.pop()
            for n in e.names:
                if is_param(n):
                    params.add(n)
                elif n in self.spec.constants and n not in consts:
                    consts.add(n)
                    if n not in self.const_over:
                        todo.append(self.spec.constants[n])
        return params, consts

    def fmt(self, text: str) -> str:
        """Fill {drive}/{dio}/{bus}/{alarm} placeholders from the binding."""
        def sub(m: re.Match) -> str:
            if m.group(1) not in self.binding:
                raise KeyError(f"placeholder {{{m.group(1)}}} is not bound (use --bind "
                               f"{m.group(1)}=...)")
            return self.binding[m.group(1)]

        return re.sub(r"\{(\w+)\}", sub, text)

    # --- signals ----------------------------------------------------------------------
    def _resolution(self, topic: str, sig: SignalDef | None) -> int:
        for pat, ms in self.res_override.items():
            if fnmatch.fnmatchcase(topic, pat):
                return _ns(ms)
        src = self.source.resolution(topic)
        if src is not None:
            return int(src)
        env = self.env(None)
        if sig is not None and sig.resolution is not None:
            return _duration_ns(sig.resolution, env, f"signals.{sig.name}.resolution")
        default = None
        for pat, e in self.spec.resolution.items():
            if pat == "default":
                default = e
            elif fnmatch.fnmatchcase(topic, self.fmt(pat)):
                return _duration_ns(e, env, f"resolution.{pat}")
        return _duration_ns(default, env, "resolution.default") if default is not None else 0

    def _lags(self, s: SignalDef, topic: str, raw: list[tuple[int, Any]]
              ) -> dict[int, tuple[int, int]]:
        """Delays under load of each sample: (delivery, 0) for an input line (DI/STO) edge
        the virtual drive reported on /drive/{drive}/inputs (the record of the same line and
        level whose harness stamp is nearest, within 1 ms); (0, gap) for a message marked
        `periodic` (the virtual bench's state samples between model events): the gap since the
        previous message of its topic."""
        if s.kind not in ("line", "function"):
            out = self._sampling(topic, raw)
            for t, lag in self._frame_lags(topic, raw).items():
                out[t] = (lag, out.get(t, (0, 0))[1])
            return out
        line = (self.binding.get(s.function or "", "") if s.kind == "function"
                else s.io_line or "").partition(":")[0]
        recs = self._delivery_records().get(line)
        if not recs:
            return {}
        out = {}
        for t, v in raw:
            near = [(abs(sent - t), d) for sent, lv, d in recs if lv == bool(v)
                    and abs(sent - t) <= MS]
            if near and (d := min(near)[1]) > 0:
                out[t] = (d, 0)
        return out

    def _delivery_records(self) -> dict[str, list[tuple[int, bool, int]]]:
        """line -> [(sent_ns, level, delay_ns)] from /drive/{drive}/inputs (DI/STO edges,
        and CAN frames under `CAN 080h` lines)."""
        if self._deliveries is None:
            self._deliveries = {}
            drive = self.binding.get("drive")
            for _t, m in self.source.messages(topics.drive_inputs(drive)) if drive else []:
                try:
                    rec = (int(m["sent_ns"]), bool(m["level"]), int(m["delay_ns"]))
                except (KeyError, TypeError, ValueError, OverflowError):
                    continue  # a damaged record: no delivery known for it
                self._deliveries.setdefault(str(m.get("line")), []).append(rec)
        return self._deliveries

    def _frame_lags(self, topic: str, raw: list[tuple[int, Any]]) -> dict[int, int]:
        """Delivery delay of frames the harness sent (`dir: tx` on /canopen/...) that the
        virtual drive reported late: the records of the same COB-ID whose sender stamp lies
        within 5 ms before the frame's record (the tap stamps after the send); the largest."""
        deliveries = self._delivery_records()
        if not raw or not any(k.startswith("CAN ") for k in deliveries):
            return {}
        cobs: dict[int, set[int]] = {}
        for t, cob in samples(self.source, topic, "cob_id", {"dir": "tx"}):
            cobs.setdefault(t, set()).add(int(cob))
        out = {}
        for t, _v in raw:
            lags = [d for c in cobs.get(t, ()) for sent, _lv, d in
                    deliveries.get(topics.can_line(c), ()) if 0 <= t - sent <= 5 * MS]
            if lags:
                out[t] = max(lags)
        return out

    def _sampling(self, topic: str, raw: list[tuple[int, Any]]) -> dict[int, tuple[int, int]]:
        """(0, gap) for samples that are observations, not events: a virtual bench's periodic
        state sample (gap since the previous message of its topic) and a value the harness
        polled, an SDO upload response (`kind: sdo_tx`; gap since the previous sample of the
        same field: a change first seen there happened after that one, e.g. a statusword
        polled late by a loaded harness)."""
        index = self._sampling_index(topic)
        if index is None:
            return {}
        periodic, polled, times = index
        out = {}
        prev = None
        for t, _v in raw:
            i = bisect.bisect_left(times, t)  # the gap: since the message before the first at t
            if i > 0 and periodic(t):
                out[t] = (0, t - times[i - 1])
            elif prev is not None and polled(t):
                out[t] = (0, t - prev)
            prev = t
        return out

    def _sampling_index(self, topic: str) -> tuple[Callable[[int], bool],
                                                   Callable[[int], bool], Any] | None:
        """(a periodic sample at t?, a poll at t?, every message time) of `topic`; None when it
        has neither. Columns answer at each time asked; messages are indexed once per topic
        and source (every signal and every check of a source shares it)."""
        cols = getattr(self.source, "columns", None)
        table = cols(topic) if cols is not None else None
        if table is not None:
            if "periodic" not in table.cols and "kind" not in table.cols:
                return None
            return (lambda t: table.any_at(t, "periodic", bool),
                    lambda t: table.any_at(t, "kind", _is_poll), table.times)
        store = getattr(self.source, "_samples_cache", None)
        key = ("_sampling", topic)
        msgs = self.source.messages(topic)  # first: a re-sort here drops the cached entry
        cached = store.get(key) if store is not None else self._topic_sampling.get(topic)
        if cached is None or cached[0] != len(msgs):
            # a live source only grows (a re-sorted topic drops this): index what is new
            done, periodic, polled, times = cached or (0, set(), set(), [])
            new = msgs[done:] if done else msgs
            periodic = periodic | {t for t, m in new if isinstance(m, dict) and m.get("periodic")}
            polled = polled | {t for t, m in new if isinstance(m, dict) and _is_poll(m.get("kind"))}
            cached = (len(msgs), periodic, polled, times + [t for t, _m in new])
            if store is not None:
                store[key] = cached
            else:
                self._topic_sampling[topic] = cached
        _n, periodic, polled, times = cached
        if not periodic and not polled:
            return None
        return periodic.__contains__, polled.__contains__, times

    def trace(self, name: str) -> Trace:
        if name not in self._traces:
            self._traces[name] = self._build(name)
        return self._traces[name]

    def _signal_def(self, name: str) -> SignalDef:
        if name in self.spec.signals:
            return self.spec.signals[name]
        if name.startswith("alarm:"):
            return SignalDef(name=name[6:], kind="alarm", line=0, alarm=[name[6:]],
                             topic="/drive/{drive}/state", field="alarms")
        raise KeyError(f"unknown signal {name!r}")

    def _build(self, name: str) -> Trace:
        s = self._signal_def(name)
        if s.kind in ("topic", "function", "line", "alarm"):
            topic, fld, invert = self._where_from(s)
            raw = samples(self.source, topic, fld, s.where, runs=self._runs_suffice(s))
            res = self._resolution(topic, s)
            if s.kind == "function" or s.kind == "line":
                self._want(s, raw, bool, "a level (true or false)")
                pts = [(t, bool(v) != invert) for t, v in raw]
            elif s.kind == "alarm":
                codes = [self.fmt(c) for c in s.alarm or []]
                pts = []
                append = pts.append
                last: Any = None
                active = False
                for t, v in raw:
                    # the alarm list rarely changes between two state samples: an equal list of
                    # strings gives the same answer (a str equals only a str)
                    if not (type(v) is list and v == last and all(type(x) is str for x in v)):
                        active = _alarm_active(v, codes)
                        last = v if type(v) is list else None
                    append((t, active))
            else:
                if not s.transforms:  # read as it is: a level, a number or a name
                    self._want(s, raw, (bool, int, float, str, type(None)), "a single value")
                pts = raw
            pts = self._transform(s, pts)
            return self._held(s, _compress(s.name, pts, res, self._lags(s, topic, raw)))
        if s.kind == "signal":
            parent = self.trace(s.source or "")
            pts = self._transform(s, self._with_limit_changes(s, parent))
            return self._held(s, _compress(s.name, pts, parent.res, parent.lags))
        parents = [self.trace(p) for p in s.parts]
        return _combine(s.name, s.kind, parents)

    def _want(self, s: SignalDef, raw: Sequence[tuple[int, Any]], types: Any,
              what: str) -> None:
        """ExprError (the check cannot judge) for a recorded value not of `types`: a level
        recorded as the text "false" would read as true, a list as false."""
        if isinstance(raw, SampleList) and type(raw.values) is array:
            return  # numbers from a typed column
        for t, v in raw:
            if not isinstance(v, types):
                at = _ms(t - self.start) if self.start is not None else 0.0
                raise ExprError(f"signal {s.name}: the recorded value {_short(v)} ({at:.1f} ms "
                                f"into the recording) is not {what}")

    def _with_limit_changes(self, s: SignalDef, parent: Trace) -> SampleList:
        """The parent's change points, and where a `below`/`above` limit changes between two
        of them (a parameter written while the value holds), the value held then: the
        comparison changes at the write, not at the parent's next change."""
        pts = SampleList(parent.times, parent.values)
        thresholds = self._thresholds(s.transforms)
        if thresholds is None or thresholds.constant or not parent.times:
            return pts
        first = parent.times[0]
        have = set(parent.times)
        extra = [t for t in thresholds.times if t > first and t not in have]
        if not extra:
            return pts
        merged = sorted([*pts, *((t, parent.value_at(t)) for t in extra)], key=lambda p: p[0])
        return SampleList([t for t, _v in merged], [v for _t, v in merged])

    def _runs_suffice(self, s: SignalDef) -> bool:
        """A change-point trace of `s` needs only the first and last sample of each run of
        equal values, unless a threshold changes over time (a parameter written mid-run
        moves the change of `below`/`above` into the run)."""
        thresholds = self._thresholds(s.transforms)
        return thresholds is None or thresholds.constant

    def _where_from(self, s: SignalDef) -> tuple[str, str, bool]:
        if s.kind == "function":
            line = self.binding.get(s.function or "")
            if not line:
                raise KeyError(f"function {s.function} is not bound to a line")
            ln, _, contact = line.partition(":")
            return topics.dio(self.binding["dio"], ln), "level", contact == "b"
        if s.kind == "line":
            return topics.dio(self.binding["dio"], s.io_line or ""), "level", False
        return self.fmt(s.topic or ""), s.field or "", False

    def _transform(self, s: SignalDef, pts: list[tuple[int, Any]]) -> list[tuple[int, Any]]:
        tf = s.transforms
        if not tf:
            return pts
        thresholds = self._thresholds(tf)
        # the value transforms in their fixed order, looked up once rather than per sample
        ops: list[Callable[[Any], Any]] = []
        if "map" in tf:
            m = tf["map"]
            ops.append(lambda v, m=m: m.get(v, m.get(str(v), v)))
        if "bit" in tf:
            ops.append(lambda v, b=tf["bit"]: bool((int(v) >> b) & 1))
        if "mask" in tf:
            ops.append(lambda v, k=tf["mask"]: int(v) & k)
        if tf.get("abs"):
            ops.append(abs)
        if "equals" in tf:
            ops.append(lambda v, x=tf["equals"]: _eq(v, x))
        if "in" in tf:
            ops.append(lambda v, xs=tf["in"]: any(_eq(v, x) for x in xs))
        if tf.get("nonempty"):
            ops.append(bool)
        cmp = "below" if "below" in tf else "above" if "above" in tf else None
        # times from an integer array stay in one (any other source: as they come)
        ts: Any = array("q") if isinstance(pts, SampleList) and type(pts.times) is array else []
        vs: list[Any] = []
        t_append, v_append = ts.append, vs.append
        # the limit in force over [lo, hi): looked up again only when a sample leaves it (the
        # samples come in time order; a parameter written mid-run moves it a few times)
        lim_v: Any = None
        lo, hi = POS_INF, NEG_INF
        t = v = raw = None
        try:
            for t, raw in pts:
                v = raw
                for op in ops:
                    v = op(v)
                if thresholds:
                    if not lo <= t < hi:
                        lim, lo, hi = thresholds(t)
                        lim_v = lim[cmp] if cmp else None
                    if cmp == "below":
                        v = v < lim_v
                    elif cmp == "above":
                        v = v > lim_v
                t_append(t)
                v_append(v)
        except (TypeError, ValueError) as e:  # a text, a list, a null where a number belongs
            if isinstance(e, ExprError):
                raise
            ops_text = ", ".join(k for k in ("map", "bit", "mask", "abs", "equals", "in",
                                             "nonempty", "below", "above") if k in tf)
            at = _ms((t or 0) - self.start) if self.start is not None else 0.0
            raise ExprError(f"signal {s.name}: the recorded value {_short(raw)} ({at:.1f} ms "
                            f"into the recording) cannot take {ops_text}") from None
        return SampleList(ts, vs)  # 16 bytes a sample: a long recording's signal is long

    def _held(self, s: SignalDef, tr: Trace) -> Trace:
        """`held: D`: true only once the value has been true for D ms (an on-delay timer)."""
        if "held" not in s.transforms:
            return tr
        pts: list[tuple[int, Any]] = []
        lags = dict(tr.lags)
        since: int | None = None  # where the value became true (a true value that changes
        due = POS_INF             # to another true value, a longer alarm list, goes on)
        for i, t in enumerate(tr.times):
            if not tr.values[i]:
                since = None
                pts.append((t, False))
                continue
            if since is None:
                since = t
                due = t + _duration_ns(s.transforms["held"], self.env(t), f"signals.{s.name}.held")
            nxt = tr.times[i + 1] if i + 1 < len(tr.times) else POS_INF
            pts.append((t, due <= t))
            if t < due < nxt and due <= self.end:
                pts.append((due, True))
                if since in tr.lags:  # the timer started when the drive saw the edge
                    lags[due] = tr.lags[since]
        return _compress(tr.name, pts, tr.res, lags)

    def _thresholds(self, tf: dict[str, Any]) -> Any:
        """`span(t)`: the `below`/`above` limits in force at t and the times [lo, hi) they hold
        over (`.constant`: one value throughout); None without them. Evaluated once per
        transform and context."""
        keys = [k for k in ("below", "above") if k in tf]  # `held` is applied after
        if not keys:
            return None
        if id(tf) in self._thr:
            return self._thr[id(tf)]
        # the limits with what they read, where a parameter they read (themselves or through
        # a constant) changed: a constant they do not read is not theirs to fail on
        params, consts = self._reads([tf[k] for k in keys])
        times = self.params.change_times(params) or [0]
        vals = [{k: tf[k].eval(env) for k in keys}
                for env in (self.env(t, consts) for t in times)]

        def span(t: int) -> tuple[dict[str, float], int, int]:
            k = bisect.bisect_right(times, t) - 1
            lo = times[k] if k >= 0 else NEG_INF
            hi = times[k + 1] if k + 1 < len(times) else POS_INF
            return vals[max(0, k)], lo, hi

        constant = all(v == vals[0] for v in vals)  # the usual case: one value throughout
        if constant:
            times, vals = times[:1], vals[:1]  # no search per sample
        span.constant = constant  # type: ignore[attr-defined]
        span.times = times  # type: ignore[attr-defined]
        self._thr[id(tf)] = span
        return span

    # --- events -----------------------------------------------------------------------
    def occurrences(self, name: str) -> list[Occ]:
        """All occurrences of an edge-type event over the whole source."""
        if name not in self._occs:
            ev = self.spec.events[name]
            if ev.kind in ("rise", "fall", "change", "becomes", "raised", "cleared"):
                tr = self.trace(ev.signal or "")
                kind = {"raised": "rise", "cleared": "fall"}.get(ev.kind, ev.kind)
                times = (tr.edges(kind, ev.value) if ev.held is None
                         else self._lasting(tr, kind, ev))
                self._occs[name] = [tr.occ(t) for t in times]
            elif ev.kind == "message":
                self._occs[name] = self._messages(ev.signal or "")
            else:
                occ = Scope(self, 0, NEG_INF, POS_INF).resolve(name)
                self._occs[name] = [occ] if isinstance(occ, Occ) else []
        return self._occs[name]

    def _lasting(self, tr: Any, kind: str, ev: EventDef) -> list[int]:
        """The `kind` edges of the signal as a filter of `ev.held` ms passes it (a DI filter,
        P2.009, L9229-9236; its parameters as at each change): a change counts once its new
        value has lasted that long, stamped at the change itself; a bounce shorter than that
        changes nothing, nor does the return to the value the filter still holds. A change
        too near the recording's end to tell is kept."""
        times, values = tr.times, tr.values
        out: list[int] = []
        if not times:
            return out
        # the filter's length, worked out once per change of a parameter it reads (as the
        # thresholds are: `_thresholds`), not at every change of the signal
        params, consts = self._reads([ev.held])
        at = self.params.change_times(params) or [0]
        need_at: list[int | None] = [None] * len(at)  # worked out when an edge needs it
        held = values[0]  # what the filter passes
        n = len(times)
        for i in range(1, n):
            a, b = values[i - 1], values[i]
            if a == b or b == held:
                continue
            t = times[i]
            j = i + 1
            while j < n and values[j] == b:
                j += 1
            k = bisect.bisect_right(at, t) - 1
            if k < 0:  # before a parameter's first record: as the window rules read it then
                # (a value first written later does not cover the time before it: cannot judge)
                need = _duration_ns(ev.held, self.env(t, consts), "held")
            else:
                if need_at[k] is None:
                    need_at[k] = _duration_ns(ev.held, self.env(at[k], consts), "held")
                need = need_at[k]
            if j < n and times[j] - t < need:
                continue  # a bounce
            if ((kind == "rise" and not held and b) or (kind == "fall" and held and not b)
                    or (kind == "change") or (kind == "becomes" and _eq(b, ev.value))):
                out.append(t)
            held = b
        return out

    def _messages(self, name: str) -> list[Occ]:
        """`message: SIG`: every recorded message of the signal's topic that passes its
        `where` and whose value (after the transforms) is true, e.g. each SYNC frame the
        harness put on the wire; a repeated value is an event each time."""
        s = self._signal_def(name)
        topic, fld, _ = self._where_from(s)
        raw = samples(self.source, topic, fld, s.where)
        res = self._resolution(topic, s)
        lags = self._lags(s, topic, raw)
        return [Occ(t, res, *lags.get(t, (0, 0))) for t, v in self._transform(s, raw) if v]

    def label(self, name: str, nested: bool = False) -> str:
        """An event's text for verdicts; a composite inside a composite is named, not spelt
        out (a spec of shared composites would otherwise grow its labels exponentially)."""
        ev = self.spec.events[name]
        if ev.label:
            return ev.label
        sig = (ev.signal or "").removeprefix("alarm:")
        verbs = {"rise": "rose", "fall": "fell", "change": "changed", "raised": "raised",
                 "cleared": "cleared", "first_true": "true", "message": "message"}
        if ev.kind in verbs:
            return f"{sig} {verbs[ev.kind]}"
        if ev.kind == "becomes":
            return f"{sig} became {ev.value}"
        if nested:
            return name
        if ev.kind == "at":
            return f"{self.label(ev.refs[0], True)} + {ev.plus}"
        return f"{ev.kind.replace('_', ' ')} ({', '.join(self.label(r, True) for r in ev.refs)})"

    def expectation(self, name: str) -> str:
        ev = self.spec.events[name]
        sig = (ev.signal or "").removeprefix("alarm:")
        return {
            "rise": f"{sig} to rise", "fall": f"{sig} to fall", "change": f"{sig} to change",
            "becomes": f"{sig} to become {ev.value}", "raised": f"{sig} to be raised",
            "cleared": f"{sig} to clear", "first_true": f"{sig} to be true",
            "message": f"a {sig} message",
        }.get(ev.kind, self.label(name))


def _is_poll(kind: Any) -> bool:
    """An SDO upload response: a value the harness polled."""
    return kind == "sdo_tx"


def _alarm_active(v: Any, codes: list[str]) -> bool:
    items = [str(x) for x in v] if isinstance(v, list | tuple | set) else []
    if "any" in codes:
        return bool(items)
    return any(c in items for c in codes)


def _in_order(pts: Sequence[tuple[int, Any]]) -> bool:
    times = pts.times if isinstance(pts, SampleList) else [p[0] for p in pts]
    return all(map(operator.le, times, itertools.islice(times, 1, None)))


def _compress(name: str, pts: Sequence[tuple[int, Any]], res: int,
              lags: Mapping[int, tuple[int, int]] | None = None) -> Trace:
    if not _in_order(pts):  # sources give samples in time order: this is the rare case
        pts = sorted(pts, key=lambda p: p[0])
    # the change times from an integer array stay in one: 8 bytes each, however many; and
    # numbers straight from a typed column stay typed (a speed that changes every sample)
    whole = isinstance(pts, SampleList) and type(pts.times) is array
    typed = whole and type(pts.values) is array  # type: ignore[union-attr]
    if typed:  # a number straight from a column, changing at every sample (a speed): when
        ts, vs = pts.times, pts.values  # nothing would be dropped, the arrays are the trace
        if all(map(operator.lt, ts, itertools.islice(ts, 1, None))) and all(
                map(operator.ne, vs, itertools.islice(vs, 1, None))):
            kept = {t: lags[t] for t in ts if t in lags} if lags else {}
            return Trace(name, ts, vs, res, kept)
    times: Any = array("q") if whole else []
    values: Any = array(pts.values.typecode) if typed else []  # type: ignore[union-attr]
    for t, v in pts:
        if values and times[-1] == t:
            values[-1] = v  # the later message at the same instant wins
            if len(values) > 1 and values[-2] == v:
                times.pop()
                values.pop()
        elif not values or values[-1] != v:
            times.append(t)
            values.append(v)
    kept = {t: lags[t] for t in times if t in lags} if lags else {}
    return Trace(name, times, values, res, kept)


def _combine(name: str, kind: str, parents: list[Trace]) -> Trace:
    all_t = sorted({t for p in parents for t in p.times})
    start = max((p.times[0] for p in parents if p.times), default=None)
    if start is None or any(not p.times for p in parents):
        return Trace(name, [], [], max(p.res for p in parents))
    pts = []
    lags = {}
    for t in all_t:
        if t < start:
            continue
        vals = [bool(p.value_at(t)) for p in parents]
        v = all(vals) if kind == "all" else any(vals) if kind == "any" else not vals[0]
        pts.append((t, v))
        got = [p.lags[t] for p in parents if t in p.lags]
        if got:
            lags[t] = (max(g[0] for g in got), max(g[1] for g in got))
    return _compress(name, pts, max(p.res for p in parents), lags)


class Scope:
    """One occurrence of a constraint's trigger: events are searched in [start, end)."""

    def __init__(self, ctx: Context, index: int, start: int, end: int,
                 trigger: str | None = None, trigger_occ: Occ | None = None) -> None:
        self.ctx, self.index, self.start, self.end = ctx, index, start, end
        self.trigger, self.trigger_occ = trigger, trigger_occ
        self._memo: dict[str, Occ | Missing] = {}

    def resolve(self, name: str) -> Occ | Missing:
        if name == self.trigger and self.trigger_occ is not None:
            return self.trigger_occ
        if name not in self._memo:
            self._memo[name] = Missing("cycle")  # guarded by the loader; belt and braces
            self._memo[name] = self._resolve(self.ctx.spec.events[name])
        return self._memo[name]

    def _horizon(self, ev: EventDef, anchor_t: int) -> int:
        within = ev.within or self.ctx.spec.horizon
        end = self.end
        if within is not None:
            end = min(end, anchor_t + _duration_ns(within, self.ctx.env(anchor_t), "within") + 1)
        return end

    def _resolve(self, ev: EventDef) -> Occ | Missing:
        ctx = self.ctx
        if ev.kind == "at":
            base = self.resolve(ev.refs[0])
            if isinstance(base, Missing):
                return base
            return replace(base, t=base.t + _ns(ev.plus.eval(ctx.env(base.t))))  # type: ignore[union-attr]
        if ev.kind in ("earliest_of", "latest_of"):
            got = [self.resolve(r) for r in ev.refs]
            occs = [o for o in got if isinstance(o, Occ)]
            if (ev.kind == "latest_of" and len(occs) < len(got)) or not occs:
                return next(o for o in got if isinstance(o, Missing))
            pick = min if ev.kind == "earliest_of" else max
            t = pick(o.t for o in occs)
            lo = pick(o.t - o.res for o in occs)
            return Occ(t, t - lo, max(o.lag for o in occs if o.t == t),
                       max(o.early for o in occs if o.t == t))
        lo, hi, anchor = self.start, self.end, None
        if ev.after:
            a = self.resolve(ev.after)
            if isinstance(a, Missing):
                return a
            anchor = a
            lo, hi = a.t, self._horizon(ev, a.t)
        if ev.before:
            b = self.resolve(ev.before)
            if isinstance(b, Missing):
                return b
            lo = NEG_INF if ev.within is None else (
                b.t - _duration_ns(ev.within, ctx.env(b.t), "within"))
            occs = self._candidates(ev, lo, b.t + 1, b, every=True)
            if occs:
                return occs[-1]
            return Missing(f"no {ctx.expectation(ev.name).replace(' to ', ' ', 1)} "
                           f"before {ctx.label(ev.before)}")
        occs = self._candidates(ev, lo, hi, anchor)
        if occs:
            return occs[0]
        span = min(hi, ctx.end) - (anchor.t if anchor else max(lo, ctx.start))
        after = f" after {ctx.label(ev.after)}" if ev.after else ""
        cut = getattr(ctx.source, "cut_ns", None)
        if cut is not None and hi > cut:
            footer = getattr(ctx.source, "footer", False)
            killed = "" if footer else " (no footer: the run was killed)"
            where = (f"the recording's end{killed}, and what followed was not recorded"
                     if getattr(ctx.source, "cut_kind", None) == "end" else
                     "the recording's damage, and what followed could not be read")
            return Missing(f"expected {ctx.expectation(ev.name)}{after}; not seen in the "
                           f"{_dur(max(span, 0))} before {where}", root=not ev.after, cut=True)
        return Missing(f"expected {ctx.expectation(ev.name)}{after}; it never did in "
                       f"{_dur(max(span, 0))}", root=not ev.after)

    def _candidates(self, ev: EventDef, lo: int, hi: int, anchor: Occ | None,
                    every: bool = False) -> list[Occ]:
        """The occurrences in [lo, hi) in time order; of a `first_true`, the first one (the
        start of the range when already true then), or with `every` (a `before:` search,
        which takes the last) each instant it became true."""
        if ev.kind == "first_true":
            tr = self.ctx.trace(ev.signal or "")
            start = max(lo, tr.times[0]) if tr.times else lo
            head: list[Occ] = []
            if tr.times and tr.value_at(start) and start < hi:
                head = [anchor if anchor is not None and start == anchor.t else tr.occ(start)]
                if not every:
                    return head
            rises = [tr.occ(t) for t in tr.edges("rise") if lo <= t < hi and t != start]
            return head + rises if every else rises[:1]
        occs = self.ctx.occurrences(ev.name)
        ts = [o.t for o in occs]
        return occs[bisect.bisect_left(ts, lo):bisect.bisect_left(ts, hi)]


# --- constraints -----------------------------------------------------------------------


def _signal_reads(spec: Spec, bind: Mapping[str, str]) -> Iterator[tuple[SignalDef, str, str]]:
    """(signal, topic, field) of each recorded signal of `spec` under a resolved `bind`
    (a signal whose function or line is not bound is left out)."""
    ctx = Context(spec, MemorySource(), ParamTimeline(), bind, None, None)
    for s in spec.signals.values():
        if s.kind in ("topic", "function", "line", "alarm"):
            try:
                topic, fld, _inv = ctx._where_from(s)
            except KeyError:
                continue
            yield s, topic, fld


def spec_topics(spec: Spec, binding: Mapping[str, str] | None = None) -> set[str]:
    """The topics judging `spec` reads under `binding`: its recorded signals' topics, the
    drive's parameters and its input deliveries (for a reader that decodes only those)."""
    bind = spec.binding(binding)
    drive = bind.get("drive", "drive1")  # `alarm:ALnnn` events read the drive's state
    out = {topics.drive_params(drive), topics.drive_inputs(drive), topics.drive_state(drive)}
    out.update(topic for _s, topic, _f in _signal_reads(spec, bind))
    return out


#: the fields the checker reads of every signal topic besides the signals' own: whether a
#: sample is periodic or a poll (`_sampling`), and a sent frame's COB-ID (`_frame_lags`)
_SAMPLING_FIELDS = ("periodic", "kind", "dir", "cob_id")


def spec_columns(spec: Spec, binding: Mapping[str, str] | None = None
                 ) -> dict[str, set[str]]:
    """The signal topics judging `spec` reads under `binding`, each with the top-level
    fields read of it: what a long recording's source holds as columns
    (`RecordingSource(columns=...)`). The drive's parameters and input deliveries are not
    among them (they stay messages: `spec_topics` has them)."""
    bind = spec.binding(binding)
    drive = bind.get("drive", "drive1")
    whole = {topics.drive_params(drive), topics.drive_inputs(drive)}  # read as messages
    out: dict[str, set[str]] = {}
    for s, topic, fld in _signal_reads(spec, bind):
        if topic in whole:
            continue
        fields = out.setdefault(topic, set(_SAMPLING_FIELDS))
        fields.add(fld.split(".")[0])
        fields.update(k.split(".")[0] for k in s.where)
    # `alarm:ALnnn` events read the drive's alarms
    out.setdefault(topics.drive_state(drive), set(_SAMPLING_FIELDS)).add("alarms")
    return out


def state_fields(spec: Spec) -> set[str]:
    """The fields of the ground-truth state (`/drive/<drive>/state`) judging `spec` reads:
    its topic signals' fields and `where` keys on that topic, `alarms` for its alarm
    signals (a report keeps only these of each sample)."""
    out: set[str] = set()
    for s in spec.signals.values():
        if s.kind == "alarm":
            out.add("alarms")
        elif s.kind == "topic" and s.topic and s.topic.startswith("/drive/") \
                and s.topic.endswith("/state"):
            out.add((s.field or "").split(".")[0])
            out.update(k.split(".")[0] for k in s.where)
    return out


def context(spec: Spec, source: SignalSource,
            params: Mapping[str, Any] | ParamTimeline | None = None,
            binding: Mapping[str, str] | None = None, constants: Mapping[str, Any] | None = None,
            resolution: Mapping[str, float] | None = None) -> Context:
    """The resolver `check` uses (also used by the renderer to draw the same signals)."""
    bind = spec.binding(binding)
    if isinstance(params, ParamTimeline):
        timeline = params
    else:
        topic = topics.drive_params(bind.get("drive", "drive1"))
        timeline = ParamTimeline.from_source(source, topic, params)
    return Context(spec, source, timeline, bind, constants, resolution)


def check(spec: Spec, source: SignalSource, params: Mapping[str, Any] | ParamTimeline | None = None,
          binding: Mapping[str, str] | None = None, constants: Mapping[str, Any] | None = None,
          resolution: Mapping[str, float] | None = None) -> list[Verdict]:
    """Judge every constraint of `spec` on `source`; one Verdict per constraint occurrence.

    params: overrides (name -> value) over the parameters recorded on /drive/{drive}/params,
    or a ready ParamTimeline. binding: placeholders and function->line (see Spec.binding).
    resolution: topic glob -> ms, overriding what the source and the spec say.
    """
    ctx = context(spec, source, params, binding, constants, resolution)
    out: list[Verdict] = []
    for c in spec.constraints:
        try:
            out.extend(_judge_constraint(ctx, c))
        except (KeyError, ExprError) as e:
            msg = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
            if isinstance(e, KeyError) and is_param(str(msg)):
                msg = f"parameter {msg} is neither recorded nor given (--param {msg}=...)"
            out.append(Verdict(spec.id, c.name, "inconclusive", f"cannot judge: {msg}",
                               kind=c.kind, source=c.source))
    return out


def _judge_constraint(ctx: Context, c: ConstraintDef) -> list[Verdict]:
    if c.for_each is None:
        return [_judge(ctx, c, Scope(ctx, 0, NEG_INF, POS_INF))]
    trig = ctx.occurrences(c.for_each)
    if not trig:
        return [Verdict(ctx.spec.id, c.name, "skipped",
                        f"not applicable: no {ctx.label(c.for_each)} in the recording",
                        kind=c.kind, source=c.source)]
    out = []
    for i, o in enumerate(trig):
        end = trig[i + 1].t if i + 1 < len(trig) else POS_INF
        out.append(_judge(ctx, c, Scope(ctx, i, o.t, end, c.for_each, o)))
    return out


def _judge(ctx: Context, c: ConstraintDef, sc: Scope) -> Verdict:
    base = dict(spec=ctx.spec.id, constraint=c.name, occurrence=sc.index, kind=c.kind,
                source=c.source)
    ref_name = c.frm or c.at
    ref = sc.resolve(ref_name) if ref_name else None
    t_ref = sc.trigger_occ.t if sc.trigger_occ else (ref.t if isinstance(ref, Occ) else None)
    if c.when is not None:
        env = ctx.env(t_ref)
        unknown = []
        for n in c.when.names:
            if n in ctx.spec.signals:
                val = ctx.trace(n).value_at(t_ref) if t_ref is not None else None
                if val is None:
                    unknown.append(n)  # inconclusive only if its value decides (and/or
                    continue           # stop at the first operand that does)
                env[n] = val
        try:
            applies = c.when.eval(env)
        except KeyError as e:
            if not (e.args and e.args[0] in unknown):
                raise
            return Verdict(**base, status="inconclusive", t_ns=t_ref,
                           message=f"cannot evaluate `when: {c.when}`: {e.args[0]} unknown then")
        if not applies:
            used = ", ".join(f"{n} = {env.get(n, 'unknown')}" for n in sorted(c.when.names))
            return Verdict(**base, status="skipped", t_ns=t_ref,
                           message=f"not applicable: `{c.when}` is false ({used})")
    if isinstance(ref, Missing):
        # the event the constraint starts from hangs off one that never happened at all:
        # the scenario is not in this recording (as a for_each with no trigger)
        if ref.root:
            return Verdict(**base, status="skipped", t_ns=t_ref,
                           message=f"not applicable: {ref.why}")
        if ref.cut and c.kind == "window":
            return Verdict(**base, status="inconclusive", t_ns=t_ref, message=ref.why)
        status = "fail" if c.kind == "window" else "skipped"
        return Verdict(**base, status=status, t_ns=t_ref, message=ref.why)
    assert ref is not None
    if c.kind == "window":
        return _judge_window(ctx, c, sc, ref, base)
    return _judge_forbid(ctx, c, sc, ref, base)


def _window_values(ctx: Context, w: WindowDef, t: int) -> tuple[float | None, float | None, dict]:
    env = ctx.env(t)
    lo = float(w.min.number(env)) if w.min is not None else None
    hi = float(w.max.number(env)) if w.max is not None else None
    used = {n: env[n] for e in (w.min, w.max) if e for n in sorted(e.names)}
    if lo is not None and hi is not None and lo > hi:  # by a parameter or a --const
        ps = ", ".join(f"{n} = {v:g}" for n, v in used.items())
        raise ExprError(f"window min {lo:g} ms > max {hi:g} ms ({ps}): no time can be inside")
    return lo, hi, used


def _allowed(w: WindowDef, lo: float | None, hi: float | None, used: dict) -> str:
    ps = ", ".join(f"{n} = {v:g}" for n, v in used.items() if is_param(n))
    ps = f" ({ps})" if ps else ""
    if lo is not None and hi is not None:
        m1 = re.fullmatch(r"(.+?)\s*-\s*([^-+]+)", w.min.text) if w.min else None
        m2 = re.fullmatch(r"(.+?)\s*\+\s*([^-+]+)", w.max.text) if w.max else None
        if m1 and m2 and m1.groups() == m2.groups():
            return f"{(lo + hi) / 2:.1f} ± {(hi - lo) / 2:.1f} ms{ps}"
        return f"{lo:.1f} … {hi:.1f} ms{ps}"
    if hi is not None:
        return f"≤ {hi:.1f} ms{ps}"
    return f"≥ {lo:.1f} ms{ps}"


def _half_open(lo: float | None, hi: float | None, used: dict) -> str:
    ps = ", ".join(f"{n} = {v:g}" for n, v in used.items() if is_param(n))
    a = f"{lo:.1f}" if lo is not None else "0.0"
    b = f"{hi:.1f}" if hi is not None else "∞"
    return f"[{a}, {b}) ms" + (f" ({ps})" if ps else "")


def _judge_window(ctx, c, sc, f: Occ, base) -> Verdict:
    to = sc.resolve(c.to)
    lo, hi, used = _window_values(ctx, c.window, f.t)
    common = dict(base, t_ns=f.t, from_ns=f.t, window_ms=(lo, hi),
                  window_expr=c.window.text(), values=used)
    if isinstance(to, Missing):
        return Verdict(**common, status="inconclusive" if to.cut else "fail", message=to.why)
    # judged in integer ns, as the times are (in float ms, 2.2 - 1.2 > 1.0 would fail an
    # observation whose range touches the limit); ms only for the message
    dn = to.t - f.t
    d = _ms(dn)
    dlo, dhi = dn - to.res, dn + f.res
    flo = -math.inf if lo is None else _ns(lo)
    fhi = math.inf if hi is None else _ns(hi)
    margin = _ms(min(dn - flo, fhi - dn))
    head = f"{ctx.label(c.to)} {d:.1f} ms after {ctx.label(c.frm)}"
    allowed = _allowed(c.window, lo, hi, used)
    if dlo >= flo and dhi <= fhi:
        status, tail = "pass", f"margin {margin:.1f} ms"
    elif dhi < flo or dlo > fhi:
        status = "fail"
        tail = f"{_ms(dn - fhi):.1f} ms late" if dn > fhi else f"{_ms(flo - dn):.1f} ms early"
    else:
        status = "inconclusive"
        tail = (f"observation resolution (−{_ms(to.res):g}/+{_ms(f.res):g} ms) straddles "
                f"the {'upper' if dhi > fhi else 'lower'} limit")
    unc = (_ms(to.res), _ms(f.res))
    lower, higher = f.lag + to.early, to.lag + f.early  # delays under load (ns)
    if status == "fail" and (lower or higher):
        llo, lhi = dlo - lower, dhi + higher
        if not (lhi < flo or llo > fhi):
            status, unc = "inconclusive", (unc[0] + _ms(lower), unc[1] + _ms(higher))
            tail += f", {_load_reason(f.lag + to.lag, f.early + to.early)}"
        else:
            tail += f" (beyond {_load_what(f.lag + to.lag, f.early + to.early)})"
    return Verdict(**common, status=status, to_ns=to.t, measured_ms=d,
                   uncertainty_ms=unc, margin_ms=margin,
                   message=f"{head}; allowed {allowed}: {tail}")


def _load_what(lag: int, early: int) -> str:
    parts = []
    if lag:
        parts.append(f"the {_ms(lag):.3f} ms the input took to reach the drive after "
                     "the harness stamped it")
    if early:
        parts.append(f"the {_ms(early):.3f} ms since the previous observation (a state sample "
                     "or a poll)")
    return " and ".join(parts)


def _load_reason(lag: int, early: int) -> str:
    return f"within {_load_what(lag, early)} (delays under load): inconclusive"


def _span(ctx, c, sc, f: Occ) -> tuple[int, int, int, int, float | None, float | None, dict]:
    """Possible and sure window [lo, hi) in ns for forbid/absent/present."""
    if c.at:
        return f.t - f.res, f.t, f.t - f.res, f.t, None, None, {}
    if c.window is not None:
        lo, hi, used = _window_values(ctx, c.window, f.t)
        wlo = _ns(lo) if lo is not None else 0
        whi = _ns(hi) if hi is not None else POS_INF - f.t
        return f.t - f.res + wlo, f.t + whi, f.t + wlo, f.t - f.res + whi, lo, hi, used
    u = sc.resolve(c.until)
    end = POS_INF if isinstance(u, Missing) else u.t
    end_sure = POS_INF if isinstance(u, Missing) else u.t - u.res
    return f.t - f.res, end, f.t, end_sure, 0.0, None, {}


def _judge_forbid(ctx, c, sc, f: Occ, base) -> Verdict:
    plo, phi, slo, shi, lo, hi, used = _span(ctx, c, sc, f)
    common = dict(base, t_ns=f.t, from_ns=f.t, window_ms=(lo, hi), values=used,
                  window_expr=c.window.text() if c.window else (f"until {c.until}" if c.until
                                                               else f"at {c.at}"))
    where = (f"at {ctx.label(c.at)}" if c.at else
             f"before {ctx.label(c.until)}" if c.until and not c.window else
             f"within {_half_open(lo, hi, used)} of {ctx.label(c.frm)}" if c.window else "")
    if c.kind == "forbid":
        ev = ctx.spec.events[c.target]
        # an edge with no anchor: every one of them; an event tied to another (`after`,
        # `before`, `within`: "the first Y rise after C") is that one occurrence
        plain = ev.after is None and ev.before is None and ev.within is None
        occs = (ctx.occurrences(c.target) if plain and ev.kind in
                ("rise", "fall", "change", "becomes", "raised", "cleared", "message") else
                [o for o in [sc.resolve(c.target)] if isinstance(o, Occ)])
        status, hit, why = "pass", None, " (within the observation resolution)"
        for o in occs:
            if o.t - o.res >= slo and o.t < shi:
                if (o.t - o.res - o.early >= slo + f.lag
                        and o.t + o.lag < shi - f.early):
                    status, hit = "fail", o
                    break
                if status != "inconclusive":  # surely inside but for the delays under load
                    status, hit = "inconclusive", o
                    why = f" ({_load_reason(f.lag + o.lag, f.early + o.early)})"
            if o.t >= plo and o.t - o.res < phi and status == "pass":
                status, hit = "inconclusive", o
        what = ctx.label(c.target)
        if hit is None:
            return Verdict(**common, status="pass", message=f"no {what} {where}")
        d = _ms(hit.t - f.t)
        return Verdict(**common, status=status, to_ns=hit.t, measured_ms=d,
                       margin_ms=-abs(d) if status == "fail" else None,
                       message=f"{what} {d:.1f} ms after {ctx.label(c.frm or c.at)}: "
                       f"must not happen {where}" + ("" if status == "fail" else why))
    return _judge_level(ctx, c, f, common, where, (plo, phi, slo, shi))


def _judge_level(ctx, c, f: Occ, common: dict, where: str,
                 span: tuple[int, int, int, int]) -> Verdict:
    """absent / present: the signal must be false / true over the window."""
    plo, phi, slo, shi = span
    late = ""
    tr = ctx.trace(c.target)
    want = c.kind == "present"
    surely_bad, maybe_bad = _bad_spans(tr, want, ctx.end)
    if c.at:
        status = "pass"
        if any(a <= plo and b > phi for a, b in surely_bad):
            status = "fail"
        elif any(a <= phi and b > plo for a, b in maybe_bad):
            status = "inconclusive"
    else:
        status = "pass"
        if any(a < shi and b > slo for a, b in surely_bad):
            status = "fail"
            if (f.lag or f.early) and not any(a < shi - f.early and b > slo + f.lag
                                              for a, b in surely_bad):
                status, late = "inconclusive", f" ({_load_reason(f.lag, f.early)})"
        elif any(a < phi and b > plo for a, b in maybe_bad):
            status = "inconclusive"
    state = "true" if not want else "false"
    if status == "pass":
        verb = "was" if c.at else "stayed"
        msg = f"{c.target} {verb} {'true' if want else 'false'} {where}"
    else:
        spans = surely_bad if status == "fail" else maybe_bad
        lo_w = plo if (c.at or status != "fail") else slo
        first = next((max(a, lo_w) for a, b in spans if b > lo_w), None)
        offs = ""
        if first is not None and c.frm and not c.at:
            offs = f" ({_ms(first - f.t):.1f} ms after {ctx.label(c.frm)})"
        msg = f"{c.target} was {state} {where}{offs}" + (
            "" if status == "fail" else late or
            " — possibly, within the observation resolution")
    return Verdict(**common, status=status, message=msg)


Spans = list[tuple[int, int]]


def _bad_spans(tr: Trace, want: bool, end: int) -> tuple[Spans, Spans]:
    """Intervals where the signal is surely / possibly not `want` (unknown prefix = possibly)."""
    surely, maybe = [], []
    if not tr.times:
        return [], [(NEG_INF, POS_INF)]
    maybe.append((NEG_INF, tr.times[0]))
    for i, t in enumerate(tr.times):
        nxt = tr.times[i + 1] if i + 1 < len(tr.times) else POS_INF
        if bool(tr.values[i]) != want:
            surely.append((t, nxt - tr.res if nxt < POS_INF else POS_INF))
            maybe.append((t - tr.res, nxt))
    return surely, maybe


def check_all(specs: list[Spec], source: SignalSource, **kw: Any) -> list[Verdict]:
    out: list[Verdict] = []
    for s in specs:
        out.extend(check(s, source, **kw))
    return out


def summary(verdicts: list[Verdict]) -> dict[str, int]:
    out = {s: 0 for s in ("pass", "fail", "inconclusive", "skipped")}
    for v in verdicts:
        out[v.status] += 1
    return out


def missing_data(spec: Spec, source: SignalSource, binding: Mapping[str, str] | None = None
                 ) -> list[str]:
    """Why each of `spec`'s recorded signals has no samples in `source` ("STO1: no data on
    /dio/drive1/STO1"); [] when every signal has data. Explains a spec that judged nothing."""
    ctx = context(spec, source, None, binding)
    out = []
    for s in spec.signals.values():
        if s.kind not in ("topic", "function", "line", "alarm"):
            continue
        try:
            topic, fld, _inv = ctx._where_from(s)
        except KeyError as e:
            out.append(f"{s.name}: {e.args[0] if e.args else e}")
            continue
        if not samples(source, topic, fld, s.where):
            out.append(f"{s.name}: no data on {topic}" + (f" field {fld}" if fld else ""))
    return out


def occurrences_since(verdicts: list[Verdict], t_ns: int | None) -> list[Verdict]:
    """Only the occurrences that began at or after `t_ns` (e.g. since a plan's previous check
    of the same spec); an occurrence begins at the earliest time among its verdicts."""
    if t_ns is None:
        return verdicts
    first: dict[int, int] = {}
    for v in verdicts:
        t = v.t_ns if v.t_ns is not None else v.from_ns
        if t is not None:
            first[v.occurrence] = min(t, first.get(v.occurrence, t))
    return [v for v in verdicts if first.get(v.occurrence, t_ns) >= t_ns]


def constants_for(spec: Any, overrides: Mapping[str, float]) -> dict[str, float]:
    """The overrides (e.g. a bench's `timing.constants`) that `spec` defines; others ignored."""
    own = getattr(spec, "constants", {}) or {}
    return {k: v for k, v in overrides.items() if k in own}
