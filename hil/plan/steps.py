"""Plan steps: one YAML mapping per step, one *kind* key plus optional common keys.

Every kind is parsed by a function in `PARSERS`, which returns the step's `args` and raises
`PlanFileError` with file, line and field. Formats: docs/plans.md.
"""

from __future__ import annotations

import re
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

from hil.model.dio import inert_mapping
from hil.model.homing_methods import CANOPEN_METHODS
from hil.plan.fault_steps import describe as describe_comm
from hil.plan.fault_steps import p_fault, p_nmt, p_produce, p_sdo
from hil.plan.param_rules import check_param
from hil.plan.pr_steps import PARSERS as PR_PARSERS
from hil.plan.pr_steps import describe as pr_describe
from hil.plan.yamlio import Checker, LDict, LList, join, level, parse_duration
from hil.profile.dio import DI_SYMBOLS, DO_SYMBOLS
from hil.protocol.cia402 import MODES as CIA402_MODES

STATES = ("SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED",
          "QUICK STOP ACTIVE", "FAULT")
# states a `state:` step can command (FAULT is reached, never commanded)
COMMANDABLE = STATES[:-1]
MODES = tuple(m for m in CIA402_MODES if m != "IP")  # a `mode:` step offers no IP
VIAS = ("modbus", "sdo")
STO = ("A", "B")
COMMON = {"name", "drive", "note", "timeout", "imposed"}
_PARAM_RE = re.compile(r"^P[0-7]\.\d{3}$")
_ALARM_RE = re.compile(r"^AL[0-9A-F]{3}$")
_INT32 = (-(2**31), 2**31 - 1)


@dataclass
class Condition:
    """What `wait_until` and `expect` test: kind do|fdbk|state|param|alarm."""

    kind: str
    key: str  # DO function, parameter name, "" for fdbk/state/alarm
    value: Any  # bool level, state name, int, alarm code or None (= no alarm)
    via: str | None = None

    def describe(self) -> str:
        if self.kind == "do":
            return f"DO {self.key} {'on' if self.value else 'off'}"
        if self.kind == "fdbk":
            return f"FDBK {'closed' if self.value else 'open'}"
        if self.kind == "state":
            return f"state {self.value}"
        if self.kind == "param":
            return f"{self.key} = {self.value}"
        return "no alarm" if self.value is None else f"alarm {self.value}"


@dataclass
class Step:
    kind: str
    args: dict[str, Any]
    index: int
    line: int
    file: str
    name: str = ""
    drive: str | None = None
    timeout_ns: int | None = None
    note: str = ""
    imposed_by_manual_ns: int = 0  # `imposed:` the manual's own delay inside this step
    raw: dict[str, Any] = field(default_factory=dict)

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
        if self.kind == "wait":
            return self.args["duration"]
        if self.kind in ("pulse", "sto_dropout"):
            return max(self.args["widths"].values())
        return 0


def describe(step: Step) -> str:
    a = step.args
    k = step.kind
    if k in ("di", "sto"):
        return f"{k} " + ", ".join(f"{f}={'on' if v else 'off'}" for f, v in a["levels"].items())
    if k in ("pulse", "sto_dropout"):
        return f"{k} " + ", ".join(f"{f} {w / 1e6:g}ms" for f, w in a["widths"].items())
    if k == "write":
        vals = ", ".join(f"{p}={v}" for p, v in a["values"].items())
        refused = f" refused 0x{a['expect_error']:X}" if a.get("expect_error") else ""
        return f"write {vals} via {a['via'] or '-'}{refused}"
    if k == "read":
        return f"read {', '.join(a['values'])} via {a['via'] or '-'}"
    if k == "state":
        return f"state {a['state']}"
    if k == "mode":
        return f"mode {a['mode']}"
    if k == "move":
        return f"move {a['mode']} " + ", ".join(f"{x}={y}" for x, y in a.items() if x != "mode")
    if k == "home":
        return f"home method {a['method']}"
    if k == "wait":
        return f"wait {a['duration'] / 1e6:g}ms"
    if k in ("wait_until", "expect"):
        return f"{k} " + " and ".join(c.describe() for c in a["conditions"])
    if k == "check_timing":
        extra = ", ".join(f"{x}={y}" for x, y in (a.get("bind") or {}).items())
        return f"check_timing {a['spec']}" + (f" ({extra})" if extra else "")
    if k == "abs_read":
        want = ", ".join(f"{x}={y}" for x, y in a["expect"].items())
        same = f" same as {a['same_as']}" if a.get("same_as") else ""
        return f"absolute read (DI/DO){': ' + want if want else ''}{same}"
    if k == "abs_origin":
        return "absolute origin (ABSE + ABSC)"
    if k in ("fault", "produce", "sdo", "nmt"):
        return describe_comm(k, a)
    if k == "inject":
        return "inject " + ", ".join(f"{x}={y}" for x, y in a.items())
    if k == "fault_reset":
        return "fault reset (6040h bit 7)"
    if k.startswith("pr_"):
        return pr_describe(k, a)
    return k


