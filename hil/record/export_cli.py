"""`hil export FILE --format candump|asc|blf|csv -o OUT [--bus NAME]`: CAN traffic out."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Iterable
from pathlib import Path
from typing import TextIO

import can

from hil.record.canio import can_messages
from hil.record.reader import Recording, RecordingError

FORMATS = ("candump", "asc", "blf", "csv")
CAN_ERR_FLAG = 0x20000000  # linux/can.h: error frames carry it in the id


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument(
        "--format",
        "-f",
        choices=FORMATS,
        default="candump",
        help="candump log (-L), or a python-can writer format",
    )
    parser.add_argument("-o", "--output", type=Path, required=True, metavar="OUT")
    parser.add_argument("--bus", default=None, help="only this bus (default: all)")
    parser.add_argument(
        "--time",
        choices=("log", "publish"),
        default="log",
        help="timestamps from log_time (harness) or publish_time (source)",
    )


def candump_line(bus: str, msg: can.Message) -> str:
    """One `candump -L` line: `(1700000000.123456) can0 123#DEADBEEF`."""
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


def write_candump(items: Iterable[tuple[str, can.Message]], out: TextIO) -> int:
    n = 0
    for bus, msg in items:
        out.write(candump_line(bus, msg) + "\n")
        n += 1
    return n


def main(args: argparse.Namespace) -> int:
    try:
        rec = Recording.open(args.file)
        items = list(can_messages(rec, args.bus, time=args.time))
    except (RecordingError, ValueError) as exc:
        print(f"hil export: {exc}", file=sys.stderr)
        return 2
    if rec.truncated:
        print(
            f"hil export: {args.file} is truncated ({rec.error or 'no footer'}); "
            "exporting what is readable",
            file=sys.stderr,
        )
    try:
        if args.format == "candump":
            with open(args.output, "w", encoding="ascii") as f:
                n = write_candump(items, f)
        else:
            writer = {"asc": can.ASCWriter, "blf": can.BLFWriter, "csv": can.CSVWriter}[
                args.format
            ](args.output)
            try:
                for _bus, msg in items:
                    writer.on_message_received(msg)
            finally:
                writer.stop()
            n = len(items)
    except OSError as exc:
        print(f"hil export: cannot write {args.output}: {exc}", file=sys.stderr)
        return 2
    print(f"{n:,} frames -> {args.output} ({args.format})")
    return 0
