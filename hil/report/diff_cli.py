"""`hil diff A.mcap B.mcap [-o FILE.html] [--json FILE.json]`: the same plan recorded twice,
aligned step by step (hil.report.diff).

Exit 0 written (differences or not), 2 bad input (unreadable or not a hil recording, an
output that is one of the inputs) or write error, 4 written but a recording is damaged or cut
short (as `hil check`).
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.fileio import FileProblem, refuse_input, same_file
from hil.record.reader import (
    Recording,
    RecordingError,
    incomplete,
    not_hil_file,
    repaired_cut,
)
from hil.report.diff import write_diff


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("a", metavar="A.mcap", help="reference recording")
    parser.add_argument("b", metavar="B.mcap", help="recording compared with A")
    parser.add_argument("-o", "--output", help="HTML file (default: B's name + .diff.html)")
    parser.add_argument("--json", help="JSON file (default: the HTML name with .json)")


def _check_inputs(paths: list[str]) -> tuple[str | None, list[str]]:
    """(why an input is no hil recording, what is incomplete), with `hil check`'s reader
    checks: a non-hil MCAP is bad input, a damaged or cut recording an incomplete result."""
    partial = []
    for p in paths:
        rec = Recording.survey(p)  # channels and state, no message kept
        why = not_hil_file(rec)
        if why:
            return f"{p}: {why}", []
        cut = incomplete(p, corrupt=rec.corrupt, truncated=rec.truncated, error=rec.error,
                         footer=rec.has_footer)
        if cut:
            partial.append(cut)
        elif (why := repaired_cut(rec.metadata())) is not None:  # cut before its repair
            partial.append(f"{p}: {why}; compared as far as it goes")
    return None, partial


def main(args: argparse.Namespace) -> int:
    out = Path(args.output) if args.output else Path(args.b).with_suffix(".diff.html")
    json_out = Path(args.json) if args.json else out.with_suffix(".json")
    try:
        bad, partial = _check_inputs([args.a, args.b])
        if bad:
            raise RecordingError(bad)
        refuse_input(out, [args.a, args.b], "-o")
        refuse_input(json_out, [args.a, args.b], "--json")
        if same_file(out, json_out):  # `-o x.json` makes its JSON beside it: the same file
            how = "--json" if args.json else "the JSON output (-o's name with .json)"
            raise FileProblem(f"{how} {json_out}: is the HTML output (-o) too")
        d, html_out, json_out = write_diff(args.a, args.b, out, json_out, partial)
    except (RecordingError, FileProblem) as e:
        print(f"hil diff: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"hil diff: cannot write: {e}", file=sys.stderr)
        return 2
    if not d["same_plan"]:  # the estimates compare different scenarios: say it first
        print(f"hil diff: A ran plan {d['a']['plan']!r} and B {d['b']['plan']!r}: the "
              "differences below may come from the plans, not the drive", file=sys.stderr)
    for p, (pa, pb) in d["params"].items():
        print(f"parameter {p}: A {_v(pa)}, B {_v(pb)}")
    for o, (oa, ob) in d["options"].items():  # (recording.md: "on stdout as well")
        print(f"option {o}: A {_v(oa)}, B {_v(ob)}")
    for e in d["explanations"]:
        size = "" if e["estimate"] is None else f" ~ {e['estimate']}" + (
            "" if isinstance(e["estimate"], bool) else " ms")
        print(f"{e['what']}: A {_v(e['a_ms'])} ms, B {_v(e['b_ms'])} ms (delta "
              f"{_v(e['delta_ms'])} ms) -> {e['option']}{size} ({e['basis']})")
    moved = sum(s["differs"] for s in d["signals"])
    measured = sum(v["delta_ms"] not in (None, 0) for v in d["verdicts"])
    one_sided = sum((v["a_status"] is None) != (v["b_status"] is None) for v in d["verdicts"])
    status = sum(v["a_status"] is not None and v["b_status"] is not None
                 and v["a_status"] != v["b_status"] for v in d["verdicts"])
    print(f"{moved} signal(s) with edges that differ, {measured} verdict(s) measured "
          f"differently, {status} with another status, {one_sided} in one run only, "
          f"{len(d['states'])} state sequence(s) differ")
    print(html_out)
    print(json_out)
    for why in d.get("incomplete", ()):  # compared what the files hold; as `hil check`, 4
        print(f"hil diff: incomplete: {why}", file=sys.stderr)
    return 4 if d.get("incomplete") else 0


def _v(x: object) -> str:
    """A value on stdout: "–" where the run had none (not Python's None)."""
    return "–" if x is None else str(x)
