"""`hil`: the command line. Each subcommand lives in the room that owns it.

A command module provides `configure(parser)` (adds its arguments) and `main(args) -> int`.
Modules are imported only when their command runs, so `hil --help` stays fast.
"""

from __future__ import annotations

import argparse
import importlib
import os
import sys

from hil import __version__

# name -> (module, one-line help)
COMMANDS: dict[str, tuple[str, str]] = {
    "run": ("hil.plan.cli", "run plans on a bench (default: every shipped plan, virtual bench)"),
    "drive": ("hil.virtual.cli", "run one virtual ASDA-A3 as its own process on given transports"),
    "check": ("hil.timing.cli", "re-check timing specs on a recording, offline"),
    "report": ("hil.report.cli", "render an HTML report from a recording"),
    "diff": ("hil.report.diff_cli", "compare two recordings of a plan, step by step"),
    "inspect": ("hil.record.cli", "summarise (and repair) an MCAP recording"),
    "export": ("hil.record.export_cli", "export a recording's CAN traffic (candump, python-can)"),
    "gateway": ("hil.gateway.cli", "export a bench's buses over zenoh"),
}


# the commands that read recordings whole, a message at a time (`hil check` has its own bar)
READERS = frozenset({"report", "diff", "inspect", "export"})


def _load(name: str):
    return importlib.import_module(COMMANDS[name][0])


def build_parser(argv: list[str] | None = None) -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="hil",
        description="Hardware-in-the-loop test harness for servo drives "
        "(real benches or the built-in virtual Delta ASDA-A3).",
    )
    parser.add_argument("--version", action="version", version=f"hil {__version__}")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND")
    wanted = None
    if argv:
        wanted = next((a for a in argv if not a.startswith("-")), None)
    for name, (_module, help_text) in COMMANDS.items():
        p = sub.add_parser(name, help=help_text, description=help_text)
        if name == wanted:  # only the command being run pays for its imports
            _load(name).configure(p)
    return parser


def main(argv: list[str] | None = None) -> int:
    try:
        return _main(argv)
    except KeyboardInterrupt:  # while the command's modules load (about a second cold)
        print("hil: interrupted", file=sys.stderr)
        return 130


def _main(argv: list[str] | None) -> int:
    argv = sys.argv[1:] if argv is None else argv
    parser = build_parser(argv)
    args = parser.parse_args(argv)
    if not args.command:
        parser.print_help()
        return 2
    reads = args.command in READERS or args.command == "check"
    if reads:  # a file it did not write: a message of a wrong shape is skipped and counted
        from hil.record.reader import progress_on_terminal, skip_bad_messages

        skip_bad_messages(True)
        if args.command in READERS:  # a large file shows a bar (`hil check` has its own)
            progress_on_terminal(f"hil {args.command}: reading the recording")
    try:
        code = int(_load(args.command).main(args) or 0)
        sys.stdout.flush()  # a closed pipe shows here, not at interpreter exit
        return code
    except KeyboardInterrupt:
        print("hil: interrupted", file=sys.stderr)
        return 130
    except BrokenPipeError:
        # the reader went away (`hil inspect x.mcap | head`): stop quietly, as `cat` does;
        # point stdout at /dev/null so the interpreter's final flush cannot fail again
        # (https://docs.python.org/3/library/signal.html#note-on-sigpipe)
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
        return 141  # 128 + SIGPIPE, what a shell reports for a command killed by it
    finally:
        if reads:  # a caller in this process (a test) reads bare again
            progress_on_terminal(None)
            skip_bad_messages(False)


if __name__ == "__main__":
    sys.exit(main())
