"""`hil diff A.mcap B.mcap`: the same plan recorded twice (a real drive vs the virtual one,
before vs after a change), aligned step by step.

* **Alignment**: every edge is placed in the plan step that was running when it happened
  (`/plan/steps` start events) at an offset from that step's start; B's edges are mapped
  onto A's timeline as `start_A(step) + offset_B`, so a step that lasted longer in B (a
  `wait_until` waiting for a late output) does not shift everything after it.
* **Edges** per signal (`/dio/<drive>/<line>` levels, ground-truth booleans and CiA 402
  states of `/drive/<drive>/state`), paired by signal, new value and order: delta in ms.
* **Timing verdicts** side by side (measured ms of each spec/constraint/occurrence).
* **State sequences**: CiA 402 states, statuswords and active alarms in order, where they
  differ.
* **Explanations**: signatures of model options (`SIGNATURES`), each an interval between two
  events measured in both recordings; a difference names the options that would explain it
  and estimates their size.

All times are the sources' own (publish time: model clock, adapter time), as the checker's.
"""

from __future__ import annotations

import difflib
import json
import re
import statistics
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from hil.fileio import dumps_strict, write_text_atomic
from hil.record import topics
from hil.record.reader import Recording, decode_record, virtual_bench
from hil.report.html import CSS
from hil.terminal import html_text
from hil.timing.source import verdict_shape
from hil.units import MS
from hil.yamlio import load_yaml_text

TRUTH_EDGES = ("servo_on", "brkr", "brake_released", "torque_enabled", "sto_a", "sto_b")
MIN_DELTA_MS = 1.0  # smaller differences are jitter of an in-process bench


@dataclass
class Side:
    """What the diff reads from one recording."""

    path: str
    plan: str = ""
    bench: str = ""
    clock: str = ""  # `hil.clock`'s clock (virtual / real), "" where not recorded
    starts: dict[int, int] = field(default_factory=dict)  # step index -> start (ns)
    start_order: list[int] = field(default_factory=list)  # step indices as their starts came
    # (signal, t) -> how many step starts the recording held when the edge was recorded: an
    # edge at the very instant a step started belongs to it only if recorded after its start
    # (in virtual time a `wait_until`'s level and the next step's start share an instant)
    seen: dict[tuple[str, int], int] = field(default_factory=dict)
    labels: dict[int, str] = field(default_factory=dict)
    t0: int = 0
    edges: dict[str, list[tuple[int, Any]]] = field(default_factory=dict)  # signal -> (t, v)
    functions: dict[str, str] = field(default_factory=dict)  # function -> signal name
    states: dict[str, list[str]] = field(default_factory=dict)  # "drive1 state" -> sequence
    verdicts: dict[tuple, dict] = field(default_factory=dict)
    params: dict[str, Any] = field(default_factory=dict)
    # bench.yaml options (the plan's `options` over them, as the run merged them) + mechanics
    options: dict[str, Any] = field(default_factory=dict)
    bad_messages: int = 0  # records of a wrong shape skipped (the reader warns of the first)


def _bench_drive(text: str) -> dict:
    """The first drive of a recording's bench.yaml attachment, its parts the diff reads as
    mappings ({} for anything else): read with the project's YAML limits (an alias bomb, a
    huge or deep file is refused), since a recording is input like any other."""
    try:
        data = load_yaml_text(text, "bench.yaml")
    except Exception:  # a foreign or broken attachment: no wiring known
        return {}
    drives = data.get("drives") if isinstance(data, dict) else None
    drive = next(iter(drives.values()), {}) if isinstance(drives, dict) and drives else {}
    if not isinstance(drive, dict):
        return {}
    return {k: drive[k] for k in ("wiring", "options", "mechanics")
            if isinstance(drive.get(k), dict)}


def _plan_options(text: str) -> dict:
    """The `options` of a recording's plan.yaml attachment ({} for anything else), read with
    the project's YAML limits."""
    try:
        data = load_yaml_text(text, "plan.yaml")
    except Exception:  # a foreign or broken attachment: no options known
        return {}
    opts = data.get("options") if isinstance(data, dict) else None
    return dict(opts) if isinstance(opts, dict) else {}


