"""Does a spec apply to a recording's drive? Its DI/DO functions against the drive's mapping.

A spec binds functions to lines (`BRKR: DO6`, the factory mapping, or its `bind:`). When the
recording holds the drive's own mapping parameter of that line (P2.010-P2.022, P2.036-P2.041,
L15243) and no value of it ever selects that function, the spec's scenario cannot be on this
recording: `hil check` with every shipped spec says "not applicable" instead of judging, say,
an absolute-encoder handshake on DO4 of a drive whose DO4 is TPOS. A line whose mapping is not
recorded (a real bench) is taken as bound: judged as before. Likewise a spec's `requires:`
(parameters its scenario needs at some time, e.g. COMPARE started) that never held.
"""

from __future__ import annotations

import re

from hil.profile.dio import DI_PARAMS, DI_SYMBOLS, DO_PARAMS, DO_SYMBOLS
from hil.record import topics
from hil.timing.expr import Expr, ExprError
from hil.timing.source import SignalSource
from hil.timing.spec import Spec

_LINE = re.compile(r"(DI|DO)([0-9]+)")


def mapping_param(line: str) -> tuple[str, dict[str, int]] | None:
    """`DO4` -> ("P2.021", DO function codes); None for STO and lines beyond the table."""
    m = _LINE.fullmatch(line)
    if not m:
        return None
    kind, n = m.group(1), int(m.group(2))
    params, symbols = (DI_PARAMS, DI_SYMBOLS) if kind == "DI" else (DO_PARAMS, DO_SYMBOLS)
    if not 1 <= n <= len(params):
        return None
    return params[n - 1], symbols


def not_applicable(spec: Spec, source: SignalSource, binding: dict[str, str]) -> str | None:
    """Why `spec` does not apply to the recorded drive, or None (it applies, or unknown)."""
    bind = spec.binding(binding)
    # a record whose values are not an object of whole numbers says nothing of the drive
    timed = [(t, values) for t, msg in
             source.messages(topics.drive_params(bind.get("drive", "drive1")))
             if isinstance(values := msg.get("values") or {}, dict)
             and all(type(v) is int for v in values.values())]
    history: dict[str, list[tuple[int, int]]] = {}  # parameter -> (t, value) in time order
    for t, values in timed:
        for name, value in values.items():
            history.setdefault(name, []).append((t, value))
    if not history:
        return None
    records = [values for _t, values in timed]
    if spec.requires is not None and (why := _never_required(spec.requires, records)):
        return why
    for sig in spec.signals.values():
        if sig.kind != "function" or not sig.function:
            continue
        line = bind.get(sig.function, "").partition(":")[0]
        found = mapping_param(line)
        if found is None:
            continue
        param, symbols = found
        code = symbols.get(sig.function)
        values = [value for _t, value in history.get(param, ())]
        if code is None or not values:  # a spec-local name (MARK), or mapping not recorded
            continue
        shown = ", ".join(dict.fromkeys(f"0x{v:04X}" for v in values))
        if all(v & 0xFF != code for v in values):
            return (f"{line} is not {sig.function} on this drive ({param} = {shown}; "
                    f"{sig.function} is 0x{code:02X})")
        changes = [t for t, _m in source.messages(topics.dio(bind.get("dio", "drive1"), line))]
        if changes[1:] and not any(_mapped_at(history[param], t) == code for t in changes[1:]):
            # the line only changed while it was another function (a plan's own mapping,
            # written after the factory one was recorded): no scenario of this function
            return (f"{line} never changed while it was {sig.function} ({param} = {shown}; "
                    f"{sig.function} is 0x{code:02X})")
    return None


def _mapped_at(history: list[tuple[int, int]], t: int) -> int | None:
    """The function code the mapping parameter selected at t (its last record at or before
    t; the first record for an instant before it)."""
    code = None
    for when, value in history:
        if when > t and code is not None:
            break
        code = value & 0xFF
    return code


def _never_required(requires: Expr, records: list[dict]) -> str | None:
    """`requires` never held for the parameters in force after any record."""
    env: dict[str, int] = {}
    seen = False
    for values in records:
        env.update({k: int(v) for k, v in values.items()})
        try:
            if requires.eval(env):
                return None
            seen = True
        except (KeyError, ExprError):  # not recorded (yet): unknown
            continue
    return f"{requires} never held on this drive" if seen else None