# --- parsers ------------------------------------------------------------------------------

Parser = Callable[[Checker, Any, int, str], dict[str, Any]]


def _levels(v: Checker, obj: Any, line: int, where: str, names: dict | tuple,
            what: str) -> dict[str, bool]:
    m = v.mapping(obj, line, where)
    if not m:
        raise v.err(line, where, f"name at least one {what}")
    out = {}
    for k, val in m.items():
        if k not in names:
            raise v.err(m.kline(k), join(where, k), f"unknown {what} {k!r}; known: "
                        f"{', '.join(sorted(names))}")
        lv = level(val)
        if lv is None:
            raise v.err(m.kline(k), join(where, k), f"{val!r}: on or off")
        out[k] = lv
    return out


def _widths(v: Checker, obj: Any, line: int, where: str, names: dict | tuple,
            what: str) -> dict[str, int]:
    m = v.mapping(obj, line, where)
    if not m:
        raise v.err(line, where, f"name at least one {what}")
    out = {}
    for k in m:
        if k not in names:
            raise v.err(m.kline(k), join(where, k), f"unknown {what} {k!r}; known: "
                        f"{', '.join(sorted(names))}")
        out[k] = v.duration(m, k, where)
        if out[k] <= 0:
            raise v.err(m.kline(k), join(where, k), "must be > 0")
    return out


def p_di(v, obj, line, where):
    return {"levels": _levels(v, obj, line, where, DI_SYMBOLS, "DI function")}


def p_pulse(v, obj, line, where):
    return {"widths": _widths(v, obj, line, where, DI_SYMBOLS, "DI function")}


def p_sto(v, obj, line, where):
    return {"levels": _levels(v, obj, line, where, STO, "STO channel")}


def p_sto_dropout(v, obj, line, where):
    return {"widths": _widths(v, obj, line, where, STO, "STO channel")}


def _via(v: Checker, m: LDict, where: str) -> str | None:
    if "via" not in m:
        return None
    via = m["via"]
    if via not in VIAS:
        raise v.err(m.kline("via"), join(where, "via"), f"{via!r}: modbus or sdo")
    return via


def _param_values(v: Checker, m: LDict, where: str, allow_none: bool,
                  write: bool = False) -> dict[str, int | None]:
    out: dict[str, int | None] = {}
    for k, val in m.items():
        if k in ("via", "expect_error"):
            continue
        if not _PARAM_RE.match(k):
            raise v.err(m.kline(k), join(where, k), "a parameter name like P1.042 (or via)")
        if val is None and allow_none:
            check_param(v, m.kline(k), join(where, k), k, None, write=write)
            out[k] = None
            continue
        if isinstance(val, bool) or not isinstance(val, int):
            raise v.err(m.kline(k), join(where, k),
                        f"must be an integer (raw communication units), got {val!r}")
        if not _INT32[0] <= val <= 0xFFFFFFFF:
            raise v.err(m.kline(k), join(where, k), f"{val} does not fit 32 bits")
        if not (write and "expect_error" in m):  # a write that expects the refusal is fine
            check_param(v, m.kline(k), join(where, k), k, val, write=write)
        out[k] = val
    if not out:
        raise v.err(m.line, where, "name at least one parameter, e.g. P1.042: 150")
    return out


