"""A self-contained HTML report rendered from a recording alone (no external assets).

Sections: summary, steps and timing verdicts (each with a window bar: expected window and
observed value), the timing diagrams of every checked spec (`hil.timing.render.svg`: the
observed signals with the expected windows on them, redrawn from the recording), a plot of
position / velocity / torque from the virtual bench's ground truth,
the safe-state actions, the bus log of each failing step, parameters, bench and plan files.
"""

from __future__ import annotations

import json
import os
from collections.abc import Mapping
from dataclasses import fields
from pathlib import Path
from typing import Any
from urllib.parse import quote

from hil.fileio import write_text_atomic
from hil.record import topics
from hil.record.reader import virtual_bench
from hil.report.data import RunData, TruthSamples, bus_around, bus_log, load_run
from hil.report.latch_html import LATCH_SPEC, latch_html
from hil.terminal import html_text
from hil.timing.checker import Verdict, context, spec_topics, state_fields
from hil.timing.registry import load_specs
from hil.timing.render import decimate, main_lanes, nice_ticks, svg
from hil.timing.source import RecordingSource

CSS = """
body{font:14px/1.4 system-ui,sans-serif;margin:1.5em;color:#222;max-width:1200px}
h1{font-size:1.5em}h2{font-size:1.15em;margin-top:1.6em;border-bottom:1px solid #ccc}
table{border-collapse:collapse;width:100%}td,th{border:1px solid #ddd;padding:3px 6px;
text-align:left;vertical-align:top}th{background:#f3f3f3}
.pass{color:#176f2c;font-weight:600}.fail,.error,.aborted,.incomplete{color:#b00020;font-weight:600}
.inconclusive{color:#a06000;font-weight:600}.skipped{color:#777}
pre{background:#f7f7f7;padding:8px;overflow:auto;font-size:12px}
pre.bus{white-space:pre-wrap;overflow-wrap:anywhere}.nav{font-size:13px;margin:0 0 .5em}
.badge{display:inline-block;padding:2px 10px;border-radius:10px;color:#fff}
.b-pass{background:#176f2c}.b-fail,.b-error,.b-aborted,.b-incomplete{background:#b00020}
.b-inconclusive{background:#a06000}.b-unknown{background:#777}
svg{background:#fff;border:1px solid #ddd}
.diagram{overflow-x:auto}.runinfo td{border:none;padding:1px 12px 1px 0}
pre b{background:#fde2e4}figure{margin:0.8em 0}figcaption{font-weight:600;margin:0.3em 0}
details>summary{cursor:pointer;color:#1565c0}.filter{font-size:13px;margin:.4em 0}
.diagram.zoom svg{width:2400px;height:auto}.diagram svg{max-width:100%;height:auto}
"""

# Inline and offline (no CDN): filter the verdict table by status, zoom a diagram on click.
JS = """
function hilFilter(box){var want=box.value;document.querySelectorAll('tr.v').forEach(
function(r){r.style.display=(!want||r.dataset.status===want)?'':'none';});
document.querySelectorAll('details.verdicts').forEach(function(d){d.open=true;});}
function hilFind(box){var q=box.value.toLowerCase();document.querySelectorAll('tr.s').forEach(
function(r){r.style.display=(!q||r.textContent.toLowerCase().indexOf(q)>=0)?'':'none';});}
document.addEventListener('click',function(e){var d=e.target.closest('.diagram');
if(d&&!e.target.closest('details')){d.classList.toggle('zoom');}});
"""
esc = html_text  # control characters as \xNN, then HTML-escaped


def _status(s: str) -> str:
    return f'<span class="{esc(s)}">{esc(s.upper())}</span>'


def _ms(value: object) -> str:
    """A measured interval for the table: 3 decimals, '–' for presence/absence rules."""
    if isinstance(value, int | float) and not isinstance(value, bool):
        return f"{value:.3f} ms"
    return "–"


