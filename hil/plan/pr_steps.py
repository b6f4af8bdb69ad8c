"""Plan steps of PR mode: `pr_table`, `pr_trigger`, `pr_wait` (docs/pr.md).

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

from typing import Any

from hil import clock
from hil.bench.yamlio import PARAM_ROUTES, Checker, LDict, join
from hil.drivers.delta_pr import STATES, DeltaPr, PrTableError, table_words
from hil.plan.context import StepFailed

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


def p_pr_table(v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
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
        raise v.err(m.line, where, "name at least one path, e.g. 1: {type: single, data: 1000}")
    return {"table": table, "via": via}


def _field_types(v: Checker, pm: LDict, where: str) -> None:
    for key, x in pm.items():
        want = _FIELD_TYPES[key]
        if (isinstance(x, bool) and bool not in want) or not isinstance(x, want):
            names = " or ".join({bool: "true/false", int: "an integer", str: "a name"}[t]
                                for t in want)
            raise v.err(pm.kline(key), join(where, key), f"{x!r}: {names}")


def p_pr_trigger(v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
    if isinstance(obj, int) and not isinstance(obj, bool):
        m = LDict({"pr": obj})
        m.line, m.key_lines = line, {"pr": line}
    else:
        m = v.mapping(obj, line, where)
    v.keys(m, {"pr", "by", "via", "width"}, where, required=("pr",))
    return {"pr": v.integer(m, "pr", where, 0, 99), "by": v.choice(m, "by", where, BY, "p5007"),
            "via": v.choice(m, "via", where, PARAM_ROUTES),
            "width": v.duration(m, "width", where, 20_000_000)}


def p_pr_wait(v: Checker, obj: Any, line: int, where: str) -> dict[str, Any]:
    m = v.mapping(obj, line, where)
    v.keys(m, {"pr", "state", "timeout", "via"}, where, required=("pr",))
    out = {"pr": v.integer(m, "pr", where, 0, 99), "state": m.get("state", "in_position"),
           "timeout": v.duration(m, "timeout", where, 5_000_000_000),
           "via": v.choice(m, "via", where, PARAM_ROUTES)}
    if not isinstance(out["state"], str) or out["state"] not in STATES:
        raise v.err(m.kline("state"), join(where, "state"), f"{out['state']!r}: one of "
                    f"{', '.join(STATES)}")
    return out


class _Access:
    """DeltaPr's parameter access through a plan's DriveIO (bench route or `via`)."""

    def __init__(self, d: Any, via: str | None) -> None:
        self.d, self.via = d, via

    def read_param(self, name: str) -> int:
        return self.d.read_param(name, self.via)

    def write_param(self, name: str, value: int) -> None:
        self.d.write_param(name, value, self.via)


def x_pr_table(ctx: Any, s: Any, d: Any) -> str:
    pr = DeltaPr(_Access(d, s.args["via"]))
    try:
        words = pr.write_table(s.args["table"])
    except PrTableError as exc:
        raise StepFailed(str(exc)) from None
    ctx.written(d.name, words)
    return f"{len(s.args['table'])} path(s) written and read back"


def x_pr_trigger(ctx: Any, s: Any, d: Any) -> str:
    n = s.args["pr"]
    if s.args["by"] == "p5007":
        DeltaPr(_Access(d, s.args["via"])).trigger(n)
        return f"P5.007 = {n}"
    for i, f in enumerate(POS):  # POS0-6 = n, then a CTRG pulse (L4834-4840, L15098)
        if f in d.spec.di:
            d.set_function(f, bool(n >> i & 1))
        elif n >> i & 1:
            raise StepFailed(f"PR#{n} needs {f}, which the bench does not wire")
    ctx.sleep(s.args["width"])
    d.set_function("CTRG", True)
    ctx.sleep(s.args["width"])
    d.set_function("CTRG", False)
    return f"POS = {n}, CTRG pulse"


def x_pr_wait(ctx: Any, s: Any, d: Any) -> str:
    pr = DeltaPr(_Access(d, s.args["via"]), sleep=lambda t: ctx.sleep(int(t * 1e9)))
    t0 = clock.monotonic()
    try:
        waited = pr.wait(s.args["pr"], s.args["state"], s.args["timeout"] / 1e9)
    except TimeoutError as exc:
        raise StepFailed(str(exc)) from None
    return f"PR#{s.args['pr']} {s.args['state']} after {waited * 1e3:.0f} ms " \
           f"({(clock.monotonic() - t0) * 1e3:.0f} ms)"


def describe(kind: str, a: dict[str, Any]) -> str:
    if kind == "pr_table":
        return "pr_table " + ", ".join(f"#{n} {f['type']}" for n, f in a["table"].items())
    if kind == "pr_trigger":
        return f"pr_trigger PR#{a['pr']} by {a['by']}"
    return f"pr_wait PR#{a['pr']} {a['state']}"


PARSERS = {"pr_table": p_pr_table, "pr_trigger": p_pr_trigger, "pr_wait": p_pr_wait}
EXECUTORS = {"pr_table": x_pr_table, "pr_trigger": x_pr_trigger, "pr_wait": x_pr_wait}