def load_side(path: str | Path) -> Side:
    """One side of a diff, read twice without holding the file or its chunks: its metadata
    and attachments (the wiring) outside the chunks, then each message as it comes."""
    rec = Recording.head(path)
    meta = rec.metadata()
    run = meta.get("hil.run", {})
    side = Side(str(path), run.get("plan", Path(path).stem), run.get("bench", "?"),
                str(meta.get("hil.clock", {}).get("clock", "")))
    drive: dict = {}
    plan_opts: dict = {}
    for a in rec.attachments():
        if a.name == "bench.yaml":
            drive = _bench_drive(a.data.decode("utf-8", "replace"))
        elif a.name == "plan.yaml" and virtual_bench(meta):  # a plan's options go to every
            # virtual drive (bench_with_options)
            plan_opts = _plan_options(a.data.decode("utf-8", "replace"))
    wiring = dict(drive.get("wiring") or {})
    try:
        binding = json.loads(meta.get("timing", {}).get("binding", "{}"))
    except (ValueError, RecursionError):
        binding = {}
    if isinstance(binding, dict):
        wiring |= {k: v for k, v in binding.items() if k not in ("drive", "dio")}
    side.options = {**dict(drive.get("options") or {}), **plan_opts,
                    **{f"mechanics.{k}": v for k, v in (drive.get("mechanics") or {}).items()}}
    line_func = {}
    for func, w in wiring.items():
        line, _, contact = str(w).partition(":")
        line_func[line] = (func, contact == "b")
    last: dict[str, Any] = {}
    states: dict[str, list[str]] = {}
    shapeless = [0]  # DI/DO records without a level

    def take(topic: str, lt: int, pt: int, raw: bytes) -> None:
        if topic.startswith("/can/"):
            return  # raw frames: nothing here reads them
        msg = decode_record(raw, topic)  # none an object: skipped and counted
        t = pt or lt
        if topic == topics.PLAN_STEPS:
            idx = msg.get("index")
            if msg.get("event") == "start" and type(idx) is not int:
                raise TypeError(f"{topic}: a step start whose index is no whole number")
            if msg.get("event") == "start" and isinstance(idx, int):
                if idx not in side.starts:
                    side.start_order.append(idx)
                side.starts.setdefault(idx, lt)
                side.labels[idx] = str(msg.get("step", ""))
        elif topic == topics.TIMING_VERDICTS:
            verdict_shape(msg)  # a measured "150" compared as nothing (helper-137)
            key = (msg.get("spec"), msg.get("constraint"), msg.get("occurrence"))
            side.verdicts[key] = msg
        elif topic.startswith("/dio/"):
            if type(msg.get("level")) is not bool:
                shapeless[0] += 1  # {}, "false" or 1: no level (it read as a True edge, or
                return  # vanished, with exit 0: helper-129; `hil check` refuses 1 too)
            line = topic.split("/")[3]
            func, inverted = line_func.get(line, ("", False))
            name = f"{line} {func}".strip()
            if func:
                side.functions[func] = name
            _change(side, last, name, t, bool(msg["level"]) != inverted)
        elif topic.startswith("/drive/") and topic.endswith("/state"):
            d = topic.split("/")[2]
            for f in TRUTH_EDGES:
                if f in msg:
                    _change(side, last, f"{d}.{f}", t, bool(msg[f]))
            for f in ("state", "statusword"):
                if msg.get(f) not in (None, ""):
                    _change(side, last, f"{d}.{f}", t, msg[f])
                    seq = states.setdefault(f"{d} {f}", [])
                    shown = _word(msg[f]) if f == "statusword" else str(msg[f])
                    if not seq or seq[-1] != shown:
                        seq.append(shown)
            alarms = msg.get("alarms")
            if isinstance(alarms, list):  # AL500 in one run only (helper-137)
                seq = states.setdefault(f"{d} alarms", [])
                shown = ", ".join(map(str, alarms)) or "none"
                if not seq or seq[-1] != shown:
                    seq.append(shown)
        elif topic.startswith("/drive/") and topic.endswith("/params"):
            side.params.update(msg.get("values") or {})
        elif topic.startswith("/canopen/") and "statusword" in msg:  # a real drive's TPDO
            seq = states.setdefault(f"{topic} statusword", [])
            shown = _word(msg["statusword"])
            if not seq or seq[-1] != shown:
                seq.append(shown)

    whole = Recording.stream(path, None, take)
    side.bad_messages = whole.bad_messages + shapeless[0]
    full = whole.metadata().get("hil.run", {})
    side.plan, side.bench = full.get("plan", side.plan), full.get("bench", side.bench)
    side.states = states
    side.t0 = min(side.starts.values()) if side.starts else 0
    for name in list(side.edges):  # only what happened during the plan
        side.edges[name] = [(t, v) for t, v in side.edges[name] if t >= side.t0]
    return side