def _window_svg(v: dict) -> str:
    """Expected window (green band) and observed value (marker, with its uncertainty)."""
    lo, hi = ([*list(v.get("window_ms") or [None, None]), None, None])[:2]
    m = v.get("measured_ms")
    unc = v.get("uncertainty_ms") or [0, 0]
    vals = [x for x in (lo, hi, m) if isinstance(x, int | float)]
    if not vals:
        return ""
    top = max(vals) * 1.25 + 1
    W, H, pad = 360, 34, 10

    def x(val: float) -> float:
        return pad + (W - 2 * pad) * max(0.0, val) / top

    parts = [f'<svg width="{W}" height="{H}" viewBox="0 0 {W} {H}" '
             'xmlns="http://www.w3.org/2000/svg">',
             f'<line x1="{pad}" y1="24" x2="{W - pad}" y2="24" stroke="#999"/>']
    a = x(lo if isinstance(lo, int | float) else 0)
    b = x(hi if isinstance(hi, int | float) else top)
    parts.append(f'<rect x="{a:.1f}" y="8" width="{max(1.0, b - a):.1f}" height="16" '
                 'fill="#cdeccf" stroke="#176f2c"><title>expected window</title></rect>')
    if isinstance(m, int | float):
        color = {"pass": "#176f2c", "fail": "#b00020"}.get(v.get("status", ""), "#a06000")
        ul, uh = x(m - (unc[0] or 0)), x(m + (unc[1] or 0))
        parts.append(f'<line x1="{ul:.1f}" y1="16" x2="{uh:.1f}" y2="16" stroke="{color}" '
                     'stroke-width="3"/>')
        parts.append(f'<circle cx="{x(m):.1f}" cy="16" r="4" fill="{color}">'
                     f'<title>observed {m} ms</title></circle>')
    parts.append(f'<text x="{pad}" y="33" font-size="9">0</text>'
                 f'<text x="{W - pad - 40}" y="33" font-size="9">{top:.1f} ms</text></svg>')
    return "".join(parts)


MAX_DIAGRAMS = 6  # per checked spec: failing occurrences first


def _spec_by_id(ids: set[str] | None = None) -> Mapping[str, object]:
    """The shipped specs by id; with `ids`, only the files named so (a spec's file is named
    by its id), all of them when one is not found that way."""
    if ids:
        from hil.timing.registry import load_spec_cached
        from hil.timing.spec import SpecError, shipped_specs

        out: dict[str, object] = {}
        for path in shipped_specs():
            if path.stem in ids:
                try:
                    spec = load_spec_cached(path)
                except SpecError:
                    continue
                out[spec.id] = spec
        if ids <= set(out):
            return out
    return load_specs()


