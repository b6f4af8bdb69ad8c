"""`hil export FILE -o OUT [-f candump|asc|blf|csv|trc|mf4] [--bus NAME]`: CAN traffic out.

The format comes from OUT's extension, the one python-can's `LogReader` reads it by: `.log`
candump (`candump -L`), `.asc`, `.blf`, `.csv`, `.trc` (PCAN), `.mf4` (ASAM MDF, with
`hil[mf4]`). `-f` names it where the extension says nothing (`-o traffic.txt -f
candump`) and must agree with a known extension. `-o -` writes a text format to stdout
(default candump); BLF and MF4 are binary and are refused there.
Exit 0 written, 2 bad input (usage, unreadable recording, unknown bus, format) or write error.
"""

from __future__ import annotations

import argparse
import io
import re
import struct
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import can

from hil.fileio import atomic_path, refuse_input
from hil.record.canio import bus_topics, stream_can
from hil.record.reader import Recording, RecordingError, before_channels

FORMATS = ("candump", "asc", "blf", "csv", "trc", "mf4")
#: OUT extension -> format (the suffixes python-can's LogReader/Logger use)
EXTENSIONS = {".log": "candump", ".asc": "asc", ".blf": "blf", ".csv": "csv", ".trc": "trc",
              ".mf4": "mf4"}
BINARY = ("blf", "mf4")  # never to stdout
CAN_ERR_FLAG = 0x20000000  # linux/can.h: error frames carry it in the id
STDOUT = "-"


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument(
        "--format",
        "-f",
        choices=FORMATS,
        default=None,
        help="output format (default: from the -o extension: .log candump, .asc, .blf, .csv, "
        ".trc (PCAN), .mf4 (ASAM MDF, needs `pip install 'hil[mf4]'`); candump for -o -)",
    )
    parser.add_argument("-o", "--output", required=True, metavar="OUT",
                        help="output file, or - for stdout (text formats only)")
    parser.add_argument("--bus", default=None, help="only this bus (default: all)")
    parser.add_argument(
        "--time",
        choices=("log", "publish"),
        default="log",
        help="timestamps from log_time (the harness's, the default) or publish_time (the "
             "source's; hil check judges on publish_time)",
    )


def output_format(output: str, fmt: str | None) -> str:
    """The format to write `output` in; ValueError with the reason when it cannot be told or
    contradicts the file name."""
    if output == STDOUT:
        fmt = fmt or "candump"
        if fmt in BINARY:
            raise ValueError(f"-o -: {fmt.upper()} is binary and is not written to stdout; give "
                             f"a .{fmt} file")
        return fmt
    ext = Path(output).suffix.lower()
    by_ext = EXTENSIONS.get(ext)
    known = ", ".join(f"{e} ({f})" for e, f in EXTENSIONS.items())
    if fmt is None:
        if by_ext is None:
            raise ValueError(f"-o {output}: cannot tell the format from {ext or 'no extension'!r}"
                             f"; use one of {known}, or give -f")
        fmt = by_ext
    elif by_ext is not None and by_ext != fmt:
        raise ValueError(f"-o {output} names a {by_ext} file but -f is {fmt}; "
                         f"python-can would read it as {by_ext} (extensions: {known})")
    if fmt == "mf4":
        try:
            import asammdf  # noqa: F401  (python-can's MF4Writer needs it)
        except ImportError:
            raise ValueError(f"-o {output}: MF4 needs the asammdf package: "
                             "pip install 'hil[mf4]'") from None
    return fmt


class _KeepOpen(io.TextIOWrapper):
    """stdout for a python-can writer: its `stop()` closes the file; this only flushes."""

    def close(self) -> None:
        self.flush()


_IFNAME = re.compile(r"[^A-Za-z0-9_.:@-]")


def candump_line(bus: str, msg: can.Message) -> str:
    """One `candump -L` line: `(1700000000.123456) can0 123#DEADBEEF`. The bus name is an
    interface token there: a character outside `A-Za-z0-9_.:@-` (a space would split the
    line, an escape sequence would reach a terminal) becomes `_`."""
    bus = _IFNAME.sub("_", bus) or "_"
    cid = msg.arbitration_id
    if msg.is_error_frame:
        ident = f"{cid | CAN_ERR_FLAG:08X}"
    elif msg.is_extended_id:
        ident = f"{cid:08X}"
    else:
        ident = f"{cid:03X}"
    data = bytes(msg.data).hex().upper()
    if msg.is_fd:
        flags = (1 if msg.bitrate_switch else 0) | (2 if msg.error_state_indicator else 0)
        body = f"{ident}##{flags:X}{data}"
    elif msg.is_remote_frame:
        body = f"{ident}#R{msg.dlc if msg.dlc else ''}"
    else:
        body = f"{ident}#{data}"
    return f"({msg.timestamp:.6f}) {bus} {body}"


