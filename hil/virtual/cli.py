"""`hil drive`: one virtual ASDA-A3 as its own process on the given transports.

Prints a line containing `ready` once every face answers; stops cleanly on SIGINT/SIGTERM
(faces and buses closed, retained parameters saved).
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import re
import signal
import sys
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

from hil.bench.bench import load_bench
from hil.bench.yamlio import PlanFileError
from hil.fileio import FileProblem, read_limited
from hil.model.errors import ModelError
from hil.model.mechanics import Mechanics
from hil.transport.urls import TransportUrlError, parse_url
from hil.virtual.options import model_options
from hil.virtual.stack import DriveSpec, VirtualDriveStack
from hil.virtual.world import StdioControl, idle_inputs, initial_params
from hil.yamlio import load_yaml_file


def configure(p: argparse.ArgumentParser) -> None:
    p.add_argument("--name", default="drive1", type=_drive_name,
                   help="drive name in its recording topics (default: drive1)")
    p.add_argument(
        "--can",
        metavar="URL",
        help="CAN transport, e.g. zenoh:lab/b1/can?listen=tcp/127.0.0.1:7447",
    )
    p.add_argument(
        "--rs485", metavar="URL", help="RS-485 transport, e.g. pty:/tmp/ttyA3?baud=115200"
    )
    p.add_argument("--dio", metavar="URL", help="DI/DO transport, e.g. zenoh:lab/b1/dio?listen=...")
    p.add_argument("--pulse", metavar="URL",
                   help="pulse line (PT input, OA/OB/OZ, the PLC's sensors), e.g. "
                        "zenoh:lab/b1/pulse?listen=tcp/127.0.0.1:7448 (docs/pulse.md)")
    p.add_argument("--node-id", type=_ranged("node id", 1, 127),
                   help="CANopen node id 1-127 (P3.000; default: parameter)")
    p.add_argument("--station", type=_ranged("station", 1, 0x7F),
                   help="Modbus station 1-127 (P3.000, 01h-7Fh, L10497; default: parameter)")
    p.add_argument(
        "--params",
        type=Path,
        metavar="FILE",
        help="JSON or YAML mapping of parameters to set at power-up, e.g. {P1.042: 150}",
    )
    p.add_argument(
        "--state",
        type=Path,
        metavar="DIR",
        help="directory keeping retained parameters across runs",
    )
    p.add_argument(
        "--di",
        action="append",
        default=[],
        metavar="N=0|1",
        help="DI contact level at power-up (repeatable), e.g. --di 8=1 (EMGS wired)",
    )
    p.add_argument(
        "--bench",
        type=Path,
        metavar="FILE",
        help="take mechanics, model options, parameters (wiring + params) and idle DI levels "
        "of a bench drive (--drive; default: the bench's first drive)",
    )
    p.add_argument("--drive", metavar="NAME", help="which drive of --bench this process is")
    p.add_argument(
        "--control",
        choices=("none", "stdio"),
        default="none",
        help="stdio: take JSON commands (power_cycle, inject, snapshot) on stdin and stream "
        "ground truth as 'hil-ctl' JSON lines on stdout (used by the runner's subprocess "
        "benches); stdin closing stops the drive",
    )


def _drive_name(text: str) -> str:
    """A drive's name: a topic segment (letters, digits, `_`, `-`, `.`; 1-64), not a newline
    that splits the `ready` line nor a slash that adds topic levels."""
    if not re.fullmatch(r"[A-Za-z0-9_.-]{1,64}", text):
        raise argparse.ArgumentTypeError(f"{text[:40]!r}: letters, digits, _ - . (1-64)")
    return text


def _ranged(what: str, lo: int, hi: int) -> Callable[[str], int]:
    """argparse type: an integer in lo..hi (P3.000 range, L10469), else a usage error."""

    def parse(text: str) -> int:
        try:
            value = int(text, 0)
        except ValueError:
            raise argparse.ArgumentTypeError(f"{text!r} is not a {what}") from None
        if not lo <= value <= hi:
            raise argparse.ArgumentTypeError(f"{what} {value} outside {lo}..{hi}")
        return value

    return parse


def _load_mapping(path: Path) -> dict[str, int]:
    """`--params FILE`: parameter name -> value, YAML (line-numbered errors) or JSON."""
    if path.suffix in (".yaml", ".yml"):
        data = load_yaml_file(path, PlanFileError)
        where = lambda k: f"{path}:{data.kline(k)}: {k}"  # noqa: E731
    else:
        try:
            data = json.loads(read_limited(path, 1 << 20, "JSON file").decode("utf-8"))
        except FileProblem as e:
            raise ParamsFileError(str(e)) from None
        except OSError as e:
            raise ParamsFileError(f"{path}: cannot read: {e.strerror or e}") from None
        except ValueError as e:
            raise ParamsFileError(f"{path}: not JSON: {e}") from None
        where = lambda k: f"{path}: {k}"  # noqa: E731
    if not isinstance(data, dict):
        raise ParamsFileError(f"{path}: expected a mapping of parameter names to values")
    out = {}
    for k, v in data.items():
        try:  # a whole number as written: not 1.7 (-> 1), true (-> 1) or infinity
            if isinstance(v, bool) or (isinstance(v, float) and not v.is_integer()):
                raise ValueError
            out[str(k)] = int(v, 0) if isinstance(v, str) else int(v)
        except (TypeError, ValueError, OverflowError):
            raise ParamsFileError(f"{where(k)}: {str(v)[:40]!r} is not an integer") from None
    return out


class ParamsFileError(ValueError):
    """A `--params` file that cannot be used; the message names the file (and line)."""


def _from_bench(spec: DriveSpec, args: argparse.Namespace) -> str:
    """Fill `spec` from a bench drive: mechanics, options, the wiring's mapping parameters
    plus its params (command-line --params win), idle DI levels (b-contacts closed)."""

    if not args.bench:
        return "--drive needs --bench FILE"
    try:
        bench = load_bench(args.bench)
    except (OSError, PlanFileError) as e:
        return str(e)
    name = args.drive or bench.default_drive
    if name not in bench.drives:
        return (f"--drive {name}: bench {bench.name!r} has no such drive "
                f"(drives: {', '.join(bench.drives)})")
    d = bench.drives[name]
    spec.name = name if args.name == "drive1" else args.name
    spec.mechanics = Mechanics.from_dict(dict(d.mechanics))
    spec.options = model_options(d.options, where=f"drives.{name}.options")
    spec.params = {**initial_params(d), **spec.params}
    if not args.di:
        spec.inputs = idle_inputs(d)
    if spec.node_id is None:
        spec.node_id = d.node_id
    if spec.station is None:
        spec.station = d.station
    if spec.modbus_mode is None and d.rs485:
        spec.modbus_mode = d.modbus_mode
    if spec.pulse_wiring is None:
        spec.pulse_wiring = d.pulse_wiring
    return ""


def _inputs(values: list[str]) -> dict[int, bool]:
    out = {}
    for item in values:
        n, _, level = item.partition("=")
        if not (n.isascii() and n.isdigit()) or level not in ("0", "1"):
            print(f"hil drive: --di {item!r}: expected N=0 or N=1, e.g. 8=1", file=sys.stderr)
            raise SystemExit(2)  # a usage error, as argparse exits
        if not 1 <= int(n) <= 10:  # the physical inputs (VDI11-13 are no terminals)
            print(f"hil drive: --di {item!r}: DI1 ~ DI10", file=sys.stderr)
            raise SystemExit(2)
        out[int(n)] = level == "1"
    return out


REASON_SHOWN = 300  # characters of a refusal's reason `hil drive` prints (helper-138)


def report_refusals(now: dict[str, tuple[int, str]], reported: dict[str, int],
                    stream: Any) -> None:
    """One line on `stream` per kind of input refused since the last call (`reported` keeps
    the counts printed): a PLC or harness whose messages a pulse or DI/DO face drops sees
    why, where a CANopen or Modbus face would answer on the wire. At most one line per kind
    per call (the run loop calls it every 0.2 s), so a flood costs a line per kind."""
    for what, (n, last) in now.items():
        new = n - reported.get(what, 0)
        if new > 0:
            reported[what] = n
            if len(last) > REASON_SHOWN:  # a reason quotes the peer's field: a 5 MB `freq`
                last = f"{last[:REASON_SHOWN]}… ({len(last) - REASON_SHOWN:,} more)"
            print(f"hil drive: refused {new} {what} ({n} in all); last: {last}",
                  file=stream, flush=True)


def main(args: argparse.Namespace) -> int:
    if not (args.can or args.rs485 or args.dio or args.pulse):
        print("hil drive: give at least one of --can, --rs485, --dio, --pulse", file=sys.stderr)
        return 2
    if args.state and os.path.exists(args.state) and not os.path.isdir(args.state):
        print(f"hil drive: --state {args.state}: not a directory (--state names the directory "
              "that keeps retained parameters across runs)", file=sys.stderr)
        return 2
    try:
        params = _load_mapping(args.params) if args.params else {}
    except (ParamsFileError, PlanFileError) as e:
        print(f"hil drive: --params {e}", file=sys.stderr)
        return 2
    spec = DriveSpec(
        name=args.name,
        can=args.can,
        rs485=args.rs485,
        dio=args.dio,
        pulse=args.pulse,
        node_id=args.node_id,
        station=args.station,
        params={},
        inputs=_inputs(args.di) or {8: True},
        state_path=args.state,
    )
    spec.params = params
    if args.bench or args.drive:
        err = _from_bench(spec, args)
        if err:
            print(f"hil drive: {err}", file=sys.stderr)
            return 2
    try:  # a malformed URL is bad input (2); one that cannot be opened is exit 1
        for url, kind in ((spec.can, "can"), (spec.rs485, "serial"), (spec.dio, "dio"),
                          (spec.pulse, "pulse")):
            if url:
                parse_url(url, kind)
    except TransportUrlError as e:
        print(f"hil drive: {e}", file=sys.stderr)
        return 2
    stop = threading.Event()
    for sig in (signal.SIGINT, signal.SIGTERM):
        signal.signal(sig, lambda *_: stop.set())
    try:
        stack = VirtualDriveStack(spec).start()
    except ModelError as exc:  # a --params / bench value the drive refuses: bad input
        print(f"hil drive: {exc}", file=sys.stderr)
        return 2
    except Exception as exc:  # transport errors name the URL
        print(f"hil drive: {exc}", file=sys.stderr)
        return 1
    control = None
    reported: dict[str, int] = {}  # refusals printed so far, per kind
    try:
        if args.control == "stdio":

            control = StdioControl(stack, stop)
        print(f"hil drive: ready: {stack.describe()}", flush=True)
        if control is not None:
            control.start()
        failed = None
        while not stop.wait(0.2):
            report_refusals(stack.refusals(), reported, sys.stderr)
            failed = getattr(getattr(stack, "host", None), "model_failed", None)
            if failed is not None:  # its outputs froze: end, so the runner sees it died
                print(f"hil drive: the model failed ({type(failed).__name__}: {failed}); "
                      "stopping", file=sys.stderr, flush=True)
                break
    finally:
        if control is not None:
            control.close()
        stack.stop()
        with contextlib.suppress(OSError, ValueError):  # stderr gone with the runner
            report_refusals(stack.refusals(), reported, sys.stderr)
        print("hil drive: stopped", flush=True)
    return 1 if failed is not None else 0