def timing_diagrams(run: RunData, source: Any = None) -> list[tuple[str, str]]:
    """(title, svg) per checked spec and occurrence: the observed signals with the expected
    windows drawn on them (`hil.timing.render.svg`), from the recording alone. A spec that
    cannot be redrawn (unknown id, unreadable recording) gives a note instead of a diagram.
    `source`: the recording as a timing source already (the plan's `LiveSource`, over the
    recorder's messages of the whole file), instead of reading the file for it."""

    groups: dict[tuple[str, object], list[dict]] = {}
    for v in run.verdicts:
        if v.get("spec") == LATCH_SPEC:
            continue  # no diagram: the latch section shows its figures
        groups.setdefault((str(v.get("spec", "")), v.get("step")), []).append(v)
    if not groups:
        return []
    out: list[tuple[str, str]] = []
    try:
        specs = _spec_by_id({sid for sid, _step in groups})
        wanted: set[str] = set()  # decode only what the diagrams draw from
        for (sid, _step), vds in groups.items():
            spec = specs.get(sid)
            if spec is not None:
                wanted |= spec_topics(spec, vds[0].get("binding") or None)
        if source is None:
            # the drive state the report already decoded is shared, not decoded twice,
            # unless a spec reads a state field the report did not keep (truth_fields)
            kept = run.truth_fields
            full = kept is not None and any(not state_fields(s) <= kept
                                            for s in specs.values())
            shared = ({} if full else
                      {topics.drive_state(d): msgs for d, msgs in run.truth.items()})
            source = RecordingSource(run.path, topics=sorted(wanted - set(shared)),
                                     at_rest=True)
            for topic, msgs in shared.items():
                if topic in wanted:
                    source.put_table(topic, msgs.table)
    except Exception as e:  # a truncated or foreign recording: the table still stands
        return [("timing diagrams", f"<p>Diagrams not drawn: {esc(str(e))}</p>")]
    names = {f.name for f in fields(Verdict)}
    # one context per spec, binding and parameters: the checks of one spec at several steps
    # (a homing spec after each homing) draw from the same traces, built once
    contexts: dict[str, Any] = {}
    for (sid, step), vds in groups.items():
        spec = specs.get(sid)
        label = f"{sid}" + (f" (step {int(step) + 1})" if isinstance(step, int) else "")
        if spec is None:
            out.append((label, f"<p>No timing spec {esc(sid)} here: diagram not drawn.</p>"))
            continue
        verdicts = []
        for vd in vds:
            kw = {k: vd[k] for k in names if k in vd}
            kw["uncertainty_ms"] = tuple(kw.get("uncertainty_ms") or (0.0, 0.0))
            kw["window_ms"] = tuple(kw.get("window_ms") or (None, None))
            verdicts.append(Verdict(**kw))
        occs = sorted({v.occurrence for v in verdicts},
                      key=lambda o: (not any(v.status == "fail" and v.occurrence == o
                                             for v in verdicts), o))
        binding = vds[0].get("binding") or None
        params = vds[0].get("check_params") or None
        key = json.dumps([sid, binding, params], sort_keys=True, default=repr)
        try:  # its traces are built once for every diagram drawn from it
            ctx = contexts.get(key)
            if ctx is None:
                ctx = contexts[key] = context(spec, source, params, binding)
        except Exception as e:
            out.append((label, f"<p>Diagram not drawn: {esc(type(e).__name__)}: "
                               f"{esc(str(e))}</p>"))
            continue
        for occ in occs[:MAX_DIAGRAMS]:
            chosen = [v for v in verdicts if v.occurrence == occ]
            try:
                main, helpers = main_lanes(spec, chosen, ctx)
                pic = svg(spec, source, chosen, occurrence=None, width=1100, t0=run.t0,
                          lanes=main, ctx=ctx)
                if helpers:
                    pic += (f"<details><summary>{len(helpers)} helper signals of the spec"
                            "</summary>" + svg(spec, source, chosen, occurrence=None,
                                               width=1100, t0=run.t0, lanes=helpers, ctx=ctx,
                                               legend=False) + "</details>")
            except Exception as e:
                pic = f"<p>Diagram not drawn: {esc(type(e).__name__)}: {esc(str(e))}</p>"
            out.append((f"{label}, occurrence {occ + 1}", pic))
        if len(occs) > MAX_DIAGRAMS:
            out.append((f"{label}: {len(occs) - MAX_DIAGRAMS} more occurrences",
                        "<p>Not drawn (see the verdict table).</p>"))
    return out


