"""`hil report RECORDING.mcap [-o FILE.html] [--junit FILE.xml] [--index FILE.html]`.

Exit 0 written, 2 bad input (usage, unreadable recording) or write error.
"""

from __future__ import annotations

import argparse
import os
import stat
import sys
from pathlib import Path

from hil.fileio import FileProblem, refuse_input, same_file
from hil.record.reader import Recording, RecordingError, not_hil_file
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


def _no_place_beside(recording: str) -> str | None:
    """Why the default page cannot go beside `recording` (None: it can): a pipe or a device,
    or a name in /dev, /dev/fd or /proc (`/dev/stdin` of a file) is no folder of a
    recording's own (/dev/shm is: a tmpfs)."""
    parent = Path(recording).parent.absolute()
    stream = parent in (Path("/dev"), Path("/dev/fd")) or parent.parts[1:2] == ("proc",)
    try:
        stream = stream or not stat.S_ISREG(os.stat(recording).st_mode)
    except OSError:  # not there: the reader says so
        pass
    if stream:
        return f"{recording}: a stream, not a file in a folder of its own; give -o FILE.html"
    return None


def _refuse_clobber(args: argparse.Namespace) -> None:
    """No output may be a recording it reads, nor another output of the same call."""
    if not args.output:
        for r in args.recording:
            if (why := _no_place_beside(r)) is not None:
                raise FileProblem(why)
    pages = [args.output or Path(r).with_suffix(".html") for r in args.recording]
    # a page no -o named is the default one beside its recording: said as such
    outs = [("-o" if args.output else f"page of {r}", p)
            for r, p in zip(args.recording, pages, strict=True)]
    outs += [(flag, v) for flag, v in (("--junit", args.junit), ("--index", args.index)) if v]
    for flag, out in outs:
        refuse_input(out, args.recording, flag)
        if Path(out).is_dir():  # said before any page is written, not after the first
            raise FileProblem(f"{flag} {out}: is a directory; give a file name")
    for i, (flag, out) in enumerate(outs):
        for other_flag, other in outs[i + 1:]:
            if same_file(out, other):
                if flag.startswith("page of") and other_flag.startswith("page of"):
                    raise FileProblem(f"{other}: the page of two recordings given "  # one
                                      f"({flag[8:]} and {other_flag[8:]}: one file twice?)")
                what = f"the {flag}" if flag.startswith("page of") else f"the {flag} output"
                raise FileProblem(f"{other_flag} {other}: is also {what}")


def main(args: argparse.Namespace) -> int:
    if args.output and len(args.recording) > 1:
        print("hil report: -o takes one recording", file=sys.stderr)
        return 2
    try:
        _refuse_clobber(args)
    except FileProblem as e:
        print(f"hil report: {e}", file=sys.stderr)
        return 2
    try:
        for r in args.recording:  # a readable MCAP that is no hil recording: bad input, as
            why = not_hil_file(Recording.survey(r))  # `hil check` and `hil diff` say
            if why:
                print(f"hil report: {r}: {why}", file=sys.stderr)
                return 2
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
