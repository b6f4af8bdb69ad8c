"""The report's "Capture / latch" section: each judged edge of a `latch` step with the true
position, the captured value, the error and its uncertainty in counts (docs/capture.md)."""

from __future__ import annotations

from html import escape as esc
from typing import Any

LATCH_SPEC = "latch"


def _num(x: Any, fmt: str) -> str:
    if isinstance(x, int | float) and x == x:  # not NaN
        return format(x, fmt)
    return "-"


def latch_html(run: Any, status_html: Any = None) -> list[str]:
    """The section's HTML lines ([] when the run has no latch verdicts)."""
    status_html = status_html or (lambda s: f'<span class="{esc(s)}">{esc(s.upper())}</span>')
    rows = [v for v in run.verdicts if v.get("spec") == LATCH_SPEC]
    if not rows:
        return []
    h = ["<h2>Capture / latch: captured position vs ground truth</h2>",
         "<table><tr><th>step</th><th>edge</th><th>status</th><th>true [counts]</th>"
         "<th>captured</th><th>error [counts]</th><th>± uncertainty</th><th>tolerance</th>"
         "<th>width</th><th>message</th></tr>"]
    for v in rows:
        lt = v.get("latch") or {}
        step = v.get("step")
        step_s = f"{int(step) + 1}" if isinstance(step, int) else ""
        h.append(f"<tr><td>{step_s}</td><td>{esc(str(lt.get('index', '')))}</td>"
                 f"<td>{status_html(str(v.get('status', '')))}</td>"
                 f"<td>{_num(lt.get('true_counts'), '.1f')}</td>"
                 f"<td>{esc(str(lt.get('captured', '-')))}</td>"
                 f"<td><b>{_num(lt.get('error_counts'), '+.1f')}</b></td>"
                 f"<td>{_num(lt.get('uncertainty_counts'), '.1f')}</td>"
                 f"<td>±{_num(v.get('tolerance_counts'), 'g')}</td>"
                 f"<td>{_num(lt.get('width_counts'), '.0f')}</td>"
                 f"<td>{esc(str(v.get('message', '')))}</td></tr>")
    h.append("</table>")
    return h