def _word(value: Any) -> str:
    """A statusword as the manual writes one, `0x0237` (it read `567`); anything else as
    it came."""
    return f"0x{value:04X}" if type(value) is int and 0 <= value <= 0xFFFF else str(value)


def _change(side: Side, last: dict, name: str, t: int, value: Any) -> None:
    """Record `value` of signal `name` at `t` when it changed (the first sample is no edge)."""
    if name in last and last[name] != value:
        side.edges.setdefault(name, []).append((t, value))
        side.seen.setdefault((name, t), len(side.start_order))
    last[name] = value


def _place(side: Side, t: int, name: str | None = None) -> tuple[int, int]:
    """(step index, offset ns) of instant `t`: the step running then (of steps that began at
    the same instant, as zero-time steps do in virtual time, the last one). For signal
    `name`'s edge, of the steps whose start was recorded before the edge."""
    n = side.seen.get((name, t)) if name is not None else None
    steps = side.start_order[:n] if n is not None else side.starts
    k = max((i for i in steps if side.starts[i] <= t), key=lambda i: (side.starts[i], i),
            default=min(side.starts, default=0))
    return k, t - side.starts.get(k, side.t0)


def _map(a: Side, b: Side, t_b: int, name: str | None = None) -> int:
    """B's instant on A's timeline: the same offset into the same step."""
    k, off = _place(b, t_b, name)
    return a.starts.get(k, a.t0 + (t_b - b.t0)) + off


# --- signatures: interval (from event, to event) -> options that would explain a change ----
@dataclass(frozen=True)
class Signature:
    key: str
    what: str
    start: tuple[str, Any]  # (signal or "func:NAME", value)
    end: tuple[str, Any]
    options: tuple[str, ...]
    estimate: str  # "delta": knob = B - A; "absolute": B's interval; "param:P": A's P + delta


SIGNATURES = (
    Signature("scan", "DI SON closes -> servo on (DI filter, scan delay)",
              ("func:SON", True), ("truth:servo_on", True),
              ("P2.009 (DI response filter, L9229-9236)", "scan delay"), "param:P2.009"),
    Signature("brake_on", "servo on -> BRKR on (P1.042, L8492-8501)",
              ("truth:servo_on", True), ("func:BRKR", True),
              ("dev_brake_on_delay_ms", "P1.042"), "delta"),
    Signature("brake_off", "servo off -> BRKR off (P1.043 / P1.038 rule, L8503-8516)",
              ("truth:servo_on", False), ("func:BRKR", False),
              ("dev_brake_off_delay_ms", "dev_ignore_speed_rule", "P1.043"), "delta"),
    Signature("brake_release", "BRKR on -> shaft free (brake mechanics)",
              ("truth:brkr", True), ("truth:brake_released", True),
              ("mechanics.brake_release_ms",), "absolute"),
    Signature("brake_engage", "BRKR off -> shaft clamped (brake mechanics)",
              ("truth:brkr", False), ("truth:brake_released", False),
              ("mechanics.brake_engage_ms",), "absolute"),
)


def _signal(side: Side, ref: str) -> list[tuple[int, Any]]:
    kind, _, name = ref.partition(":")
    if kind == "func":
        return side.edges.get(side.functions.get(name, "?"), [])
    return next((e for n, e in side.edges.items() if n.endswith("." + name)), [])


def intervals(side: Side, sig: Signature) -> list[float]:
    """ms from each `start` edge to the first `end` edge after it (before the next start)."""
    starts = [t for t, v in _signal(side, sig.start[0]) if v == sig.start[1]]
    ends = [t for t, v in _signal(side, sig.end[0]) if v == sig.end[1]]
    out = []
    for i, s in enumerate(starts):
        nxt = starts[i + 1] if i + 1 < len(starts) else None
        e = next((e for e in ends if e >= s and (nxt is None or e < nxt)), None)
        if e is not None:
            out.append((e - s) / MS)
    return out


def _is_param(name: str) -> bool:
    return re.match(r"P\d\.\d{3}\b", name) is not None