# Refusal codes a `write` may expect (`expect_error`): a Modbus exception code (1..255,
# e.g. 03h illegal data value, a3-comms §1) or a CiA 301 SDO abort code (e.g. 0x06090031
# value too high, L17024-17042).
MODBUS_EXCEPTION = (1, 0xFF)
SDO_ABORT = (0x05000000, 0xFFFFFFFF)


def check_expect_error(v: Checker, line: int, where: str, code: int, via: str | None) -> None:
    """The expected refusal code must be one the route can answer."""
    if via == "modbus" and not MODBUS_EXCEPTION[0] <= code <= MODBUS_EXCEPTION[1]:
        raise v.err(line, where, f"0x{code:X} is not a Modbus exception code (1..255, e.g. 3 = "
                    "illegal data value) for via: modbus")
    if via == "sdo" and not SDO_ABORT[0] <= code <= SDO_ABORT[1]:
        raise v.err(line, where, f"{code} is not an SDO abort code (0x05000000..0xFFFFFFFF, "
                    "e.g. 0x06090031 value too high) for via: sdo")


def p_write(v, obj, line, where):
    m = v.mapping(obj, line, where)
    via = _via(v, m, where)
    fields = {k: x for k, x in m.items() if k != "expect_error"}
    fm = LDict(fields)
    fm.line, fm.key_lines = m.line, m.key_lines
    if "expect_error" in m:
        fm["expect_error"] = m["expect_error"]  # seen by _param_values: no range rule
    out = {"values": _param_values(v, fm, where, False, write=True), "via": via,
           "expect_error": None}
    if "expect_error" in m:
        fw = join(where, "expect_error")
        code = m["expect_error"]
        if isinstance(code, bool) or not isinstance(code, int) or code <= 0:
            raise v.err(m.kline("expect_error"), fw, f"{code!r}: the refusal code, a Modbus "
                        "exception code (e.g. 3) or an SDO abort code (e.g. 0x06090031)")
        if len(out["values"]) != 1:
            raise v.err(m.kline("expect_error"), fw, "one parameter per refused write "
                        f"(got {', '.join(out['values'])})")
        check_expect_error(v, m.kline("expect_error"), fw, code, via)
        out["expect_error"] = code
    else:
        for k, val in out["values"].items():
            if why := inert_mapping(k, val):  # issue 13 item 6: the drive refuses it
                raise v.err(m.kline(k), join(where, k), f"0x{val:04X} maps {why}; a write "
                            "that expects the refusal needs expect_error (0x06090030 / 3)")
    return out


def p_read(v, obj, line, where):
    if isinstance(obj, str):
        if not _PARAM_RE.match(obj):
            raise v.err(line, where, f"{obj!r}: a parameter name like P1.042")
        check_param(v, line, where, obj, None, write=False)
        return {"values": {obj: None}, "via": None}
    m = v.mapping(obj, line, where)
    return {"values": _param_values(v, m, where, True), "via": _via(v, m, where)}


def p_state(v, obj, line, where):
    if not isinstance(obj, str) or obj.strip().upper() not in COMMANDABLE:
        raise v.err(line, where, f"{obj!r}: one of {', '.join(COMMANDABLE)}")
    return {"state": obj.strip().upper()}


def p_mode(v, obj, line, where):
    if not isinstance(obj, str) or obj.strip().upper() not in MODES:
        raise v.err(line, where, f"{obj!r}: one of {', '.join(MODES)}")
    return {"mode": obj.strip().upper()}


_MOVE_KEYS = {
    "PP": {"mode", "target", "velocity", "accel", "decel", "relative", "wait"},
    "PV": {"mode", "velocity"},
    "PT": {"mode", "torque"},
}


