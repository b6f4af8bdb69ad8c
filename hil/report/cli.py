"""`hil report RECORDING.mcap [-o FILE.html] [--junit FILE.xml] [--index FILE.html]`.

Exit 0 written, 2 bad input (usage, unreadable recording) or write error.
"""

from __future__ import annotations

import argparse
import sys
from pathlib import Path

from hil.record.reader import RecordingError
from hil.report.html import write_html
from hil.report.index import write_index
from hil.report.junit import write_junit


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", nargs="+", help="MCAP recording(s) of plan runs")
    parser.add_argument("-o", "--output", help="HTML file (one recording only; default: "
                        "beside the recording, .html)")
    parser.add_argument("--junit", help="also write JUnit XML of all recordings to this file")
    parser.add_argument("--index", metavar="FILE", help="also write an index page listing "
                        "every recording (status, verdicts, duration, links)")


def main(args: argparse.Namespace) -> int:
    if args.output and len(args.recording) > 1:
        print("hil report: -o takes one recording", file=sys.stderr)
        return 2
    try:
        for r in args.recording:
            out = write_html(r, args.output)
            print(out)
        if args.junit:
            print(write_junit(args.recording, Path(args.junit)))
        if args.index:
            print(write_index(args.recording, args.index))
    except RecordingError as e:  # not a readable recording: bad input, like every command
        print(f"hil report: {e}", file=sys.stderr)
        return 2
    except OSError as e:
        print(f"hil report: cannot write: {e}", file=sys.stderr)
        return 2
    return 0
