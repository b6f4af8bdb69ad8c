"""`hil check RECORDING.mcap`: re-judge timing specs on a recording, offline and read-only.

Default specs: those the recording's metadata (`timing` record, key `specs`) names, else every
shipped spec in fixtures/timing/. Exit 0 when every verdict passed (or was not applicable),
1 when any failed, 3 when none failed but some were inconclusive, 2 on bad input.
"""

from __future__ import annotations

import argparse
import json
import sys
from pathlib import Path
from typing import Any

from hil.timing.checker import Verdict, check, constants_for, summary
from hil.timing.spec import Spec, SpecError, load_spec, shipped_specs


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("recording", help="MCAP recording to check")
    parser.add_argument("--spec", action="append", default=[], metavar="FILE|ID",
                        help="spec file or shipped spec id (repeatable; default: the ones the "
                        "recording names, else all shipped)")
    parser.add_argument("--bind", action="append", default=[], metavar="NAME=VALUE",
                        help="placeholder or DI/DO function binding, e.g. drive=drive1, "
                        "dio=io0, BRKR=DO4, EMGS=DI8:b")
    parser.add_argument("--param", action="append", default=[], metavar="P1.042=150",
                        help="override a recorded drive parameter")
    parser.add_argument("--const", action="append", default=[], metavar="NAME=VALUE",
                        help="override a spec constant, e.g. tol=2 or cia402_max=20")
    parser.add_argument("--resolution", action="append", default=[], metavar="GLOB=MS",
                        help="observation resolution of topics, e.g. '/dio/*/DO*=1'")
    parser.add_argument("--time", choices=("publish", "log"), default="publish",
                        help="timestamps to judge on (default: the source's own, publish)")
    parser.add_argument("--json", action="store_true", help="print verdicts as JSON")
    parser.add_argument("--whole", action="store_true",
                        help="check each spec once over the whole recording, even for a plan "
                             "recording (default there: re-check every check_timing step as run)")
    parser.add_argument("--svg", metavar="DIR", help="also write one SVG diagram per spec")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="also list verdicts that are not applicable (skipped)")


def _pairs(items: list[str], what: str, number: bool = False) -> dict[str, Any]:
    out: dict[str, Any] = {}
    for item in items:
        key, sep, val = item.partition("=")
        if not sep or not key:
            raise ValueError(f"{what} {item!r}: expected NAME=VALUE")
        if number:
            try:
                out[key] = int(val, 0)
            except ValueError:
                try:
                    out[key] = float(val)
                except ValueError:
                    raise ValueError(f"{what} {item!r}: {val!r} is not a number") from None
        else:
            out[key] = val
    return out


def resolve_specs(names: list[str]) -> list[Spec]:
    """Spec files or shipped ids -> loaded specs (raises SpecError / FileNotFoundError)."""
    shipped = {p.stem: p for p in shipped_specs()}
    out = []
    for n in names:
        p = Path(n)
        if not p.exists() and n in shipped:
            p = shipped[n]
        elif not p.exists():
            raise FileNotFoundError(f"spec {n!r}: no such file and no shipped spec with that id "
                                    f"(shipped: {', '.join(sorted(shipped))})")
        out.append(load_spec(p))
    return out


def format_table(verdicts: list[Verdict], verbose: bool = False) -> str:
    rows = [v for v in verdicts if verbose or v.status != "skipped"]
    lines = [f"{'STATUS':<13}{'SPEC':<20}{'#':>3}  CONSTRAINT / EXPLANATION"]
    for v in rows:
        lines.append(f"{v.status.upper():<13}{v.spec:<20}{v.occurrence:>3}  {v.constraint}")
        lines.append(f"{'':<38}{v.message}")
    s = summary(verdicts)
    lines.append(", ".join(f"{n} {k}" for k, n in s.items()))
    return "\n".join(lines)


def exit_code(verdicts: list[Verdict]) -> int:
    s = summary(verdicts)
    return 1 if s["fail"] else 3 if s["inconclusive"] else 0


def _as_run(args: argparse.Namespace, runs: list[dict], binding: dict, params: dict,
            consts: dict, res: dict) -> int:
    """Re-judge every `check_timing` step of a plan recording on what the run had seen by then,
    with the step's binding, parameters, constants and `since` (the live verdicts, offline)."""
    from hil.timing.checker import occurrences_since
    from hil.timing.source import RecordingSource

    verdicts: list[Verdict] = []
    cache: dict[int, RecordingSource] = {}
    for run in runs:
        try:
            (spec,) = resolve_specs([run["spec"]])
        except (SpecError, FileNotFoundError, ValueError) as e:
            print(f"hil check: step {run['step']}: {e}", file=sys.stderr)
            return 2
        until = int(run["until_ns"])
        src = cache.get(until) or cache.setdefault(
            until, RecordingSource(args.recording, time=args.time, until_log_ns=until))
        vs = check(spec, src, params=(run["params"] | params) or None,
                   binding=dict(run["binding"]) | binding,
                   constants=(run["constants"] | consts) or None, resolution=res)
        verdicts.extend(occurrences_since(vs, run["since_ns"]))
    if args.json:
        print(json.dumps([v.to_dict() for v in verdicts], indent=2, default=str))
    else:
        print(format_table(verdicts, args.verbose))
    return exit_code(verdicts)


def main(args: argparse.Namespace) -> int:
    try:
        binding = _pairs(args.bind, "--bind")
        params = _pairs(args.param, "--param", number=True)
        consts = _pairs(args.const, "--const", number=True)
        res = _pairs(args.resolution, "--resolution", number=True)
    except ValueError as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    if not Path(args.recording).is_file():
        print(f"hil check: {args.recording}: no such file", file=sys.stderr)
        return 2
    try:
        from hil.timing.source import (
            RecordingSource,
            infer_places,
            recorded_checks,
            recorded_constants,
            recorded_specs,
        )

        source = RecordingSource(args.recording, time=args.time)
    except ImportError as e:
        print(f"hil check: cannot read recordings ({e})", file=sys.stderr)
        return 2
    except Exception as e:
        print(f"hil check: {args.recording}: cannot read: {e}", file=sys.stderr)
        return 2
    rec_specs, rec_binding = recorded_specs(source.meta)
    runs = [] if (args.spec or args.whole) else recorded_checks(source)
    if runs:  # a plan run: re-check each check step as it was made, with no bench
        return _as_run(args, runs, binding, params, consts, res)
    try:
        specs = resolve_specs(args.spec or rec_specs) if (args.spec or rec_specs) else [
            load_spec(p) for p in shipped_specs()]
    except (SpecError, FileNotFoundError) as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    bind = infer_places(source.topics()) | rec_binding | binding
    bench_consts = recorded_constants(source.meta)
    verdicts: list[Verdict] = []
    for spec in specs:
        own = constants_for(spec, bench_consts)
        vs = check(spec, source, params=params, binding=bind, constants=(own | consts) or None,
                   resolution=res)
        verdicts.extend(vs)
        if args.svg:
            from hil.timing.render import svg

            out = Path(args.svg)
            out.mkdir(parents=True, exist_ok=True)
            (out / f"{spec.id}.svg").write_text(svg(spec, source, vs, params, bind),
                                                encoding="utf-8")
    if args.json:
        print(json.dumps([v.to_dict() for v in verdicts], indent=2, default=str))
    else:
        print(format_table(verdicts, args.verbose))
    return exit_code(verdicts)