def p_move(v, obj, line, where):
    m = v.mapping(obj, line, where)
    mode = str(m.get("mode", "PP")).upper()
    if mode not in _MOVE_KEYS:
        raise v.err(m.kline("mode"), join(where, "mode"), f"{m.get('mode')!r}: PP, PV or PT")
    v.keys(m, _MOVE_KEYS[mode], where)
    out: dict[str, Any] = {"mode": mode}
    if mode == "PP":
        out["target"] = v.integer(m, "target", where, *_INT32)
        out["velocity"] = v.integer(m, "velocity", where, 1, _INT32[1])
        out["accel"] = v.integer(m, "accel", where, 1, _INT32[1], 200)
        out["decel"] = v.integer(m, "decel", where, 1, _INT32[1], 200)
        out["relative"] = v.boolean(m, "relative", where, False)
        out["wait"] = v.boolean(m, "wait", where, True)
    elif mode == "PV":
        out["velocity"] = v.integer(m, "velocity", where, *_INT32)
    else:
        out["torque"] = v.integer(m, "torque", where, -3000, 3000)  # 0.1 % (6071h)
    return out


def p_home(v, obj, line, where):
    m = v.mapping(obj, line, where)
    v.keys(m, {"method", "speeds", "accel", "offset"}, where, required=("method",))
    out = {"method": v.integer(m, "method", where, -128, 127),  # 6098h (L18838)
           "accel": v.integer(m, "accel", where, 1, _INT32[1], 100),
           "offset": v.integer(m, "offset", where, *_INT32, 0), "speeds": (100, 20)}
    if out["method"] not in CANOPEN_METHODS:  # 6098h range 0..35, 15/16/31/32 reserved
        raise v.err(m.kline("method"), join(where, "method"),
                    f"homing method {out['method']}: the A3 supports 1-14, 17-30 and 33-35 "
                    "(6098h, L18856-18869)")
    if "speeds" in m:
        s = m["speeds"]
        if (not isinstance(s, list) or len(s) != 2
                or not all(isinstance(x, int) and not isinstance(x, bool) and x > 0 for x in s)):
            raise v.err(m.kline("speeds"), join(where, "speeds"),
                        "[fast, slow]: two positive integers (6099h sub 1 and 2)")
        out["speeds"] = (s[0], s[1])
    return out


def p_wait(v, obj, line, where):
    try:
        d = parse_duration(obj)
    except ValueError as e:
        raise v.err(line, where, str(e)) from None
    return {"duration": d}


_COND_KEYS = {"do", "fdbk", "state", "param", "alarm", "via"}


def _conditions(v: Checker, m: LDict, where: str) -> list[Condition]:
    out: list[Condition] = []
    via = _via(v, m, where)
    for k in m:
        if k not in _COND_KEYS:
            continue
        fw, kl = join(where, k), m.kline(k)
        val = m[k]
        if k == "do":
            for f, lv in _levels(v, val, kl, fw, DO_SYMBOLS, "DO function").items():
                out.append(Condition("do", f, lv))
        elif k == "fdbk":
            lv = level(val)
            if lv is None:
                raise v.err(kl, fw, f"{val!r}: on (closed) or off (open)")
            out.append(Condition("fdbk", "", lv))
        elif k == "state":
            if not isinstance(val, str) or val.strip().upper() not in STATES:
                raise v.err(kl, fw, f"{val!r}: one of {', '.join(STATES)}")
            out.append(Condition("state", "", val.strip().upper()))
        elif k == "param":
            pm = v.mapping(val, kl, fw)
            for p, x in _param_values(v, pm, fw, False).items():
                out.append(Condition("param", p, x, via))
        elif k == "alarm":
            if val is None or (isinstance(val, str) and val.lower() == "none") or val is False:
                out.append(Condition("alarm", "", None, via))
            elif isinstance(val, str) and _ALARM_RE.match(val.upper()):
                out.append(Condition("alarm", "", val.upper(), via))
            else:
                raise v.err(kl, fw, f"{val!r}: an alarm code like AL500, or none")
    if not out:
        raise v.err(m.line, where, "name a condition: do, fdbk, state, param or alarm")
    return out


def p_wait_until(v, obj, line, where):
    m = v.mapping(obj, line, where)
    v.keys(m, _COND_KEYS | {"timeout"}, where)
    out = {"conditions": _conditions(v, m, where), "timeout": None}
    if "timeout" in m:
        out["timeout"] = v.duration(m, "timeout", where)
    return out


