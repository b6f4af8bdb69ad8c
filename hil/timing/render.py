"""Expected vs observed timing diagrams: WaveJSON (for WaveDrom) and a self-contained SVG.

Observed signals are drawn as steps on a time axis in ms; each judged window is a shaded
band on the lane of the signal it constrains (green pass, red fail, amber inconclusive),
labelled with its constraint and limits. No dependencies beyond the standard library.
"""

from __future__ import annotations

import math
import string
from collections.abc import Mapping
from typing import Any
from xml.sax.saxutils import escape

from hil.timing.checker import MS, Context, Trace, Verdict, context
from hil.timing.source import SignalSource
from hil.timing.spec import Spec

COLORS = {"pass": "#2e7d32", "fail": "#c62828", "inconclusive": "#ef8f00", "skipped": "#888"}
FILLS = {"pass": "#c8e6c9", "fail": "#ffcdd2", "inconclusive": "#ffe0b2", "skipped": "#eee"}


def _lane_of(ctx: Context, v: Verdict) -> str | None:
    """The signal a verdict constrains: its `to` event's signal or its target signal."""
    c = next((c for c in ctx.spec.constraints if c.name == v.constraint), None)
    if c is None:
        return None
    if c.kind in ("absent", "present"):
        return c.target
    ev = ctx.spec.events.get(c.target if c.kind == "forbid" else (c.to or ""))
    while ev is not None and ev.signal is None and ev.refs:
        ev = ctx.spec.events.get(ev.refs[0])
    sig = ev.signal if ev else None
    return sig.removeprefix("alarm:") if sig else None