def _param_moves(a: Side, b: Side, sig: Signature) -> tuple[str, float, float] | None:
    """The first parameter among `sig`'s knobs (or its estimate's) whose recorded value
    differs between A and B, with both values; None when none does."""
    names = [o.split(" ", 1)[0] for o in sig.options if _is_param(o)]
    if sig.estimate.startswith("param:"):
        names.insert(0, sig.estimate.split(":", 1)[1])
    for p in names:
        pa, pb = a.params.get(p), b.params.get(p)
        if (isinstance(pa, int | float) and isinstance(pb, int | float)
                and not isinstance(pa, bool) and not isinstance(pb, bool) and pa != pb):
            return p, pa, pb
    return None


def _unset(x: Any) -> str:
    return "not set (its default)" if x is None else str(x)


def _recorded_options(a: Side, b: Side, sig: Signature) -> dict | None:
    """On two recordings whose model options are on record (virtual benches), what they say
    instead of a guess: the option of this interval that differs, with its two values; or,
    when none of its options differs, the options that do (helper-129: a page showed
    dev_brake_on_delay_ms 30 in A and 6 in B and explained "~ -24 ms, the option at 0 in
    A", and named dev_brake_off_delay_ms for a run that differed only in
    dev_ignore_speed_rule). None when the options are not known, or no option differs and
    a parameter may explain it."""
    if not a.options and not b.options:
        return None
    names = [o for o in sig.options if not _is_param(o)]
    for o in names:
        va, vb = a.options.get(o), b.options.get(o)
        if va != vb:
            return {"option": o, "estimate": vb,
                    "basis": f"{o} differs in the recordings ({_unset(va)} in A, "
                             f"{_unset(vb)} in B)"}
    other = sorted(k for k in set(a.options) | set(b.options)
                   if a.options.get(k) != b.options.get(k) and k not in names)
    if other and _param_moves(a, b, sig) is None:
        return {"option": ", ".join(other), "estimate": None,
                "basis": "none of this interval's options differs in the recordings; "
                         f"these do: {', '.join(other)}"}
    return None


def explain(a: Side, b: Side) -> list[dict]:
    """Model options that would explain the differences, with an estimate of their size."""
    out = []
    for sig in SIGNATURES:
        ia, ib = intervals(a, sig), intervals(b, sig)
        if not ia or not ib:
            continue
        ma, mb = statistics.median(ia), statistics.median(ib)
        delta = mb - ma
        if abs(delta) < max(MIN_DELTA_MS, 0.05 * abs(ma)):
            continue
        option = sig.options[0]
        recorded = _recorded_options(a, b, sig)  # virtual benches: the options are known
        if recorded is not None:
            out.append({"signature": sig.key, "what": sig.what, "options": list(sig.options),
                        "a_ms": round(ma, 3), "b_ms": round(mb, 3), "delta_ms": round(delta, 3),
                        "n": [len(ia), len(ib)], **recorded})
            continue
        moved = _param_moves(a, b, sig)  # a parameter of this interval differs: its part
        if moved is not None:
            p, pa, pb = moved
            rest = delta - (pb - pa)  # the parameters are ms (P1.042, P1.043, P2.009)
            if abs(rest) < max(MIN_DELTA_MS, 0.05 * abs(ma)):
                out.append({"signature": sig.key, "what": sig.what, "options": list(sig.options),
                            "option": p, "a_ms": round(ma, 3), "b_ms": round(mb, 3),
                            "delta_ms": round(delta, 3), "estimate": pb,
                            "basis": f"{p} differs ({pa} in A, {pb} in B): the whole difference",
                            "n": [len(ia), len(ib)]})
                continue
            est, basis = rest, f"delta less {p}'s change ({pa} in A, {pb} in B)"
            option = next((o for o in sig.options if o != p and not _is_param(o)), option)
        elif sig.estimate == "absolute":
            est, basis = mb, "B's measured interval"
        elif sig.estimate.startswith("param:"):
            p = sig.estimate.split(":", 1)[1]
            base = a.params.get(p)
            est = (base + delta) if isinstance(base, int | float) else delta
            basis = f"A's {p} = {base} + delta" if isinstance(base, int | float) else "delta"
        else:
            est, basis = delta, "B - A, with the option at 0 in A"
        out.append({"signature": sig.key, "what": sig.what, "options": list(sig.options),
                    "option": option, "a_ms": round(ma, 3), "b_ms": round(mb, 3),
                    "delta_ms": round(delta, 3), "estimate": round(est, 3), "basis": basis,
                    "n": [len(ia), len(ib)]})
    out += _constant_shift(a, b, {e["signature"] for e in out})
    return out