def p_expect(v, obj, line, where):
    m = v.mapping(obj, line, where)
    v.keys(m, _COND_KEYS, where)
    return {"conditions": _conditions(v, m, where)}


def p_power_cycle(v, obj, line, where):
    if obj is None or obj is True:
        return {"battery": True}
    m = v.mapping(obj, line, where)
    v.keys(m, {"battery", "off"}, where)
    return {"battery": v.boolean(m, "battery", where, True),
            "off": v.duration(m, "off", where, 0)}


def p_inject(v, obj, line, where):
    m = v.mapping(obj, line, where)
    v.keys(m, {"options", "alarm"}, where)
    out: dict[str, Any] = {}
    if "options" in m:
        from dataclasses import fields

        from hil.model.options import ModelOptions

        om = v.mapping(m["options"], m.kline("options"), join(where, "options"))
        v.keys(om, {f.name for f in fields(ModelOptions)}, join(where, "options"))
        out["options"] = dict(om)
    if "alarm" in m:
        a = m["alarm"]
        if not isinstance(a, str) or not _ALARM_RE.match(a.upper()):
            raise v.err(m.kline("alarm"), join(where, "alarm"), f"{a!r}: an alarm code like AL009")
        out["alarm"] = a.upper()
    if not out:
        raise v.err(line, where, "inject options: {...} and/or alarm: ALnnn")
    return out


BIND_LINE_RE = re.compile(r"^(DI\d{1,2}|DO\d)(:[ab])?$|^STO_[AB]$")
_NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*$")
SINCE = ("start", "last_check")


def p_check_timing(v, obj, line, where):
    if isinstance(obj, str):
        return {"spec": obj, "params": {}, "bind": {}, "constants": {}, "since": "start"}
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
        params = {k: x for k, x in _param_values(v, pm, join(where, "params"), False).items()}
    bind: dict[str, str] = {}
    if "bind" in m:
        fw = join(where, "bind")
        bm = v.mapping(m["bind"], m.kline("bind"), fw)
        for k, x in bm.items():
            if not _NAME_RE.match(str(k)):
                raise v.err(bm.kline(k), join(fw, str(k)), "a placeholder name like REF")
            if not isinstance(x, str) or not (BIND_LINE_RE.match(x) or x in DI_SYMBOLS
                                               or x in DO_SYMBOLS):
                raise v.err(bm.kline(k), join(fw, k), f"{x!r}: a line (DI9, DI6:b, DO4) or a "
                            "wired DI/DO function (ORGP, NL)")
            bind[k] = x
    constants: dict[str, float] = {}
    if "constants" in m:
        fw = join(where, "constants")
        cm = v.mapping(m["constants"], m.kline("constants"), fw)
        for k, x in cm.items():
            if isinstance(x, bool) or not isinstance(x, int | float):
                raise v.err(cm.kline(k), join(fw, str(k)), f"{x!r}: a number (ms, rpm, ...)")
            constants[str(k)] = x
    return {"spec": v.text(m, "spec", where), "params": params, "bind": bind,
            "constants": constants, "since": since}


_ABS_FIELDS = ("status", "turns", "position")


def _mapping_or_empty(v: Checker, obj: Any, line: int, where: str) -> LDict:
    if obj is None or obj is True:
        m = LDict()
        m.line, m.key_lines = line, {}
        return m
    return v.mapping(obj, line, where)


def p_abs_read(v, obj, line, where):
    m = _mapping_or_empty(v, obj, line, where)
    v.keys(m, {"expect", "tolerance", "store", "same_as", "retries"}, where)
    out: dict[str, Any] = {"expect": {}, "store": None, "same_as": None,
                           "tolerance": v.integer(m, "tolerance", where, 0, _INT32[1], 0),
                           "retries": v.integer(m, "retries", where, 0, 5, 2)}
    if "expect" in m:
        fw = join(where, "expect")
        em = v.mapping(m["expect"], m.kline("expect"), fw)
        v.keys(em, set(_ABS_FIELDS), fw)
        for k in em:
            out["expect"][k] = v.integer(em, k, fw, *_INT32)
    for k in ("store", "same_as"):
        if k in m:
            name = m[k]
            if not isinstance(name, str) or not _NAME_RE.match(name):
                raise v.err(m.kline(k), join(where, k), f"{name!r}: a name like before_cycle")
            out[k] = name
    return out