def _plot(run: RunData, drive: str, samples: TruthSamples) -> str:
    """Inline SVG: position, velocity and torque against time, one panel each."""
    keys = [("position (counts)", ("position_counts", "position", "pos")),
            ("velocity (rpm)", ("speed_rpm", "velocity", "vel")),
            ("torque (%)", ("torque_pct", "torque"))]
    series = []
    times = samples.table.times
    for label, names in keys:
        pts = []
        cols = [c for c in (samples.column(n) for n in names) if c is not None]  # drawn only
        for i, t in enumerate(times):
            for c in cols:
                v = c[i]
                if isinstance(v, int | float) and not isinstance(v, bool):
                    pts.append((t, float(v)))
                    break
        if pts:
            series.append((label, pts))
    if not series:
        return "<p>No ground truth (position/velocity/torque) in this recording.</p>"
    t0 = min(p[0][0] for _, p in series)
    t1 = max(p[-1][0] for _, p in series)
    span = max(t1 - t0, 1)
    zero = run.t0 or t0  # axis labels: ms from the plan start
    W, PH, pad = 900, 110, 50
    out = [f'<svg width="{W}" height="{PH * len(series) + 34}" xmlns="http://www.w3.org/2000/svg">']
    for i, (label, pts) in enumerate(series):
        y0 = i * PH + 10
        lo = min(v for _, v in pts)
        hi = max(v for _, v in pts)
        if hi == lo:  # a flat signal: drawn mid-panel between two labels that differ
            half = max(1.0, abs(hi) * 0.1)  # (it read "0" above "0", the line on the floor)
            lo, hi = lo - half, hi + half
        rng = hi - lo
        coords = " ".join(decimate(pts, lambda t: pad + (W - pad - 10) * (t - t0) / span,
                                   lambda v, y0=y0, lo=lo, rng=rng:
                                   y0 + PH - 20 - (PH - 30) * (v - lo) / rng))
        out.append(f'<text x="4" y="{y0 + 12}" font-size="11">{esc(label)}</text>'
                   f'<text x="4" y="{y0 + 26}" font-size="9">{hi:.4g}</text>'
                   f'<text x="4" y="{y0 + PH - 20}" font-size="9">{lo:.4g}</text>'
                   f'<rect x="{pad}" y="{y0}" width="{W - pad - 10}" height="{PH - 20}" '
                   'fill="none" stroke="#ddd"/>'
                   f'<polyline points="{coords}" fill="none" stroke="#1f5fbf" '
                   'stroke-width="1.2"/>')
    for v_ms in nice_ticks((t0 - zero) / 1e6, (t1 - zero) / 1e6, 6):
        xt = pad + (W - pad - 10) * (zero + v_ms * 1e6 - t0) / span
        out.append(f'<text x="{xt:.1f}" y="{PH * len(series) + 14}" '
                   f'font-size="10" text-anchor="middle">{v_ms:.6g}</text>')
    out.append(f'<text x="{W - 10}" y="{PH * len(series) + 28}" font-size="10" '
               'text-anchor="end">ms from the plan start</text></svg>')
    return "".join(out)


def run_info_table(info: dict[str, str]) -> str:
    """Run date, hil version, host, bench, clock, git revision and the drives under test."""
    dev = info.get("deviations")
    return ("<table class='runinfo' style='width:auto'><tr>" + "".join(
        f"<td><small>{esc(k)}</small><br><b>{esc(info.get(k, '?'))}</b></td>"
        for k in ("date", "hil", "host", "bench", "clock", "git", "dut"))
        + (f"<td class='fail'><small>deviation knobs (a deliberately wrong drive)</small><br>"
           f"<b>{esc(dev)}</b></td>" if dev else "") + "</tr></table>")


def _step_name(run: RunData, index: object) -> str:
    """`3: wait_until DO BRKR on` for a verdict's step index."""
    st = run.step(index)
    if st is None:
        return "–" if index is None else esc(str(index))
    return f"<a href='#step-{st.index + 1}'>{st.index + 1}</a>: {esc(st.label)}"


def _nav(run: RunData, out: Path | None, index: bool | None = None) -> str:
    """Links from a plan page to the run's index and to its recording. `index`: whether an
    index.html is (or will be, as `hil run` writes it after its plans) beside the page; None:
    whether one is there now."""
    if out is None:
        return ""
    here = out.resolve().parent
    links = []
    if index if index is not None else (here / "index.html").exists():
        links.append("<a href='index.html'>&larr; all plans of this run</a>")
    rec = Path(run.path).resolve()
    href = Path(os.path.relpath(rec, here)).as_posix()
    links.append(f"<a href='{esc(quote(href))}' download>recording {esc(rec.name)}</a> (open it in "
                 "Foxglove)")
    return "<p class='nav'>" + " · ".join(links) + "</p>"


