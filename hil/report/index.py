"""One `index.html` per run: every plan with its status, verdict counts, duration and links to
its report, recording and JUnit file (in the spirit of Robot Framework's log.html).

Read from the recordings alone, like every report: `write_index(recordings, out)`. Links are
relative to the index, so the directory can be archived or served as it is.
"""

from __future__ import annotations

import json
import os
from collections import Counter
from pathlib import Path
from urllib.parse import quote

from hil.fileio import write_text_atomic
from hil.record.reader import RecordingError
from hil.report.data import RunData, load_run, started_ns
from hil.report.html import CSS, run_info_table
from hil.terminal import html_text

esc = html_text  # control characters as \xNN, then HTML-escaped
INDEX_CSS = """
.bar{height:10px;border-radius:5px;background:#b00020;margin:0.5em 0 1em}
.bar>div{height:10px;border-radius:5px;background:#176f2c}
td.num{text-align:right;font-variant-numeric:tabular-nums}
"""




def _row(rec: Path, out_dir: Path) -> dict:
    """What the index shows of one recording (a row that says so if it is unreadable)."""

    row: dict = {"recording": rec, "plan": rec.stem, "status": "unreadable", "info": {},
                 "steps": (0, 0), "verdicts": Counter(), "duration_ms": None, "reason": ""}
    try:
        run = load_run(rec, truth=False)
    except (RecordingError, OSError) as e:
        row["reason"] = str(e)
        return row
    res = run.metadata.get("hil.result", {})
    row.update(plan=run.plan, status=run.status or "unknown", info=run.info(),
               steps=(sum(s.status == "pass" for s in run.steps if s.index >= 0),
                      sum(s.index >= 0 for s in run.steps)),
               verdicts=Counter(str(v.get("status")) for v in run.verdicts),
               reason=_reason(run, res),
               description=run.metadata.get("hil.plan", {}).get("description", ""),
               tags=_tags(run.metadata.get("hil.plan", {}).get("tags", "[]")),
               started=started_ns(run.metadata.get("hil.run", {})))
    try:  # the plan's wall time; a killed run has none ("–"), not its recorded span, which
        row["duration_ms"] = float(res["duration_ms"])  # is virtual time on that clock
    except (KeyError, ValueError):
        row["duration_ms"] = None
    return row


def _reason(run: RunData, res: dict) -> str:
    """Why a plan did not pass, in a line: the recording's own contradiction, the run's
    reason when it stopped early, else the first step that did not pass (a plan that ran to
    its end says "end of plan", which tells a reviewer nothing)."""
    if run.status == "pass":
        return ""
    if run.status_note:
        return run.status_note
    why = str(res.get("reason", ""))
    bad = run.first_failure()
    if bad is not None and why in ("", "end of plan"):
        text = f"step {bad.index + 1} {bad.label} {bad.status}"
        return f"{text}: {bad.message}"[:300] if bad.message else text
    return why


def _link(target: Path, out_dir: Path, text: str) -> str:
    if not target.exists():
        return ""
    href = Path(os.path.relpath(target.resolve(), out_dir.resolve())).as_posix()
    # percent-encoded: a `#`, `%`, `?` or space in a file name is part of the name
    return f"<a href='{esc(quote(href))}'>{esc(text)}</a>"


def _merged_info(rows: list[dict]) -> dict[str, str]:
    """The run's identity; a field that differs between plans lists every value."""
    out = {}
    for k in ("date", "hil", "host", "bench", "clock", "git", "dut"):
        vals = sorted({r["info"].get(k, "?") for r in rows if r["info"]})
        if k == "date" and vals:
            vals = [vals[0]]  # the run started with its first plan
        out[k] = ", ".join(vals) or "?"
    return out