def _constant_shift(a: Side, b: Side, found: set[str]) -> list[dict]:
    """A real drive has no ground truth: every DO reaction shifted by about the same amount
    is the signature of a scan delay / DI filter (P2.009)."""
    if "scan" in found or any(n.endswith(".servo_on") for n in a.edges):
        return []
    deltas = [e["delta_ms"] for s in edge_diffs(a, b) if s["signal"].startswith("DO")
              for e in s["edges"] if e["delta_ms"] is not None]
    if len(deltas) < 2:
        return []
    c = statistics.median(deltas)
    if abs(c) < MIN_DELTA_MS or any(abs(d - c) > max(1.0, 0.15 * abs(c)) for d in deltas):
        return []
    return [{"signature": "scan", "what": "every DO reaction shifted by the same time",
             "options": ["P2.009 (DI response filter, L9229-9236)", "scan delay"],
             "option": "P2.009 (DI response filter, L9229-9236)", "a_ms": None, "b_ms": None,
             "delta_ms": round(c, 3), "estimate": round(c, 3), "basis": "delta",
             "n": [len(deltas), len(deltas)]}]


def edge_diffs(a: Side, b: Side) -> list[dict]:
    """Per signal: its edges paired by new value and order, with B mapped onto A's time."""
    out = []
    for name in sorted(set(a.edges) | set(b.edges)):
        ea, eb = a.edges.get(name, []), b.edges.get(name, [])
        rows = []
        values = list(dict.fromkeys([v for _, v in ea] + [v for _, v in eb]))
        for val in values:
            ta = [t for t, v in ea if v == val]
            tb = [t for t, v in eb if v == val]
            for i in range(max(len(ta), len(tb))):
                r: dict[str, Any] = {"value": val, "n": i + 1, "step": None, "a_ms": None,
                                     "b_ms": None, "delta_ms": None}
                if i < len(ta):
                    k, _ = _place(a, ta[i], name)
                    r.update(step=k, a_ms=round((ta[i] - a.t0) / MS, 3))
                if i < len(tb):
                    mb = _map(a, b, tb[i], name)
                    r["b_ms"] = round((mb - a.t0) / MS, 3)
                    if r["step"] is None:
                        r["step"] = _place(b, tb[i], name)[0]
                if i < len(ta) and i < len(tb):
                    r["delta_ms"] = round((mb - ta[i]) / MS, 3)
                rows.append(r)
        rows.sort(key=lambda r: r["a_ms"] if r["a_ms"] is not None else r["b_ms"])
        moved = [r for r in rows if r["delta_ms"] is None or abs(r["delta_ms"]) >= MIN_DELTA_MS]
        out.append({"signal": name, "edges": rows, "differs": bool(moved),
                    "max_delta_ms": max((abs(r["delta_ms"]) for r in rows
                                         if r["delta_ms"] is not None), default=None),
                    "count": [len(ea), len(eb)]})
    return out


def verdict_diffs(a: Side, b: Side) -> list[dict]:
    out = []
    for key in sorted(set(a.verdicts) | set(b.verdicts), key=repr):
        va, vb = a.verdicts.get(key, {}), b.verdicts.get(key, {})
        ma, mb = va.get("measured_ms"), vb.get("measured_ms")
        num = isinstance(ma, int | float) and isinstance(mb, int | float)
        out.append({"spec": key[0], "constraint": key[1], "occurrence": key[2],
                    "step": va.get("step", vb.get("step")),
                    "a_status": va.get("status"), "b_status": vb.get("status"),
                    "a_ms": ma, "b_ms": mb, "delta_ms": round(mb - ma, 3) if num else None,
                    "window_ms": va.get("window_ms") or vb.get("window_ms")})
    return out


def state_diffs(a: Side, b: Side) -> list[dict]:
    out = []
    for key in sorted(set(a.states) | set(b.states)):
        sa, sb = a.states.get(key, []), b.states.get(key, [])
        if sa == sb:
            continue
        ops = [f"{tag}: A {sa[i1:i2]} B {sb[j1:j2]}" for tag, i1, i2, j1, j2
               in difflib.SequenceMatcher(a=sa, b=sb).get_opcodes() if tag != "equal"]
        out.append({"sequence": key, "a": sa, "b": sb, "differences": ops})
    return out