def _range(verdicts: list[Verdict], ctx: Context, occurrence: int | None) -> tuple[int, int]:
    chosen = [v for v in verdicts if v.from_ns is not None and
              (occurrence is None or v.occurrence == occurrence)]
    bad = [v for v in chosen if v.status == "fail"]
    chosen = bad or chosen
    pts: list[int] = []
    for v in chosen:
        pts += [t for t in (v.from_ns, v.to_ns) if t is not None]
        if v.window_ms[1] is not None and v.from_ns is not None:
            pts.append(v.from_ns + int(v.window_ms[1] * MS))
    # the occurrence's trigger and the other references of its constraints stay in view: a
    # failing constraint timed from a later event must not cut off the cause (STO lost)
    occs = {v.occurrence for v in chosen}
    pts += [t for v in verdicts if v.occurrence in occs and v.status != "skipped"
            for t in (v.t_ns, v.from_ns) if t is not None]
    if not pts:
        ts = [t for n in ctx.spec.signals for t in _safe(ctx, n).times]
        pts = ts or [0, 1]
    lo, hi = min(pts), max(pts)
    pad = max((hi - lo) // 5, 2 * MS)
    return lo - pad, hi + pad


def _safe(ctx: Context, name: str) -> Trace:
    try:
        return ctx.trace(name)
    except KeyError:
        return Trace(name, [], [], 0)


def _lanes(ctx: Context) -> list[str]:
    return list(ctx.spec.signals)


def wavejson(spec: Spec, source: SignalSource, verdicts: list[Verdict],
             params: Mapping[str, Any] | None = None, binding: Mapping[str, str] | None = None,
             t_range: tuple[int, int] | None = None, occurrence: int | None = 0,
             cycles: int = 100) -> dict[str, Any]:
    """A WaveJSON dict: one lane per signal, one node lane for events, one edge per window."""
    ctx = context(spec, source, params, binding)
    lo, hi = t_range or _range(verdicts, ctx, occurrence)
    step = max((hi - lo) / cycles, 1)
    lanes: list[Any] = []
    for name in _lanes(ctx):
        tr = _safe(ctx, name)
        wave, data, last = [], [], object()
        for i in range(cycles):
            v = tr.value_at(int(lo + (i + 1) * step))
            if v is None:
                ch = "x"
            elif isinstance(v, bool):
                ch = "1" if v else "0"
            else:
                ch = "="
            if v is not None and v == last and i != 0:
                ch = "."
            elif ch == "=":
                data.append(str(v))
            wave.append(ch)
            last = v
        lane: dict[str, Any] = {"name": name, "wave": "".join(wave)}
        if data:
            lane["data"] = data
        lanes.append(lane)
    nodes = ["."] * cycles
    edges: list[str] = []
    letters = iter(string.ascii_letters)
    for v in verdicts:
        if v.from_ns is None or v.to_ns is None or (occurrence is not None and
                                                     v.occurrence != occurrence):
            continue
        a, b = (int((t - lo) / step) for t in (v.from_ns, v.to_ns))
        if not (0 <= a < cycles and 0 <= b < cycles):
            continue
        try:
            na = nodes[a] if nodes[a] != "." else next(letters)
            nodes[a] = na
            nb = nodes[b] if nodes[b] != "." else next(letters)
            nodes[b] = nb
        except StopIteration:
            break
        mark = {"pass": "✓", "fail": "✗", "inconclusive": "?"}.get(v.status, "")
        edges.append(f"{na}<->{nb} {v.measured_ms:.1f} ms {mark} {v.constraint}")
    lanes.append({"name": "events", "node": "".join(nodes)})
    return {
        "signal": lanes,
        "edge": edges,
        "head": {"text": f"{spec.id}: {spec.title}"},
        "foot": {"text": f"{spec.source} — 1 cycle = {step / MS:.3g} ms from "
                         f"t = {lo / MS:.3f} ms"},
        "config": {"hscale": 1},
    }


def nice_ticks(a: float, b: float, n: int = 8) -> list[float]:
    """Round tick values (1, 2 or 5 x 10^k apart) covering [a, b], about `n` of them."""
    span = b - a
    if not span > 0:
        return [a]
    raw = span / n
    mag = 10 ** math.floor(math.log10(raw))
    step = next(m * mag for m in (1, 2, 5, 10) if m * mag >= raw)
    first = math.ceil(a / step) * step
    out = []
    k = 0
    while first + k * step <= b + step * 1e-9:
        out.append(round(first + k * step, 12))
        k += 1
    return out


def _tick_label(v: float) -> str:
    return f"{v:.6g}" if abs(v) >= 1e-9 else "0"


def main_lanes(spec: Spec, verdicts: list[Verdict], ctx: Context | None = None
               ) -> tuple[list[str], list[str]]:
    """(the manual's signals, helper signals) of a diagram: recorded signals (a topic field,
    a DI/DO function or line, an alarm) and any signal a shown verdict constrains come
    first; signals a spec derives from others (thresholds, combinations) are helpers."""
    constrained = set()
    if ctx is not None:
        constrained = {lane for v in verdicts if (lane := _lane_of(ctx, v))}
    main, helpers = [], []
    for name, sig in spec.signals.items():
        recorded = sig.kind in ("topic", "function", "line", "alarm")
        (main if recorded or name in constrained else helpers).append(name)
    return main, helpers


def svg(spec: Spec, source: SignalSource, verdicts: list[Verdict],
        params: Mapping[str, Any] | None = None, binding: Mapping[str, str] | None = None,
        t_range: tuple[int, int] | None = None, occurrence: int | None = 0,
        width: int = 960, t0: int | None = None, lanes: list[str] | None = None,
        ctx: Context | None = None, legend: bool = True) -> str:
    """A self-contained SVG timing diagram (observed signals + expected window bands).

    The time axis reads in ms from `t0` (a report passes the plan start), else from the
    start of the drawn range, with round ticks. Booleans are drawn as steps, numbers as a
    plot scaled to the lane (its range printed under its name), other values as labelled
    boxes (the label only where it fits). `lanes`: which signals (default: all), `ctx`: a
    context to share between diagrams of one spec (its traces are built once)."""
    ctx = ctx or context(spec, source, params, binding)
    lo, hi = t_range or _range(verdicts, ctx, occurrence)
    hi = max(hi, lo + 1)
    origin = lo if t0 is None else t0
    names = list(lanes) if lanes is not None else _lanes(ctx)
    shown = [v for v in verdicts if occurrence is None or v.occurrence == occurrence]
    left, right, top, lane_h = 150, 40, 40, 34
    plot_w = width - left - right
    height = top + lane_h * len(names) + 34 + (16 * len(shown) if legend else 0)

    def x(t: float) -> float:
        return left + (min(max(t, lo), hi) - lo) / (hi - lo) * plot_w

    out = [f'<svg xmlns="http://www.w3.org/2000/svg" width="{width}" height="{height}" '
           f'viewBox="0 0 {width} {height}" font-family="sans-serif" font-size="11">',
           f'<title>{escape(spec.id)}: {escape(spec.title)}</title>',
           f'<rect width="{width}" height="{height}" fill="white"/>',
           f'<text x="8" y="16" font-size="13" font-weight="bold">{escape(spec.title)}</text>',
           f'<text x="8" y="30" fill="#555">{escape(spec.source)}</text>']
    # time axis: round ticks in ms from the origin
    axis_y = top + lane_h * len(names) + 4
    out.append(f'<line x1="{left}" y1="{axis_y}" x2="{left + plot_w}" y2="{axis_y}" '
               'stroke="#333"/>')
    for v_ms in nice_ticks((lo - origin) / MS, (hi - origin) / MS):
        xt = x(origin + v_ms * MS)
        out.append(f'<line x1="{xt:.1f}" y1="{top}" x2="{xt:.1f}" y2="{axis_y}" '
                   'stroke="#eee"/>')
        out.append(f'<text x="{xt:.1f}" y="{axis_y + 14}" text-anchor="middle">'
                   f'{_tick_label(v_ms)}</text>')
    foot = ("ms from the plan start" if t0 is not None
            else f"ms from t = {lo / MS:.3f} ms")
    out.append(f'<text x="{left + plot_w}" y="{axis_y + 28}" text-anchor="end">{foot}</text>')
    row = {n: i for i, n in enumerate(names)}
    # expected windows as bands
    for v in shown:
        lane = _lane_of(ctx, v)
        if v.from_ns is None or lane not in row or v.status == "skipped":
            continue
        wlo = v.from_ns + int((v.window_ms[0] or 0) * MS)
        whi = v.from_ns + int(v.window_ms[1] * MS) if v.window_ms[1] is not None else hi
        y0 = top + row[lane] * lane_h + 2
        w = max(x(whi) - x(wlo), 2)
        out.append(f'<rect x="{x(wlo):.1f}" y="{y0}" width="{w:.1f}" height="{lane_h - 4}" '
                   f'fill="{FILLS[v.status]}" stroke="{COLORS[v.status]}" opacity="0.8">'
                   f'<title>{escape(v.message)}</title></rect>')
    # observed signals
    for name in names:
        tr = _safe(ctx, name)
        y0 = top + row[name] * lane_h
        drawn, scale = _lane(tr, x, lo, hi, y0 + 6, y0 + lane_h - 6)
        label_y = y0 + lane_h / 2 + (0 if scale else 4)
        out.append(f'<text x="8" y="{label_y:.1f}">{escape(name)}</text>')
        if scale:
            out.append(f'<text x="8" y="{label_y + 11:.1f}" fill="#777" font-size="9">'
                       f'{escape(scale)}</text>')
        out.append(drawn)
    if legend:  # verdict markers and legend
        ly = axis_y + 44
        for v in shown:
            col = COLORS[v.status]
            if v.to_ns is not None and lo <= v.to_ns <= hi:
                out.append(f'<line x1="{x(v.to_ns):.1f}" y1="{top}" x2="{x(v.to_ns):.1f}" '
                           f'y2="{axis_y}" stroke="{col}" stroke-dasharray="3,2"/>')
            out.append(f'<text x="8" y="{ly}" fill="{col}">[{v.status}] '
                       f'{escape(v.constraint)}: {escape(v.message)}</text>')
            ly += 16
    out.append("</svg>")
    return "\n".join(out)


def _lane(tr: Trace, x, lo: int, hi: int, y_hi: float, y_lo: float) -> tuple[str, str]:
    """(SVG of one lane, its value range text for a plotted number lane, else "")."""
    if not tr.times:
        return "", ""
    if all(isinstance(v, bool) for v in tr.values):
        return _steps(tr, x, lo, hi, y_hi, y_lo), ""
    if all(isinstance(v, int | float) and not isinstance(v, bool) for v in tr.values
           if v is not None):
        return _plot_lane(tr, x, lo, hi, y_hi, y_lo)
    return _boxes(tr, x, lo, hi, y_hi, y_lo), ""


def _plot_lane(tr: Trace, x, lo: int, hi: int, y_hi: float, y_lo: float
               ) -> tuple[str, str]:
    """A number lane as a held-value plot, at most four points per pixel column."""
    pts = [(max(lo, tr.times[0]), tr.value_at(max(lo, tr.times[0])))]
    pts += [(t, v) for t, v in zip(tr.times, tr.values, strict=True) if lo < t <= hi]
    pts = [(t, float(v)) for t, v in pts if v is not None]
    if not pts:
        return "", ""
    vmin, vmax = min(v for _, v in pts), max(v for _, v in pts)
    span = vmax - vmin or 1.0

    def y(v: float) -> float:
        return y_lo - (v - vmin) / span * (y_lo - y_hi)

    out = decimate(pts, x, y, held=True)
    out.append(f"{x(hi):.1f},{y(pts[-1][1]):.1f}")
    rng = f"{vmin:.6g} … {vmax:.6g}" if vmax != vmin else f"= {vmin:.6g}"
    return (f'<polyline points="{" ".join(out)}" fill="none" stroke="#1565c0" '
            'stroke-width="1.2"/>', rng)


def decimate(pts: list[tuple[int, float]], fx: Any, fy: Any, held: bool = False
             ) -> list[str]:
    """Polyline points of (t, value) samples, at most four per pixel column (first, min,
    max, last): what the eye sees of thousands of samples, in a page that stays small.
    `held`: each column starts at the value held from the previous sample (steps)."""
    cols: dict[int, list[float]] = {}
    order: list[int] = []
    prev = pts[0][1] if pts else 0.0
    for t, v in pts:
        c = int(fx(t))
        if c not in cols:
            start = prev if held else v
            cols[c] = [start, min(start, v), max(start, v), v]
            order.append(c)
        else:
            col = cols[c]
            col[1], col[2], col[3] = min(col[1], v), max(col[2], v), v
        prev = v
    out: list[str] = []
    for c in order:
        first, mn, mx, last = cols[c]
        out.append(f"{c},{fy(first):.1f}")
        if mn != mx:
            out.append(f"{c},{fy(mn):.1f} {c},{fy(mx):.1f}")
        out.append(f"{c},{fy(last):.1f}")
    return out


def _boxes(tr: Trace, x, lo: int, hi: int, y_hi: float, y_lo: float) -> str:
    """Values that are neither booleans nor numbers (states, phases) as boxes, each label
    only where its box is wide enough to hold it."""
    bounds = [t for t in tr.times if lo < t < hi]
    starts = [max(lo, tr.times[0]), *bounds]
    parts: list[str] = []
    last: Any = object()
    run_start = None
    spans: list[tuple[int, int, Any]] = []
    for t in starts:
        v = tr.value_at(t)
        if v != last:
            if run_start is not None:
                spans.append((run_start, t, last))
            run_start, last = t, v
    if run_start is not None:
        spans.append((run_start, hi, last))
    for a, b, v in spans:
        w = max(x(b) - x(a), 1)
        parts.append(f'<rect x="{x(a):.1f}" y="{y_hi:.1f}" width="{w:.1f}" '
                     f'height="{y_lo - y_hi:.1f}" fill="none" stroke="#1565c0">'
                     f'<title>{escape(str(v))}</title></rect>')
        text = escape(str(v))[:16]
        if w >= 6.5 * len(text) + 4:
            parts.append(f'<text x="{x(a) + 2:.1f}" y="{(y_hi + y_lo) / 2 + 4:.1f}">'
                         f'{text}</text>')
    return "".join(parts)


def _steps(tr: Trace, x, lo: int, hi: int, y_hi: float, y_lo: float) -> str:
    """A boolean lane as steps."""
    pts: list[str] = []
    v0 = tr.value_at(lo)
    y = y_hi if v0 else y_lo
    start = max(lo, tr.times[0])
    pts.append(f"{x(start):.1f},{y:.1f}")
    for t, v in zip(tr.times, tr.values, strict=True):
        if t <= start or t > hi:
            continue
        pts.append(f"{x(t):.1f},{y:.1f}")
        y = y_hi if v else y_lo
        pts.append(f"{x(t):.1f},{y:.1f}")
    pts.append(f"{x(hi):.1f},{y:.1f}")
    return (f'<polyline points="{" ".join(pts)}" fill="none" stroke="#1565c0" '
            'stroke-width="1.5"/>')