def render_html(run: RunData, out: Path | None = None, index: bool | None = None,
                source: Any = None) -> str:
    """One plan's report: steps, timing verdicts and diagrams, motion, safe state, bus logs
    around failures, parameters, the plan and bench files and the log. `out`: where the page
    goes (its links to the index and the recording are relative to it); `index` as `_nav`;
    `source` as `timing_diagrams`'."""
    st = run.status or "unknown"
    h: list[str] = [
        "<!DOCTYPE html><html><head><meta charset='utf-8'>",
        f"<title>hil report: {esc(run.plan)}</title><style>{CSS}</style>"
        f"<script>{JS}</script></head><body>",
        _nav(run, out, index),
        f"<h1>{esc(run.plan)} <span class='badge b-{esc(st)}'>{esc(st.upper())}</span></h1>",
        run_info_table(run.info()),
        (f"<p class='first'><b>{esc(st.upper())}</b>: {esc(run.status_note)}</p>"
         if run.status_note else ""),
        _first_failure(run),
        f"<p>Recording <code>{esc(run.path)}</code>"
        + (f" · <b>recording damaged ({esc(run.damage)}): what followed could not be read"
           + ("; the repair kept the records around it" if run.metadata.get("hil.repair")
              else ", and nothing after it is shown") + "</b>" if run.damage else
           " · <b>recording cut short: its tail is lost (the run itself ended)</b>"
           if run.truncated and run.metadata.get("hil.result") else
           " · <b>recording truncated (killed run)</b>" if run.truncated else "")
        + (f" · <b>{run.bad_messages} record(s) of a wrong shape skipped: steps, verdicts "
           "or signals they held are not shown</b>" if run.bad_messages else "")
        + " · times are ms from the plan start</p>",
    ]
    h += _steps_html(run)
    h += _verdicts_html(run, source)
    for section in (latch_html, _motion_html, _safety_html, _bus_html, _files_html):
        h += section(run)
    h.append("</body></html>\n")
    return "\n".join(h)


def _first_failure(run: RunData) -> str:
    """The first step that did not pass, where it is in its plan file and why: the line a
    reviewer needs before scrolling (empty for a passing run)."""
    bad = run.first_failure()
    if bad is None:
        return ""
    where = f"{Path(bad.file).name}:{bad.line}" if bad.file and bad.line else (
        f"line {bad.line}" if bad.line else "")
    return (f"<p class='first'><b>First failure</b>: <a href='#step-{bad.index + 1}'>step "
            f"{bad.index + 1}</a> {esc(bad.label)} {_status(bad.status)}"
            + (f" ({esc(where)})" if where else "") + f": {esc(bad.message)}</p>")


def _steps_html(run: RunData) -> list[str]:
    h = ["<h2>Steps</h2><p class='filter'><input type='search' placeholder='find a step' "
         "oninput='hilFind(this)'></p><table><tr><th>#</th><th>step</th><th>line</th>"
         "<th>status</th><th>start</th><th>time</th><th>message</th></tr>"]
    for s in run.steps:
        n = s.index + 1 if s.index >= 0 else "-"
        start = f"{(s.t_start - run.t0) / 1e6:.1f} ms" if s.t_start is not None else ""
        h.append(f"<tr class='s' id='step-{n}'><td>{n}</td><td>{esc(s.label)}</td>"
                 f"<td>{s.line or ''}</td>"
                 f"<td>{_status(s.status)}</td><td>{start}</td>"
                 f"<td>{s.duration_ns / 1e6:.1f} ms</td><td>{esc(s.message)}</td></tr>")
    h.append("</table>")
    return h


