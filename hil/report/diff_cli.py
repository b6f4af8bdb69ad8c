"""`hil diff A.mcap B.mcap [-o FILE.html] [--json FILE.json]`: the same plan recorded twice,
aligned step by step (hil.report.diff).

Exit 0 written (differences or not), 2 bad input (unreadable recording) or write error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.record.reader import RecordingError
from hil.report.diff import write_diff


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("a", metavar="A.mcap", help="reference recording")
    parser.add_argument("b", metavar="B.mcap", help="recording compared with A")
    parser.add_argument("-o", "--output", help="HTML file (default: B's name + .diff.html)")
    parser.add_argument("--json", help="JSON file (default: the HTML name with .json)")


def main(args: argparse.Namespace) -> int:
    out = Path(args.output) if args.output else Path(args.b).with_suffix(".diff.html")
    try:
        d, html_out, json_out = write_diff(args.a, args.b, out, args.json)
    except RecordingError as e:
        print(f"hil diff: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"hil diff: cannot write: {e}", file=sys.stderr)
        return 2
    for e in d["explanations"]:
        print(f"{e['what']}: A {e['a_ms']} ms, B {e['b_ms']} ms (delta {e['delta_ms']} ms) "
              f"-> {e['option']} ~ {e['estimate']} ms")
    moved = sum(s["differs"] for s in d["signals"])
    print(f"{moved} signal(s) with edges that differ, "
          f"{sum(v['delta_ms'] not in (None, 0) for v in d['verdicts'])} verdict(s) measured "
          f"differently, {len(d['states'])} state sequence(s) differ")
    print(html_out)
    print(json_out)
    return 0