def diff(a_path: str | Path, b_path: str | Path) -> dict:
    """The whole comparison as plain data (what the JSON file holds)."""
    a, b = load_side(a_path), load_side(b_path)
    la = [a.labels[k] for k in sorted(a.labels)]
    lb = [b.labels[k] for k in sorted(b.labels)]
    # the parameters both hold (a run cut before its snapshot holds none: not 554 changes)
    params = {p: [a.params.get(p), b.params.get(p)] for p in sorted(set(a.params) & set(b.params))
              if a.params.get(p) != b.params.get(p)}
    options = {o: [a.options.get(o), b.options.get(o)]
               for o in sorted(set(a.options) | set(b.options))
               if a.options.get(o) != b.options.get(o)}
    partial = [f"{x.path}: {x.bad_messages} message(s) of a wrong shape were skipped (the "
               "warning above names the first): what they held is not compared"
               for x in (a, b) if x.bad_messages]
    partial += [f"{x.path}: no step start could be read ({y.path} has {len(y.starts)}): its "
                "edges cannot be placed in the plan's steps" for x, y in ((a, b), (b, a))
                if y.starts and not x.starts]
    partial += [f"{x.path}: holds no parameter values ({y.path} holds {len(y.params)}): its "
                "parameters are not compared" for x, y in ((a, b), (b, a))
                if y.params and not x.params]
    return {"a": {"path": a.path, "plan": a.plan, "bench": a.bench, "clock": a.clock},
            "b": {"path": b.path, "plan": b.plan, "bench": b.bench, "clock": b.clock},
            "same_plan": a.plan == b.plan, "same_steps": la == lb,
            "steps": [{"index": k, "label": a.labels.get(k, b.labels.get(k)),
                       "a_ms": round((a.starts[k] - a.t0) / MS, 3) if k in a.starts else None,
                       "b_ms": round((b.starts[k] - b.t0) / MS, 3) if k in b.starts else None}
                      for k in sorted(set(a.starts) | set(b.starts))],
            "signals": edge_diffs(a, b), "verdicts": verdict_diffs(a, b),
            "states": state_diffs(a, b), "explanations": explain(a, b),
            "params": params, "options": options, "incomplete": partial}


# --- HTML -----------------------------------------------------------------------------------
esc = html_text  # control characters as \xNN, then HTML-escaped


def _n(x: Any) -> str:
    return "–" if x is None else (f"{x:.3f}" if isinstance(x, float) else esc(str(x)))


def _side_bench(side: dict) -> str:
    """`bench virtual, clock real`: which bench and on which clock the run went."""
    clk = side.get("clock") or ""
    return f"bench {esc(side['bench'])}" + (f", clock {esc(clk)}" if clk else "")


def _estimate_html(est: Any) -> str:
    """` ≈ 6 ms` (a size), ` ≈ True` (an option's value), nothing when none is known."""
    if est is None:
        return ""
    unit = "" if isinstance(est, bool) or not isinstance(est, int | float) else " ms"
    return f" ≈ <b>{_n(est)}</b>{unit}"


def _verdict_cell(v: dict, side: str) -> str:
    """A verdict's value and status in one run; "not in this run" where it has none."""
    status = v[f"{side}_status"]
    if status is None:
        return "– <small>not in this run</small>"
    return f"{_n(v[f'{side}_ms'])} {esc(str(status))}"


