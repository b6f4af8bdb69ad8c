"""The vocabulary step kinds share: states, conditions, DI/STO level maps, parameter values.

Parse helpers raise `PlanFileError` with file, line and field (hil/bench/yamlio.py).
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

from hil.bench.param_rules import check_param
from hil.bench.yamlio import Checker, LDict, join, level
from hil.profile.dio import DO_SYMBOLS
from hil.protocol.cia402 import MODES as CIA402_MODES

if TYPE_CHECKING:
    from hil.plan.kinds.base import CheckContext

STATES = ("SWITCH ON DISABLED", "READY TO SWITCH ON", "SWITCHED ON", "OPERATION ENABLED",
          "QUICK STOP ACTIVE", "FAULT")
# states a `state:` step can command (FAULT is reached, never commanded)
COMMANDABLE = STATES[:-1]
MODES = tuple(m for m in CIA402_MODES if m != "IP")  # a `mode:` step offers no IP
VIAS = ("modbus", "sdo")
STO = ("A", "B")
PARAM_RE = re.compile(r"^P[0-7]\.[0-9]{3}\Z")
ALARM_RE = re.compile(r"^AL[0-9A-F]{3}\Z")
NAME_RE = re.compile(r"^[A-Za-z_][A-Za-z0-9_]*\Z")
INT32 = (-(2**31), 2**31 - 1)


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


def levels(v: Checker, obj: Any, line: int, where: str, names: dict | tuple,
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


def widths(v: Checker, obj: Any, line: int, where: str, names: dict | tuple,
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


def parse_via(v: Checker, m: LDict, where: str) -> str | None:
    if "via" not in m:
        return None
    via = m["via"]
    if via not in VIAS:
        raise v.err(m.kline("via"), join(where, "via"), f"{via!r}: modbus or sdo")
    return via


def param_values(v: Checker, m: LDict, where: str, allow_none: bool,
                  write: bool = False) -> dict[str, int | None]:
    out: dict[str, int | None] = {}
    for k, val in m.items():
        if k in ("via", "expect_error"):
            continue
        if not PARAM_RE.match(k):
            raise v.err(m.kline(k), join(where, k), "a parameter name like P1.042 (or via)")
        if val is None and allow_none:
            check_param(v, m.kline(k), join(where, k), k, None, write=write)
            out[k] = None
            continue
        if isinstance(val, bool) or not isinstance(val, int):
            raise v.err(m.kline(k), join(where, k),
                        f"must be an integer (raw communication units), got {val!r}")
        if not INT32[0] <= val <= 0xFFFFFFFF:
            raise v.err(m.kline(k), join(where, k), f"{val} does not fit 32 bits")
        if not (write and "expect_error" in m):  # a write that expects the refusal is fine
            check_param(v, m.kline(k), join(where, k), k, val, write=write)
        out[k] = val
    if not out:
        raise v.err(m.line, where, "name at least one parameter, e.g. P1.042: 150")
    return out


# Refusal codes a `write` may expect (`expect_error`): a Modbus exception code (1..255,
# e.g. 03h illegal data value, Modbus application protocol) or a CiA 301 SDO abort code (e.g.
# 0x06090031 value too high, L17024-17042).
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


def mapping_or_empty(v: Checker, obj: Any, line: int, where: str) -> LDict:
    if obj is None or obj is True:
        m = LDict()
        m.line, m.key_lines = line, {}
        return m
    return v.mapping(obj, line, where)


COND_KEYS = {"do", "fdbk", "state", "param", "alarm", "via"}


def conditions(v: Checker, m: LDict, where: str) -> list[Condition]:
    out: list[Condition] = []
    via = parse_via(v, m, where)
    for k in m:
        if k not in COND_KEYS:
            continue
        fw, kl = join(where, k), m.kline(k)
        val = m[k]
        if k == "do":
            for f, lv in levels(v, val, kl, fw, DO_SYMBOLS, "DO function").items():
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
            for p, x in param_values(v, pm, fw, False).items():
                out.append(Condition("param", p, x, via))
        elif k == "alarm":
            if val is None or (isinstance(val, str) and val.lower() == "none") or val is False:
                out.append(Condition("alarm", "", None, via))
            elif isinstance(val, str) and ALARM_RE.match(val.upper()):
                out.append(Condition("alarm", "", val.upper(), via))
            else:
                raise v.err(kl, fw, f"{val!r}: an alarm code like AL500, or none")
    if not out:
        raise v.err(m.line, where, "name a condition: do, fdbk, state, param or alarm")
    return out


def check_via(cc: CheckContext, field: str, via: str | None) -> None:
    """A parameter route the step's drive really has (`via:` or the drive's default)."""
    d, dname = cc.drive, cc.dname
    via = via or d.param_via
    if not via:
        raise cc.err(f"drive {dname} has no parameter access (rs485 or can)", field)
    if via == "modbus" and not d.rs485:
        raise cc.err(f"drive {dname} has no RS-485 line for via: modbus", field)
    if via == "sdo" and not d.can:
        raise cc.err(f"drive {dname} has no CAN bus for via: sdo", field)


def check_dio(cc: CheckContext) -> None:
    if not cc.drive.dio:
        raise cc.err(f"drive {cc.dname} has no DI/DO lines (dio:)")


def check_can(cc: CheckContext) -> None:
    if not cc.drive.can:
        raise cc.err(f"drive {cc.dname} has no CAN bus: CiA 402 needs `can:`")