def p_abs_origin(v, obj, line, where):
    m = _mapping_or_empty(v, obj, line, where)
    v.keys(m, {"hold"}, where)
    out: dict[str, Any] = {"hold": None}
    if "hold" in m:
        out["hold"] = v.duration(m, "hold", where)
        if out["hold"] <= 0:
            raise v.err(m.kline("hold"), join(where, "hold"), "must be > 0")
    return out


def p_fault_reset(v, obj, line, where):
    if obj not in (None, True):
        raise v.err(line, where, "write `fault_reset: true`")
    return {}


PARSERS: dict[str, Parser] = {
    "di": p_di,
    "pulse": p_pulse,
    "sto": p_sto,
    "sto_dropout": p_sto_dropout,
    "write": p_write,
    "read": p_read,
    "state": p_state,
    "fault_reset": p_fault_reset,
    "mode": p_mode,
    "move": p_move,
    "home": p_home,
    "wait": p_wait,
    "wait_until": p_wait_until,
    "expect": p_expect,
    "power_cycle": p_power_cycle,
    "inject": p_inject,
    "check_timing": p_check_timing,
    "abs_read": p_abs_read,
    "abs_origin": p_abs_origin,
    "fault": p_fault,
    "produce": p_produce,
    "sdo": p_sdo,
    "nmt": p_nmt,
}
PARSERS.update(PR_PARSERS)  # pr_table, pr_trigger, pr_wait (hil/plan/pr_steps.py)
VIRTUAL_ONLY = ("power_cycle", "inject")
MOTION = ("move", "home")


def parse_step(v: Checker, obj: Any, index: int, line: int) -> Step:
    where = f"steps[{index}]"
    m = v.mapping(obj, line, where)
    kinds = [k for k in m if k in PARSERS]
    unknown = [k for k in m if k not in PARSERS and k not in COMMON]
    if unknown:
        k = unknown[0]
        raise v.err(m.kline(k), join(where, k),
                    f"unknown step kind; known: {', '.join(PARSERS)} (common keys: "
                    f"{', '.join(sorted(COMMON))})")
    if len(kinds) != 1:
        problem = ("no step kind" if not kinds else f"one kind per step, found {', '.join(kinds)}")
        raise v.err(m.line, where, f"{problem}; known: {', '.join(PARSERS)}")
    kind = kinds[0]
    args = PARSERS[kind](v, m[kind], m.kline(kind), join(where, kind))
    step = Step(kind, args, index, m.kline(kind), v.file, raw=dict(m))
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
    return step


def parse_steps(v: Checker, obj: Any, line: int) -> list[Step]:
    lst: LList = v.seq(obj, line, "steps")
    if not lst:
        raise v.err(line, "steps", "a plan needs at least one step")
    steps = [parse_step(v, item, i, lst.item_lines[i]) for i, item in enumerate(lst)]
    stored: set[str] = set()
    names: set[str] = set()
    for st in steps:
        since = st.args.get("since") if st.kind == "check_timing" else None
        if since is not None and since not in SINCE and since not in names:
            raise v.err(st.raw[st.kind].kline("since"), join(st.where, "check_timing.since"),
                        f"{since!r}: start, last_check or the name of an earlier step "
                        f"(named so far: {', '.join(sorted(names)) or 'none'})")
        if st.name:
            names.add(st.name)
        if st.kind != "abs_read":  # `same_as` names a reading an earlier `abs_read` stored
            continue
        same = st.args["same_as"]
        if same is not None and same not in stored:
            raise v.err(st.raw[st.kind].kline("same_as"), join(st.where, "abs_read.same_as"),
                        f"no earlier abs_read stored {same!r} (stored so far: "
                        f"{', '.join(sorted(stored)) or 'none'})")
        if st.args["store"]:
            stored.add(st.args["store"])
    return steps