def write_candump(feed: Callable[[Callable[[str, can.Message], None]], Any], out: TextIO) -> int:
    """candump -L lines of what `feed(on_frame)` hands over."""
    n = 0

    def on_frame(bus: str, msg: can.Message) -> None:
        nonlocal n
        out.write(candump_line(bus, msg) + "\n")
        n += 1

    feed(on_frame)
    return n


#: frames a format's python-can writer drops with only a warning on its logger (TRCWriter):
#: counted here as not exported (helper-137: an export of a recording with guarding RTRs
#: said every frame was written)
CANNOT_CARRY = {"trc": (("is_error_frame", "error frames"), ("is_remote_frame", "remote frames"),
                        ("is_fd", "CAN FD frames"))}


def _write_can(fmt: str, target: Any, feed: Callable[[Callable[[str, can.Message], None]], Any],
               left_out: dict[str, int] | None = None) -> int:
    """Write what `feed(on_frame)` hands over with python-can's writer for `fmt` (asc, blf,
    csv, trc, mf4) to `target`; returns the frames written. A frame the format cannot carry
    (`CANNOT_CARRY`, a time BLF cannot encode) is not written and counted in `left_out`
    ({why: how many})."""
    writer = {"asc": can.ASCWriter, "blf": can.BLFWriter, "csv": can.CSVWriter,
              "trc": can.TRCWriter, "mf4": can.MF4Writer}[fmt](target)
    cannot = CANNOT_CARRY.get(fmt, ())
    left = {} if left_out is None else left_out
    n = 0

    def on_frame(_bus: str, msg: can.Message) -> None:
        nonlocal n
        for attr, what in cannot:
            if getattr(msg, attr):
                why = f"python-can's {fmt.upper()} writer cannot carry {what}"
                left[why] = left.get(why, 0) + 1
                return
        times = (getattr(writer, "start_timestamp", None), getattr(writer, "stop_timestamp", None))
        try:
            writer.on_message_received(msg)
        except (struct.error, OverflowError):  # BLF: a time out of its range
            if hasattr(writer, "stop_timestamp"):  # the file's start and end times stay those
                writer.start_timestamp, writer.stop_timestamp = times  # of the frames written
            why = f"the {fmt.upper()} format cannot carry their times"
            left[why] = left.get(why, 0) + 1
            return
        n += 1

    try:
        feed(on_frame)
    finally:
        writer.stop()
    return n


def main(args: argparse.Namespace) -> int:
    output = str(args.output)
    try:
        fmt = output_format(output, args.format)
    except ValueError as exc:
        print(f"hil export: {exc}", file=sys.stderr)
        return 2
    try:
        if output != STDOUT:
            refuse_input(output, [args.file], "-o")
        # the recording's buses and state first (a bad --bus or file is said before any
        # output exists), then its frames a message at a time: never held whole
        head = Recording.survey(args.file)
        buses = bus_topics(head, args.bus)
    except (RecordingError, ValueError) as exc:
        print(f"hil export: {exc}", file=sys.stderr)
        return 2
    if empty := before_channels(head.truncated, head.corrupt, len(head.channels())):
        print(f"hil export: {args.file}: {empty}: nothing to export", file=sys.stderr)
        return 2
    if not buses:  # no empty file for a recording without CAN traffic (helper-137)
        print(f"hil export: {args.file}: no CAN bus recorded"
              f"{' before its damage' if head.truncated else ''}: nothing to export",
              file=sys.stderr)
        return 2
    if head.truncated:
        print(
            f"hil export: {args.file} is "
            f"{'damaged' if head.corrupt else 'truncated'} ({head.error or 'no footer'}); "
            "exporting what is readable",
            file=sys.stderr,
        )

    def feed(on_frame: Callable[[str, can.Message], None]) -> None:
        stream_can(args.file, args.bus, on_frame, time=args.time, head=head)

    to_stdout = output == STDOUT
    left_out: dict[str, int] = {}
    try:
        if fmt == "candump":
            if to_stdout:
                n = write_candump(feed, sys.stdout)
                sys.stdout.flush()
            else:
                with atomic_path(output) as tmp, open(tmp, "w", encoding="ascii") as f:
                    n = write_candump(feed, f)
        elif to_stdout:
            n = _write_can(fmt, _KeepOpen(sys.stdout.buffer, encoding="utf-8",
                                          write_through=True), feed, left_out)
        else:
            with atomic_path(output) as tmp:  # a failed export leaves the old file
                n = _write_can(fmt, str(tmp), feed, left_out)
    except (RecordingError, ValueError) as exc:  # the file changed since its first read
        print(f"hil export: {exc}", file=sys.stderr)
        return 2
    except BrokenPipeError:
        raise  # `-o - | head`: the reader went away; `hil` stops quietly (exit 141)
    except OSError as exc:
        print(f"hil export: cannot write {output}: {exc}", file=sys.stderr)
        return 2
    where = "stdout" if to_stdout else output
    for why, k in left_out.items():
        print(f"hil export: {k:,} frame(s) not exported: {why}", file=sys.stderr)
    print(f"{n:,} frames -> {where} ({fmt})", file=sys.stderr if to_stdout else sys.stdout)
    return 0