def render_html(d: dict) -> str:
    h = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
         f"<title>hil diff: {esc(d['a']['plan'])}</title><style>{CSS}</style></head><body>",
         f"<h1>hil diff: {esc(d['a']['plan'])}</h1>",
         f"<p>A <code>{esc(d['a']['path'])}</code> ({_side_bench(d['a'])}) · "
         f"B <code>{esc(d['b']['path'])}</code> ({_side_bench(d['b'])}) · times in ms from "
         "A's plan start, B mapped onto A step by step</p>"]
    for why in d.get("incomplete", ()):  # a cut or damaged file: compared as far as it goes
        h.append(f"<p class='fail'>Incomplete: {esc(why)}</p>")
    if not d["same_plan"]:
        h.append("<p class='fail'>The recordings are not of the same plan: the alignment is "
                 "by step index only.</p>")
    elif not d["same_steps"]:  # (it said "not of the same plan" while the JSON said it was)
        h.append("<p class='fail'>The plan's steps differ between the recordings: the "
                 "alignment is by step index only.</p>")
    h.append("<h2>Model options that would explain the differences</h2>")
    if d["explanations"]:
        h.append("<table id='explanations'><tr><th>signature</th><th>A ms</th><th>B ms</th>"
                 "<th>delta ms</th><th>options</th><th>estimate</th></tr>")
        for e in d["explanations"]:
            h.append(f"<tr><td>{esc(e['what'])}</td><td>{_n(e['a_ms'])}</td><td>{_n(e['b_ms'])}"
                     f"</td><td>{_n(e['delta_ms'])}</td><td>{esc(', '.join(e['options']))}</td>"
                     f"<td>{esc(e['option'])}{_estimate_html(e['estimate'])}<br><small>"
                     f"{esc(e['basis'])}</small></td></tr>")
        h.append("</table>")
    else:
        h.append("<p>No signature differs.</p>")
    h.append("<h2>Timing verdicts side by side</h2><table><tr><th>step</th><th>spec</th>"
             "<th>constraint</th><th>A</th><th>B</th><th>delta ms</th></tr>")
    for v in d["verdicts"]:
        step = v["step"] + 1 if isinstance(v["step"], int) else "–"
        h.append(f"<tr><td>{step}</td><td>{esc(str(v['spec']))}</td>"
                 f"<td>{esc(str(v['constraint']))}</td>"
                 f"<td class='{esc(str(v['a_status']))}'>{_verdict_cell(v, 'a')}</td>"
                 f"<td class='{esc(str(v['b_status']))}'>{_verdict_cell(v, 'b')}</td>"
                 f"<td>{_n(v['delta_ms'])}</td></tr>")
    h.append("</table><h2>Edges per signal</h2><table><tr><th>signal</th><th>edge</th>"
             "<th>step</th><th>A ms</th><th>B ms</th><th>delta ms</th></tr>")
    labels = {s["index"]: s["label"] for s in d["steps"]}
    for s in d["signals"]:
        for r in s["edges"]:
            cls = " class='fail'" if r["delta_ms"] is None or abs(r["delta_ms"]) >= \
                MIN_DELTA_MS else ""
            step = f"{r['step'] + 1}: {labels.get(r['step'], '')}" if r["step"] is not None \
                else "–"
            h.append(f"<tr{cls}><td>{esc(s['signal'])}</td><td>→ {esc(str(r['value']))} "
                     f"#{r['n']}</td><td>{esc(step)}</td><td>{_n(r['a_ms'])}</td>"
                     f"<td>{_n(r['b_ms'])}</td><td>{_n(r['delta_ms'])}</td></tr>")
    h.append("</table><h2>State sequences</h2>")
    if d["states"]:
        for s in d["states"]:
            h.append(f"<h3>{esc(s['sequence'])}</h3><pre>"
                     + esc("\n".join(s["differences"])) + "</pre>")
    else:
        h.append("<p>Identical.</p>")
    for title, key in (("Parameters that differ", "params"), ("Bench options that differ",
                                                              "options")):
        if d[key]:
            h.append(f"<h2>{title}</h2><table><tr><th></th><th>A</th><th>B</th></tr>"
                     + "".join(f"<tr><td>{esc(k)}</td><td>{_n(v[0])}</td><td>{_n(v[1])}</td></tr>"
                               for k, v in d[key].items()) + "</table>")
    h.append("</body></html>\n")
    return "\n".join(h)


def write_diff(a: str | Path, b: str | Path, html_out: str | Path,
               json_out: str | Path | None = None,
               incomplete: list[str] | None = None) -> tuple[dict, Path, Path]:
    """The comparison to `html_out` and `json_out`; `incomplete`: what the caller found cut
    or damaged in the files (`hil diff`'s reader checks), on the page and in the JSON too."""
    d = diff(a, b)
    d["incomplete"] = [*(incomplete or ()), *d["incomplete"]]
    html_out = Path(html_out)
    json_out = Path(json_out) if json_out else html_out.with_suffix(".json")
    write_text_atomic(html_out, render_html(d))
    write_text_atomic(json_out, dumps_strict(d, indent=1, default=str) + "\n")
    return d, html_out, json_out
