"""Timing specs: one YAML file per manual timing diagram (format in docs/timing.md).

`load_spec(path)` returns a validated `Spec`; anything wrong raises `SpecError` whose message
is `file:line: field: what is wrong` (field like `constraints[1].window.max`).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from dataclasses import field as _f
from pathlib import Path
from typing import Any

from hil.paths import fixture
from hil.profile.params import ParamTable
from hil.record.messages import CLOSED
from hil.record.schemas import SCHEMAS, schema_for_topic
from hil.timing.expr import MAX_BIT, MAX_MAGNITUDE, Expr, ExprError, is_param
from hil.yamlio import FileError, LDict, LList, join, load_yaml_file, load_yaml_text

# Factory DI/DO assignment (L1860-1907, L9251-9336): function -> "LINE[:b]".
# BRKR has no factory DO: the virtual bench maps it to DO6 with P2.041 = 0x0108 (a-contact).
FACTORY_BINDING: dict[str, str] = {
    "SON": "DI1",  # P2.010 = 0x0101 (L1860)
    "CCLR": "DI2",
    "ARST": "DI5",  # P2.014 = 0x0102 (L1860)
    "NL": "DI6:b",  # P2.015 = 0x0022
    "PL": "DI7:b",  # P2.016 = 0x0023
    "EMGS": "DI8:b",  # P2.017 = 0x0021 (L6981, L1877, L2882; L9315 typo)
    "SRDY": "DO1",  # P2.018 = 0x0101 (L1900)
    "ZSPD": "DO2",  # P2.019 = 0x0103
    "HOME": "DO3",  # P2.020 = 0x0109
    "TPOS": "DO4",  # P2.021 = 0x0105
    "ALRM": "DO5:b",  # P2.022 = 0x0007, b-contact
    "BRKR": "DO6",  # P2.041 = 0x0108 on the virtual bench (docs/manual-choices.md#timing)
}
DEFAULT_PLACES: dict[str, str] = {"drive": "drive1", "dio": "drive1", "bus": "can0"}
# A3 lines, and a PLC's inputs / outputs on a pulse line (X<n>, Y<n>: docs/pulse.md)
LINE_RE = re.compile(r"(DI(?:10|[1-9])|DO[1-6]|STO_A|STO_B|FDBK|[XY][0-9]{1,3})(?::([ab]))?")
PLACE_RE = re.compile(r"\{(\w+)\}")
STATUSES = ("pass", "fail", "inconclusive", "skipped")


class SpecError(FileError):
    """A malformed spec: `file:line: field: what is wrong` (`.where` / `.what` name them)."""

    @property
    def where(self) -> str:
        return self.field

    @property
    def what(self) -> str:
        return self.problem


def load_yaml(text: str, file: str = "<string>") -> Any:
    """Parse YAML keeping line numbers (LDict/LList); syntax errors become SpecError."""
    return load_yaml_text(text, file, SpecError)


# --- the spec model --------------------------------------------------------------------


@dataclass
class SignalDef:
    """Where a signal comes from and how its samples are turned into values."""

    name: str
    kind: str  # topic | function | line | alarm | derived | all | any | not
    line: int
    topic: str | None = None
    field: str | None = None
    where: dict[str, Any] = _f(default_factory=dict)
    function: str | None = None
    io_line: str | None = None
    alarm: list[str] | None = None  # codes; ["any"] = any alarm
    source: str | None = None  # derived: the parent signal
    parts: list[str] = _f(default_factory=list)  # all/any/not
    transforms: dict[str, Any] = _f(default_factory=dict)  # map bit mask abs equals in below..
    resolution: Expr | None = None


@dataclass
class EventDef:
    name: str
    kind: str  # rise fall change becomes raised cleared first_true message at earliest_of latest_of
    line: int
    signal: str | None = None
    value: Any = None
    refs: list[str] = _f(default_factory=list)  # earliest_of/latest_of/at
    plus: Expr | None = None
    after: str | None = None
    before: str | None = None
    within: Expr | None = None
    held: Expr | None = None  # an edge counts only if its new value lasts this long (ms)
    label: str = ""  # "BRKR rose", used in messages


@dataclass
class WindowDef:
    min: Expr | None
    max: Expr | None

    def text(self) -> str:
        lo = str(self.min) if self.min is not None else "-inf"
        hi = str(self.max) if self.max is not None else "+inf"
        return f"[{lo}, {hi}] ms"


@dataclass
class ConstraintDef:
    name: str
    kind: str  # window | forbid | absent | present
    line: int
    frm: str | None = None
    to: str | None = None
    until: str | None = None
    at: str | None = None
    target: str | None = None  # forbid: event; absent/present: signal
    window: WindowDef | None = None
    when: Expr | None = None
    for_each: str | None = None
    source: str = ""
    note: str = ""


@dataclass
class Spec:
    id: str
    title: str
    source: str
    path: str
    signals: dict[str, SignalDef]
    events: dict[str, EventDef]
    constraints: list[ConstraintDef]
    for_each: str | None = None
    bind: dict[str, str] = _f(default_factory=dict)
    constants: dict[str, Expr] = _f(default_factory=dict)
    resolution: dict[str, Expr] = _f(default_factory=dict)  # topic glob -> ms; "default"
    horizon: Expr | None = None
    notes: str = ""
    # parameters the scenario needs at some time in the recording (e.g. "bit(P5.059, 0) == 1":
    # COMPARE ran); `hil check` with every shipped spec skips a recording where it never held
    requires: Expr | None = None

    def binding(self, overrides: dict[str, str] | None = None) -> dict[str, str]:
        """Placeholders and function->line map: defaults < spec `bind` < overrides."""
        out = dict(DEFAULT_PLACES) | dict(FACTORY_BINDING) | self.bind
        return out | dict(overrides or {})


def spec_params(spec: Spec, constants: dict[str, Any] | None = None) -> set[str]:
    """The drive parameters `spec`'s expressions read (windows, `when`, thresholds, `held`,
    `plus`/`within`, resolutions, constants); a constant given in `constants` replaces its
    expression."""
    out: set[str] = set()
    seen: set[int] = set()

    def walk(x: Any) -> None:
        if isinstance(x, Expr):
            out.update(x.params)
        elif isinstance(x, dict):
            for v in x.values():
                walk(v)
        elif isinstance(x, list | tuple):
            for v in x:
                walk(v)
        elif hasattr(x, "__dataclass_fields__") and id(x) not in seen:
            seen.add(id(x))
            for name in x.__dataclass_fields__:
                walk(getattr(x, name))

    given = constants or {}
    walk({k: e for k, e in spec.constants.items() if k not in given})
    walk([spec.signals, spec.events, spec.constraints, spec.resolution, spec.horizon])
    return out


# --- validation ------------------------------------------------------------------------

_TRANSFORMS = {"map", "bit", "mask", "abs", "equals", "in", "below", "above", "nonempty", "held"}
_SIGNAL_KEYS = {
    "topic": {"topic", "field", "where", "resolution", *_TRANSFORMS},
    "function": {"function", "resolution"},
    "line": {"line", "resolution"},
    "alarm": {"alarm", "topic", "field", "resolution"},
    "signal": {"signal", *_TRANSFORMS},
    "all": {"all"},
    "any": {"any"},
    "not": {"not"},
}
_EVENT_KINDS = ("rise", "fall", "change", "becomes", "raised", "cleared", "first_true",
                "message", "at", "earliest_of", "latest_of")
_EVENT_MODS = {"after", "before", "within", "label"}
_CONSTRAINT_KEYS = {"name", "from", "to", "until", "at", "window", "when", "for_each",
                    "source", "note", "forbid", "absent", "present"}
_TOP = {"id", "title", "source", "signals", "events", "constraints", "for_each", "bind",
        "constants", "resolution", "horizon", "notes", "requires"}
_NAME_RE = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


_WANT = {"number": "a number of ms or an expression giving one (P1.042 + tol)",
         "bool": "a condition (true or false), e.g. \"P1.043 >= 0\"", "any": "an expression"}
_NAMES_HINT = "use a parameter (P1.042) or a name from `constants:`"


class _V:
    """Validation helper carrying the file name, the spec's constant names (`consts`) and the
    values of those that need no parameter (`static`, to check windows and limits now)."""

    def __init__(self, file: str) -> None:
        self.file = file
        self.consts: set[str] = set()
        self.static: dict[str, Any] = {}

    def err(self, line: int, where: str, what: str) -> SpecError:
        return SpecError(self.file, line, where or "(top)", what)

    def mapping(self, obj: Any, line: int, where: str) -> LDict:
        if not isinstance(obj, LDict):
            raise self.err(line, where, f"must be a mapping, got {_kind(obj)}")
        return obj

    def keys(self, d: LDict, allowed: set[str], where: str, required: tuple[str, ...] = ()):
        for k in d:
            if k not in allowed:
                hint = ", ".join(sorted(allowed))
                raise self.err(d.key_lines[k], join(where, k), f"unknown key (allowed: {hint})")
        for k in required:
            if k not in d:
                raise self.err(d.line, where, f"missing field {k!r}")

    def text(self, d: LDict, key: str, where: str) -> str:
        v = d[key]
        if not isinstance(v, str) or not v.strip():
            raise self.err(d.key_lines[key], join(where, key), "must be a non-empty string")
        return v.strip()

    def expr(self, d: LDict, key: str, where: str, want: str = "number",
             names: set[str] | None = None, hint: str = _NAMES_HINT,
             nonneg: bool = False) -> Expr:
        """The expression at `d[key]`: it must parse within the limits (hil/timing/expr.py),
        yield `want` ("number", "bool" or "any") as far as can be told, and read only
        parameters and `names` (default: the spec's constants). A number needing no parameter
        is evaluated now: refused when it cannot be (1 / 0) or, with `nonneg`, is negative."""
        v = d[key]
        line = d.key_lines[key]
        fld = join(where, key)
        if isinstance(v, bool) or not isinstance(v, str | int | float):
            raise self.err(line, fld, f"must be {_WANT[want]}, got {_kind(v)}")
        try:
            e = Expr(v)
        except ExprError as ex:
            raise self.err(line, fld, f"bad expression: {ex}") from None
        if want == "number" and e.kind in ("bool", "text"):
            got = "text" if e.kind == "text" else "a condition"
            raise self.err(line, fld, f"must be {_WANT[want]}, got {got} {e.text!r}")
        if want == "bool" and e.kind in ("number", "text"):
            got = "text" if e.kind == "text" else "a number"
            raise self.err(line, fld, f"must be {_WANT[want]}, got {got} {e.text!r}")
        known = self.consts if names is None else names
        bad = sorted(n for n in e.names if not is_param(n) and n not in known)
        if bad:
            raise self.err(line, fld, f"unknown name {bad[0]!r}: {hint}")
        if e.params:  # a parameter no drive has is no value any recording or --param gives
            table = ParamTable.load()
            unknown = [n for n in e.params if n not in table]
            if unknown:
                raise self.err(line, fld, f"unknown parameter {unknown[0]!r}: not in the "
                               "drive's parameter table (P<group>.<nnn>, e.g. P1.042)")
        if want == "number" and names is None:
            val = self.value(e, line, fld)
            if nonneg and val is not None and val < 0:
                raise self.err(line, fld, f"must not be negative, got {val:g} ms")
        return e

    def value(self, e: Expr | None, line: int, fld: str) -> float | None:
        """The value of `e` from the constants alone, None when it reads a parameter."""
        if e is None:
            return None
        try:
            return e.number(self.static)
        except KeyError:
            return None
        except ExprError as ex:
            raise self.err(line, fld, f"bad expression: {ex}") from None

    def name(self, v: Any, line: int, where: str) -> str:
        if not isinstance(v, str) or not _NAME_RE.fullmatch(v):
            raise self.err(line, where, f"{v!r} is not a name (letters, digits, _)")
        return v


def _kind(v: Any) -> str:
    return {dict: "a mapping", list: "a list", LDict: "a mapping", LList: "a list"}.get(
        type(v), f"{type(v).__name__} {v!r}"
    )


def parse_spec(data: Any, file: str = "<string>") -> Spec:
    """Validate parsed YAML (from `load_yaml`) into a Spec."""
    v = _V(file)
    top = v.mapping(data, getattr(data, "line", 1), "(top)")
    v.keys(top, _TOP, "", ("id", "title", "source", "signals", "events", "constraints"))
    sid = v.name(top["id"], top.key_lines["id"], "id")
    title, source = v.text(top, "title", ""), v.text(top, "source", "")
    bind: dict[str, str] = {}
    if "bind" in top:
        b = v.mapping(top["bind"], top.key_lines["bind"], "bind")
        for k, val in b.items():
            if not isinstance(val, str):
                raise v.err(b.key_lines[k], f"bind.{k}", "must be a string like DI1, DO5:b, drive1")
            if k.isupper() and not LINE_RE.fullmatch(val):
                raise v.err(b.key_lines[k], f"bind.{k}", f"{val!r} is not a line (DI1, DO6, DI8:b)")
            bind[k] = val
    constants = _constants(v, top)
    resolution: dict[str, Expr] = {}
    if "resolution" in top:
        r = top["resolution"]
        if isinstance(r, LDict):
            for k in r:
                resolution[k] = v.expr(r, k, "resolution", nonneg=True)
        else:
            resolution["default"] = v.expr(top, "resolution", "", nonneg=True)
    horizon = v.expr(top, "horizon", "", nonneg=True) if "horizon" in top else None
    requires = v.expr(top, "requires", "", want="bool", names=set(),
                      hint="only parameters (P5.059), e.g. \"bit(P5.059, 0) == 1\"") \
        if "requires" in top else None

    binding = dict(DEFAULT_PLACES) | FACTORY_BINDING | bind
    signals = _signals(v, top, binding)
    events = _events(v, top, signals)
    for_each = None
    if "for_each" in top:
        for_each = _ref(v, top, "for_each", "", events, signals)
    constraints = _constraints(v, top, events, signals, set(constants), for_each)
    return Spec(
        id=sid, title=title, source=source, path=file, signals=signals, events=events,
        constraints=constraints, for_each=for_each, bind=bind, constants=constants,
        resolution=resolution, horizon=horizon, notes=str(top.get("notes", "") or ""),
        requires=requires,
    )


def _constants(v: _V, top: LDict) -> dict[str, Expr]:
    """`constants:` in dependency order (a constant may use those defined below it; none may
    depend on itself); sets `v.consts` and `v.static` (the values that need no parameter)."""
    if "constants" not in top:
        return {}
    c = v.mapping(top["constants"], top.key_lines["constants"], "constants")
    raw: dict[str, Expr] = {}
    for k in c:
        v.name(k, c.key_lines[k], f"constants.{k}")
    for k in c:
        raw[k] = v.expr(c, k, "constants", names=set(c))
    ordered: dict[str, Expr] = {}
    state: dict[str, int] = {}
    height: dict[str, int] = {}  # the longest chain below each name

    def visit(k: str, path: list[str]) -> None:
        if state.get(k) == 2:
            return
        if state.get(k) == 1:
            cycle = " -> ".join([*path[path.index(k):], k])
            raise v.err(c.key_lines[k], f"constants.{k}",
                        f"constant depends on itself ({cycle})")
        _depth(v, c.key_lines[k], f"constants.{k}", len(path), "constants")
        state[k] = 1
        below = [n for n in sorted(raw[k].names) if n in raw]
        for n in below:
            visit(n, [*path, k])
        height[k] = 1 + max((height[n] for n in below), default=0)
        _depth(v, c.key_lines[k], f"constants.{k}", height[k], "constants")
        state[k] = 2
        ordered[k] = raw[k]

    for k in raw:
        visit(k, [])
    v.consts = set(ordered)
    for k, e in ordered.items():
        val = v.value(e, c.key_lines[k], f"constants.{k}")
        if val is not None:
            v.static[k] = val
    return ordered


def _signals(v: _V, top: LDict, binding: dict[str, str]) -> dict[str, SignalDef]:
    sigs = v.mapping(top["signals"], top.key_lines["signals"], "signals")
    out: dict[str, SignalDef] = {}
    for name, d in sigs.items():
        where = f"signals.{name}"
        line = sigs.key_lines[name]
        v.name(name, line, where)
        d = v.mapping(d, line, where)
        kinds = [k for k in _SIGNAL_KEYS if k in d]
        if len(kinds) != 1:
            raise v.err(line, where, "needs exactly one of: " + ", ".join(_SIGNAL_KEYS))
        kind = kinds[0]
        v.keys(d, _SIGNAL_KEYS[kind], where)
        s = SignalDef(name=name, kind=kind, line=line)
        if "resolution" in d:
            s.resolution = v.expr(d, "resolution", where, nonneg=True)
        if kind == "topic":
            s.topic = v.text(d, "topic", where)
            if "field" not in d:
                raise v.err(line, where, "missing field 'field' (the message field to read)")
            s.field = v.text(d, "field", where)
            if "where" in d:
                s.where = dict(v.mapping(d["where"], d.key_lines["where"], f"{where}.where"))
            _known_fields(v, d, where, s)
        elif kind == "function":
            fn = v.text(d, "function", where)
            if fn not in binding:
                raise v.err(d.key_lines["function"], f"{where}.function",
                            f"unknown function {fn!r}: add it to `bind:` (e.g. {fn}: DI3)")
            s.function = fn
        elif kind == "line":
            ln = v.text(d, "line", where)
            if not LINE_RE.fullmatch(ln):
                raise v.err(d.key_lines["line"], f"{where}.line",
                            f"{ln!r} is not a line (DI1..DI10, DO1..DO6, STO_A, STO_B, FDBK, "
                            "X<n>, Y<n>)")
            s.io_line = ln
        elif kind == "alarm":
            a = d["alarm"]
            codes = list(a) if isinstance(a, list) else [a]
            for c in codes:
                if not (isinstance(c, str) and (re.fullmatch(r"AL[0-9A-F]{3}", c) or c == "any"
                                                 or PLACE_RE.fullmatch(c))):
                    raise v.err(d.key_lines["alarm"], f"{where}.alarm",
                                f"{c!r} is not an alarm code (AL500, any or {{alarm}})")
            s.alarm = codes
            s.topic = d.get("topic", "/drive/{drive}/state")
            s.field = d.get("field", "alarms")
        elif kind == "signal":
            s.source = v.name(d["signal"], d.key_lines["signal"], f"{where}.signal")
        elif kind in ("all", "any"):
            parts = d[kind]
            if not isinstance(parts, list) or len(parts) < 2:
                raise v.err(d.key_lines[kind], f"{where}.{kind}", "must list two or more signals")
            s.parts = [v.name(p, d.key_lines[kind], f"{where}.{kind}") for p in parts]
        else:
            s.parts = [v.name(d["not"], d.key_lines["not"], f"{where}.not")]
        for t in _TRANSFORMS & set(d):
            tw = f"{where}.{t}"
            val = d[t]
            if t in ("below", "above", "held"):
                s.transforms[t] = v.expr(d, t, where, nonneg=t == "held")
            elif t in ("bit", "mask") and (isinstance(val, bool) or not isinstance(val, int)):
                raise v.err(d.key_lines[t], tw, f"must be an integer, got {_kind(val)}")
            elif t == "bit" and not 0 <= val <= MAX_BIT:
                raise v.err(d.key_lines[t], tw, f"must be a bit index 0..{MAX_BIT}, got {val}")
            elif t == "mask" and not 0 <= val <= MAX_MAGNITUDE:
                raise v.err(d.key_lines[t], tw, f"must be 0..2**64, got {val}")
            elif t == "map" and not isinstance(val, LDict):
                raise v.err(d.key_lines[t], tw, "must be a mapping value -> value")
            elif t in ("abs", "nonempty") and not isinstance(val, bool):
                raise v.err(d.key_lines[t], tw, "must be true or false")
            elif t == "in" and not isinstance(val, list):
                raise v.err(d.key_lines[t], tw, "must be a list of values")
            elif t == "map":  # keys keep their text (hil.yamlio): 0x1637 is the number 5687
                s.transforms[t] = {_map_key(k): x for k, x in val.items()}
            else:
                s.transforms[t] = dict(val) if isinstance(val, LDict) else val
        if "mask" in s.transforms and "equals" not in s.transforms:
            raise v.err(d.key_lines["mask"], f"{where}.mask", "needs `equals:` beside it")
        out[name] = s
    for s in out.values():  # references between signals
        for p in ([s.source] if s.source else []) + s.parts:
            if p not in out:
                raise v.err(s.line, f"signals.{s.name}", f"unknown signal {p!r}")
    _no_cycles(v, out)
    return out


def _known_fields(v: _V, d: LDict, where: str, s: SignalDef) -> None:
    """A field (or a `where:` key) a hil topic of a closed schema never carries is a typo: a
    signal that reads it would have no data and judge nothing (hil.record.messages)."""
    name = schema_for_topic(s.topic or "")
    if name not in CLOSED:
        return
    props = SCHEMAS[name].get("properties", {})
    for key, line in [(s.field, d.key_lines["field"])] + [
            (k, d["where"].key_lines.get(k, d.key_lines["where"])) for k in s.where]:
        top = str(key).split(".")[0]
        if top not in props:
            raise v.err(line, f"{where}.field" if key == s.field else f"{where}.where.{key}",
                        f"{top!r}: {s.topic} ({name}) has no such field; it has "
                        f"{', '.join(sorted(props))}")


MAX_CHAIN = 64  # names depending on names: no real spec comes near; Python's stack would


def _depth(v: _V, line: int, field: str, depth: int, what: str) -> None:
    if depth >= MAX_CHAIN:
        raise v.err(line, field, f"a chain of more than {MAX_CHAIN} {what}, each depending "
                    "on the next: too deep to judge")


def _no_cycles(v: _V, sigs: dict[str, SignalDef]) -> None:
    def deps(s: SignalDef) -> list[str]:
        return ([s.source] if s.source else []) + s.parts

    state: dict[str, int] = {}
    height: dict[str, int] = {}

    def visit(n: str, depth: int) -> None:
        if state.get(n) == 2:
            return
        if state.get(n) == 1:
            raise v.err(sigs[n].line, f"signals.{n}", "signal depends on itself")
        _depth(v, sigs[n].line, f"signals.{n}", depth, "signals")
        state[n] = 1
        for d in deps(sigs[n]):
            visit(d, depth + 1)
        height[n] = 1 + max((height[d] for d in deps(sigs[n])), default=0)
        _depth(v, sigs[n].line, f"signals.{n}", height[n], "signals")
        state[n] = 2

    for n in sigs:
        visit(n, 0)


def _ref(v: _V, d: LDict, key: str, where: str, events: dict, signals) -> str:
    """An event reference: a name, or an inline event mapping (registered anonymously)."""
    val = d[key]
    line = d.key_lines[key]
    w = join(where, key)
    if isinstance(val, LDict):
        name = f"{where or 'spec'}.{key}".replace("[", "_").replace("]", "")
        events[name] = _event(v, name, val, line, w, signals, events)
        return name
    if not isinstance(val, str) or val not in events:
        raise v.err(line, w, f"unknown event {val!r} (known: {', '.join(events) or 'none'})")
    return val


def _event(v: _V, name: str, d: LDict, line: int, where: str, signals, events) -> EventDef:
    d = v.mapping(d, line, where)
    kinds = [k for k in _EVENT_KINDS if k in d]
    if len(kinds) != 1:
        raise v.err(line, where, "needs exactly one of: " + ", ".join(_EVENT_KINDS))
    kind = kinds[0]
    allowed = {kind, *_EVENT_MODS} | ({"value"} if kind == "becomes" else set())
    allowed |= {"plus"} if kind == "at" else set()
    allowed |= {"held"} if kind in ("rise", "fall", "becomes", "raised", "cleared") else set()
    v.keys(d, allowed, where, ("value",) if kind == "becomes" else ())
    ev = EventDef(name=name, kind=kind, line=line)
    kl = d.key_lines[kind]
    if kind in ("rise", "fall", "change", "becomes", "first_true", "message"):
        sig = d[kind]
        if not isinstance(sig, str) or sig not in signals:
            raise v.err(kl, f"{where}.{kind}", f"unknown signal {sig!r} (a signal's name)")
        if kind == "message" and signals[sig].kind != "topic":
            raise v.err(kl, f"{where}.{kind}", f"signal {sig!r} is not read from a topic: "
                        "`message` needs a {topic: ..., field: ...} signal")
        ev.signal = sig
        ev.value = d.get("value")
    elif kind in ("raised", "cleared"):
        code = d[kind]
        if isinstance(code, str) and code in signals:
            ev.signal = code
        elif isinstance(code, str) and re.fullmatch(r"AL[0-9A-F]{3}", code):
            ev.signal = f"alarm:{code}"  # implicit alarm signal from the drive state
        else:
            raise v.err(kl, f"{where}.{kind}", f"{code!r} is neither a signal nor an alarm code")
    elif kind == "at":
        ev.refs = [_ref(v, d, "at", where, events, signals)]
        if "plus" not in d:
            raise v.err(line, where, "missing field 'plus' (delay after the `at` event)")
        ev.plus = v.expr(d, "plus", where)  # may be negative: a time before the event
    else:
        lst = d[kind]
        if not isinstance(lst, list) or len(lst) < 2:
            raise v.err(kl, f"{where}.{kind}", "must list two or more events")
        for i, r in enumerate(lst):
            if not isinstance(r, str) or r not in events:
                raise v.err(lst.item_lines[i], f"{where}.{kind}[{i}]", f"unknown event {r!r}")
        ev.refs = list(lst)
    for mod in ("after", "before"):
        if mod in d:
            setattr(ev, mod, _ref(v, d, mod, where, events, signals))
    if ev.after and ev.before:
        raise v.err(line, where, "use either `after` or `before`, not both")
    if "within" in d:
        ev.within = v.expr(d, "within", where, nonneg=True)
    if "held" in d:  # a debounced edge: a bounce shorter than a DI filter is none (L9229)
        ev.held = v.expr(d, "held", where, nonneg=True)
    ev.label = str(d.get("label", "") or "")
    return ev


def _events(v: _V, top: LDict, signals) -> dict[str, EventDef]:
    evs = v.mapping(top["events"], top.key_lines["events"], "events")
    out: dict[str, EventDef] = {}
    # Two passes so that events may refer to events defined further down.
    for name in evs:
        v.name(name, evs.key_lines[name], f"events.{name}")
        out[name] = EventDef(name=name, kind="?", line=evs.key_lines[name])
    for name, d in evs.items():
        out[name] = _event(v, name, d, evs.key_lines[name], f"events.{name}", signals, out)
    _event_cycles(v, out)
    return out


def _event_cycles(v: _V, events: dict[str, EventDef]) -> None:
    state: dict[str, int] = {}
    height: dict[str, int] = {}

    def visit(n: str, depth: int) -> None:
        if state.get(n) == 2:
            return
        if state.get(n) == 1:
            raise v.err(events[n].line, f"events.{n}", "event depends on itself")
        _depth(v, events[n].line, f"events.{n}", depth, "events")
        state[n] = 1
        e = events[n]
        below = [r for r in [*e.refs, e.after, e.before] if r]
        for r in below:
            visit(r, depth + 1)
        height[n] = 1 + max((height[r] for r in below), default=0)
        _depth(v, events[n].line, f"events.{n}", height[n], "events")
        state[n] = 2

    for n in list(events):
        visit(n, 0)


def _constraints(v, top, events, signals, consts, spec_for_each) -> list[ConstraintDef]:
    lst = top["constraints"]
    if not isinstance(lst, LList) or not lst:
        raise v.err(top.key_lines["constraints"], "constraints", "must be a non-empty list")
    out = []
    seen: set[str] = set()
    for i, d in enumerate(lst):
        where = f"constraints[{i}]"
        line = lst.item_lines[i]
        d = v.mapping(d, line, where)
        v.keys(d, _CONSTRAINT_KEYS, where)
        kinds = [k for k in ("forbid", "absent", "present") if k in d]
        if len(kinds) > 1:
            raise v.err(line, where, "use only one of forbid, absent, present")
        kind = kinds[0] if kinds else "window"
        name = v.text(d, "name", where) if "name" in d else f"#{i + 1}"
        if name in seen:
            raise v.err(d.key_lines.get("name", line), f"{where}.name", f"duplicate name {name!r}")
        seen.add(name)
        c = ConstraintDef(name=name, kind=kind, line=line)
        c.source, c.note = str(d.get("source", "") or ""), str(d.get("note", "") or "")
        for key in ("from", "to", "until", "at", "for_each"):
            if key in d:
                setattr(c, "frm" if key == "from" else key, _ref(v, d, key, where, events, signals))
        c.for_each = c.for_each or spec_for_each
        if "window" in d:
            w = v.mapping(d["window"], d.key_lines["window"], f"{where}.window")
            v.keys(w, {"min", "max"}, f"{where}.window")
            if not w:
                raise v.err(w.line, f"{where}.window", "needs `min`, `max` or both")
            c.window = WindowDef(
                v.expr(w, "min", f"{where}.window") if "min" in w else None,
                v.expr(w, "max", f"{where}.window") if "max" in w else None,
            )
            lo = v.value(c.window.min, w.kline("min"), f"{where}.window.min")
            hi = v.value(c.window.max, w.kline("max"), f"{where}.window.max")
            if lo is not None and hi is not None and lo > hi:
                raise v.err(d.key_lines["window"], f"{where}.window",
                            f"min ({c.window.min} = {lo:g} ms) exceeds max ({c.window.max} = "
                            f"{hi:g} ms): nothing can pass")
        if "when" in d:
            c.when = v.expr(d, "when", where, want="bool", names=consts | set(signals),
                            hint="use a parameter, a name from `constants:` or a signal")
        if kind == "window":
            for req in ("from", "to", "window"):
                if req not in d:
                    raise v.err(line, where, f"missing field {req!r}")
        elif kind == "forbid":
            c.target = _ref(v, d, "forbid", where, events, signals)
            if "from" not in d or ("window" not in d and "until" not in d):
                raise v.err(line, where, "forbid needs `from:` and a `window:` or `until:`")
        else:
            c.target = d[kind]
            if not isinstance(c.target, str) or c.target not in signals:
                raise v.err(d.key_lines[kind], f"{where}.{kind}", f"unknown signal {c.target!r}")
            if "at" not in d and not ("from" in d and ("window" in d or "until" in d)):
                raise v.err(line, where, f"{kind} needs `at:` or `from:` with `window:`/`until:`")
        if kind == "window" and "until" in d:
            raise v.err(d.key_lines["until"], f"{where}.until", "only for forbid/absent/present")
        out.append(c)
    return out


def load_spec(path: str | Path) -> Spec:
    """Load and validate one spec file."""
    p = Path(path)  # a regular file, at most HIL_YAML_MAX_BYTES read (not /dev/zero)
    return parse_spec(load_yaml_file(p, SpecError), str(p))


def loads_spec(text: str, file: str = "<string>") -> Spec:
    return parse_spec(load_yaml(text, file), file)


def shipped_specs() -> list[Path]:
    """The spec files shipped in fixtures/timing/."""

    return sorted(fixture("timing").glob("*.yaml"))


def _map_key(key: str) -> Any:
    """A `map:` key as the value it matches: a number written as a number (`0x1637`, `12`,
    `1.5`) is that number, anything else its text."""
    for conv in (lambda k: int(k, 0), float):
        try:
            return conv(key.replace("_", ""))
        except ValueError:
            pass
    return key