def render_index(recordings: list[str | Path], out: str | Path) -> str:
    out_dir = Path(out).parent
    rows = [_row(Path(r), out_dir) for r in recordings]
    passed = sum(r["status"] == "pass" for r in rows)
    total_ms = sum(r["duration_ms"] or 0 for r in rows)
    st = "pass" if rows and passed == len(rows) else "fail"
    h = ["<!DOCTYPE html><html><head><meta charset='utf-8'>",
         f"<title>hil run: {passed}/{len(rows)} plans passed</title>"
         f"<style>{CSS}{INDEX_CSS}</style></head><body>",
         f"<h1>hil run <span class='badge b-{st}'>{passed}/{len(rows)} PASSED</span></h1>",
         run_info_table(_merged_info(rows)),
         f"<div class='bar' title='{passed} of {len(rows)} plans passed'><div style='width:"
         f"{100 * passed / max(len(rows), 1):.1f}%'></div></div>",
         "<table id='plans'><tr><th>plan</th><th>status</th><th>steps passed</th>"
         "<th>verdicts pass / fail / inconclusive</th><th>duration</th><th>files</th></tr>"]
    for r in rows:
        rec = r["recording"]
        vc = r["verdicts"]
        dur = f"{r['duration_ms'] / 1000:.2f} s" if r["duration_ms"] is not None else "–"
        links = " · ".join(x for x in (
            _link(rec.with_suffix(".html"), out_dir, "report"),
            _link(rec, out_dir, "recording"),
            _link(rec.with_suffix(".junit.xml"), out_dir, "junit")) if x)
        title = _link(rec.with_suffix(".html"), out_dir, r["plan"]) or esc(r["plan"])
        note = f"<br><small>{esc(r.get('description') or '')}</small>"
        if r["reason"]:
            note += f"<br><small class='fail'>{esc(r['reason'])}</small>"
        h.append(f"<tr class='plan'><td>{title}{note}</td>"
                 f"<td class='{esc(r['status'])}'>{esc(r['status'].upper())}</td>"
                 f"<td class='num'>{r['steps'][0]}/{r['steps'][1]}</td>"
                 f"<td class='num'>{vc['pass']} / {vc['fail']} / {vc['inconclusive']}</td>"
                 f"<td class='num'>{dur}</td><td>{links}</td></tr>")
    h.append(f"<tr><th>total</th><th>{passed}/{len(rows)}</th><th></th><th>"
             f"{sum(r['verdicts']['pass'] for r in rows)} / "
             f"{sum(r['verdicts']['fail'] for r in rows)} / "
             f"{sum(r['verdicts']['inconclusive'] for r in rows)}</th>"
             f"<th>{total_ms / 1000:.2f} s</th><th>"
             + _link(out_dir / "junit.xml", out_dir, "junit.xml (all plans)") + "</th></tr>")
    h.append("</table>")
    h += _by_tag(rows) + _history(rows, out_dir)
    h.append("</body></html>\n")
    return "\n".join(h)


def _tags(text: str) -> list[str]:
    try:
        tags = json.loads(text)
    except (ValueError, RecursionError):  # nested past the stack: no tags
        return []
    return [str(t) for t in tags] if isinstance(tags, list) else []


def _by_tag(rows: list[dict]) -> list[str]:
    """Statistics by tag, as Robot Framework's log shows them: plans, passed, failed, other."""
    stats: dict[str, Counter] = {}
    for r in rows:
        for tag in r.get("tags") or ["(no tag)"]:
            c = stats.setdefault(tag, Counter())
            c["plans"] += 1
            c[r["status"] if r["status"] in ("pass", "fail") else "other"] += 1
    if not stats:
        return []
    h = ["<h2>Statistics by tag</h2><table id='tags'><tr><th>tag</th><th>plans</th>"
         "<th>pass</th><th>fail</th><th>other</th></tr>"]
    for tag in sorted(stats):
        c = stats[tag]
        h.append(f"<tr><td>{esc(tag)}</td><td class='num'>{c['plans']}</td>"
                 f"<td class='num pass'>{c['pass']}</td><td class='num fail'>{c['fail']}</td>"
                 f"<td class='num'>{c['other']}</td></tr>")
    h.append("</table>")
    return h


def _history(rows: list[dict], out_dir: Path) -> list[str]:
    """With recordings of several runs (`hil report --index` over several run folders), each
    plan's status per run, oldest run first."""
    def first(d: Path) -> tuple[int, str]:  # when the run started (then its folder's name)
        return (min((r.get("started", 0) for r in rows
                     if r["recording"].resolve().parent == d), default=0), str(d))

    runs = sorted({r["recording"].resolve().parent for r in rows}, key=first)
    if len(runs) < 2:
        return []
    status = {(r["plan"], r["recording"].resolve().parent): r for r in rows}
    plans = sorted({r["plan"] for r in rows})
    h = ["<h2>History across runs</h2><table id='history'><tr><th>plan</th>"
         + "".join(f"<th>{esc(os.path.relpath(d, out_dir.resolve()))}</th>" for d in runs)
         + "</tr>"]
    for p in plans:
        cells = []
        for d in runs:
            r = status.get((p, d))
            cells.append("<td>–</td>" if r is None else
                         f"<td class='{esc(r['status'])}'>"
                         + (_link(r["recording"].with_suffix(".html"), out_dir,
                                  r["status"].upper()) or esc(r["status"].upper())) + "</td>")
        h.append(f"<tr><td>{esc(p)}</td>{''.join(cells)}</tr>")
    h.append("</table>")
    return h


def write_index(recordings: list[str | Path], out: str | Path) -> Path:
    out = Path(out)
    out.parent.mkdir(parents=True, exist_ok=True)
    write_text_atomic(out, render_index(recordings, out))
    return out