def _verdicts_html(run: RunData, source: Any = None) -> list[str]:
    h = ["<h2>Timing verdicts: expected vs observed</h2>"]
    if not run.verdicts:
        return [*h, "<p>No timing verdicts in this run.</p>"]
    counts: dict[str, int] = {}
    for v in run.verdicts:
        counts[str(v.get("status", ""))] = counts.get(str(v.get("status", "")), 0) + 1
    summary = ", ".join(f"{n} {k}" for k, n in sorted(counts.items()))
    all_pass = set(counts) <= {"pass", "skipped"}
    options = "".join(f"<option value='{esc(k)}'>{esc(k)} ({n})</option>"
                      for k, n in sorted(counts.items()))
    h.append(f"<p class='filter'>Show <select onchange='hilFilter(this)'><option value=''>"
             f"all ({len(run.verdicts)})</option>{options}</select></p>")
    # every verdict passed: folded (the count says so); anything else: open
    h.append(f"<details class='verdicts'{'' if all_pass else ' open'}><summary>"
             f"{len(run.verdicts)} verdicts: {esc(summary)}</summary>")
    h.append("<table><tr><th>step</th><th>spec</th><th>constraint</th><th>status</th>"
             "<th>measured</th><th>window</th><th>diagram</th><th>message</th></tr>")
    for group in _verdict_rows(run.verdicts):
        v = group[0]
        win = v.get("window_expr") or v.get("window_ms")
        status = str(v.get("status", ""))
        measured, message = _ms(v.get("measured_ms")), str(v.get("message", ""))
        if len(group) > 1:  # passing occurrences of one constraint: one row
            ms = [float(g["measured_ms"]) for g in group
                  if isinstance(g.get("measured_ms"), int | float)]
            if ms:
                measured = f"{min(ms):.3f} … {max(ms):.3f} ms"
            message = f"{len(group)} occurrences, all {status}; closest to its limit: {message}"
            status_cell = f"{_status(status)} ×{len(group)}"
        else:
            status_cell = _status(status)
        h.append(f"<tr class='v' data-status='{esc(status)}'>"
                 f"<td>{_step_name(run, v.get('step'))}</td>"
                 f"<td>{esc(str(v.get('spec', '')))}</td>"
                 f"<td>{esc(str(v.get('constraint', '')))}<br><small>"
                 f"{esc(str(v.get('source', '')))}</small></td>"
                 f"<td>{status_cell}</td>"
                 f"<td>{measured}</td><td>{esc(str(win))}</td>"
                 f"<td>{_window_svg(v)}</td><td>{esc(message)}</td></tr>")
    h.append("</table></details>")
    h.append("<h2>Timing diagrams: observed signals and expected windows</h2>"
             "<p class='filter'>The manual's signals; a spec's helper signals are folded "
             "under each diagram. Click a diagram to zoom it.</p>")
    for title, pic in timing_diagrams(run, source):
        h.append(f"<figure><figcaption>{esc(title)}</figcaption>"
                 f"<div class='diagram'>{pic}</div></figure>")
    return h


def _verdict_rows(verdicts: list[dict]) -> list[list[dict]]:
    """Table rows: every verdict that did not pass on its own row; the passing occurrences of
    one constraint at one step in one row, led by the one closest to its limit (smallest
    margin). Order: as recorded, by each row's first verdict."""
    rows: list[list[dict]] = []
    passing: dict[tuple, list[dict]] = {}
    for v in verdicts:
        if v.get("status") != "pass":
            rows.append([v])
            continue
        key = (v.get("step"), v.get("spec"), v.get("constraint"))
        if key not in passing:
            passing[key] = []
            rows.append(passing[key])
        passing[key].append(v)

    def margin(v: dict) -> float:
        m = v.get("margin_ms")
        return float(m) if isinstance(m, int | float) else float("inf")

    return [sorted(r, key=margin) if len(r) > 1 else r for r in rows]


def _motion_html(run: RunData) -> list[str]:
    h = ["<h2>Motion (virtual-bench ground truth)</h2>"]
    if not run.truth:
        virtual = virtual_bench(run.metadata)
        return [*h, "<p>No ground truth in this recording ("
                + ("a virtual bench's, cut or damaged before its first state sample"
                   if virtual and (run.truncated or run.damage) else
                   "a virtual bench's that recorded none" if virtual else "real bench")
                + ").</p>"]
    for d, samples in run.truth.items():
        h.append(f"<h3>{esc(d)}</h3>{_plot(run, d, samples)}")
    return h


def _safety_html(run: RunData) -> list[str]:
    h = ["<h2>Safe state</h2>"]
    if not run.safety:
        if run.damage:
            return [*h, "<p class='fail'>Safe state not seen: the recording is damaged before "
                        "it, and what followed could not be read. Check the bench.</p>"]
        if run.truncated and not run.metadata.get("hil.result"):
            return [*h, "<p class='fail'>Safe state not confirmed: the recording ends before "
                        "the run drove one (the run was killed). Check the bench.</p>"]
        return [*h, "<p>No safe-state actions recorded.</p>"]
    h.append("<table><tr><th>drive</th><th>action</th><th>ok</th><th>reason</th>"
             "<th>detail</th></tr>")
    for a in run.safety:
        h.append(f"<tr><td>{esc(str(a.get('drive', '')))}</td><td>{esc(str(a.get('action')))}"
                 f"</td><td>{_status('pass' if a.get('ok') else 'fail')}</td>"
                 f"<td>{esc(str(a.get('reason', '')))}</td>"
                 f"<td>{esc(str(a.get('detail', '')))}</td></tr>")
    h.append("</table>")
    return h


def _bus_html(run: RunData) -> list[str]:
    """The frames around each failing check, then the bus log of other failing steps."""
    h: list[str] = []
    bad = [v for v in run.verdicts if v.get("status") in ("fail", "inconclusive")]
    if bad:
        h.append("<h2>Bus log around failing checks</h2>"
                 "<p>Frames between the reference and the observed instant of each failing "
                 "constraint (highlighted), with the frames just before and after; times on "
                 "the checker's clock (each source's own stamp), as in the verdicts.</p>")
    for v in bad:
        rows = bus_around(run, v)
        h.append(f"<h3>{_step_name(run, v.get('step'))}: {esc(str(v.get('spec', '')))}: "
                 f"{esc(str(v.get('constraint', '')))} {_status(str(v.get('status')))}</h3>")
        if not rows:
            h.append("<p>No bus traffic recorded around this check.</p>")
            continue
        h.append("<pre class='bus'>" + "\n".join(
            (f"<b>{line}</b>" if inside else line)
            for t, topic, text, inside in rows
            for line in [f"{(t - run.t0) / 1e6:10.3f} ms  {esc(topic):<28} {esc(text)}"])
            + "</pre>")
    shown = {v.get("step") for v in bad}  # checks have their frames above
    failing = [s for s in run.steps if s.status not in ("pass", "skipped")
               and s.index not in shown]
    if failing:
        h.append("<h2>Bus log of failing steps</h2>")
    for s in failing:
        rows = bus_log(run, s)
        h.append(f"<h3>step {s.index + 1}: {esc(s.label)}</h3>")
        if not rows:
            h.append("<p>No bus traffic during this step.</p>")
            continue
        h.append("<pre class='bus'>" + "\n".join(
            f"{(t - run.t0) / 1e6:10.3f} ms  {esc(topic):<28} {esc(text)}"
            for t, topic, text in rows) + "</pre>")
    return h


def _files_html(run: RunData) -> list[str]:
    """Parameters, the plan and bench files as run, and the tail of the log."""
    h = ["<h2>Parameters</h2>"]
    for d, values in run.params.items():
        shown = dict(sorted(values.items()))
        h.append(f"<details><summary>{esc(d)}: {len(shown)} parameters</summary><pre>"
                 + esc("\n".join(f"{k} = {v}" for k, v in shown.items())) + "</pre></details>")
    for name in ("bench.yaml", "plan.yaml"):
        if name in run.attachments:
            h.append(f"<h2>{esc(name)}</h2><pre>{esc(run.attachments[name])}</pre>")
    if run.logs:
        h.append("<h2>Log</h2><pre>" + "\n".join(
            f"{(lg['_t'] - run.t0) / 1e6:10.3f} ms  {esc(str(lg.get('name', '')))}: "
            f"{esc(str(lg.get('message', '')))}" for lg in run.logs[-300:]) + "</pre>")
    return h


def write_html(recording: str | Path, out: str | Path | None = None,
               index: bool | None = None, messages: Any = None, source: Any = None) -> Path:
    """The plan page of `recording` to `out` (default: beside it); `index` as `_nav`;
    `messages` as `load_run`'s (the recorder's own, instead of reading the file again);
    `source` as `timing_diagrams`'."""
    run = load_run(recording, messages=messages)
    out = Path(out) if out is not None else Path(recording).with_suffix(".html")
    write_text_atomic(out, render_html(run, out, index, source))
    return out


