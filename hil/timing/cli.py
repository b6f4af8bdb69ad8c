"""`hil check RECORDING.mcap`: re-judge timing specs on a recording, offline and read-only.

Default specs: those the recording's metadata (`timing` record, key `specs`) names, else every
shipped spec in fixtures/timing/.

Exit codes: 0 every judged verdict passed; 1 any failed; 2 bad input (usage, no such file, not
an MCAP file, not a hil recording, bad spec); 3 none failed but some were inconclusive; 4
incomplete: nothing was judged at all, a spec named with --spec found no data, or the recording
is damaged mid-file (a corrupt chunk: everything after it is unreadable), cut (no footer: a
killed run) or of a run that was aborted (Ctrl-C: `hil.result` status aborted). Nothing
judged is not
a pass, so 4 always comes with the reason on stderr.

Flags are checked before anything is judged; a bad one is exit 2 naming it: `--const` must be
a constant of the chosen specs, `--param` a parameter of the drive's table (chapter 8),
`--bind` a placeholder or DI/DO function the chosen specs use (a function to a line such as
DO4 or DI8:b); values are finite numbers within the expression limits (|x| <= 2**64),
resolutions are not negative, `--svg` is a directory that can be created and written.
"""

from __future__ import annotations

import argparse
import math
import re
import sys
from pathlib import Path
from typing import Any

from hil.fileio import dumps_strict
from hil.record import topics
from hil.record.progress import ReadProgress
from hil.record.reader import RecordingError, before_channels, repaired_cut
from hil.record.reader import incomplete as reader_incomplete
from hil.record.reader import not_hil as reader_not_hil
from hil.terminal import TEXT_MAX, terminal_text
from hil.timing.applicable import not_applicable
from hil.timing.checker import (
    Verdict,
    check,
    constants_for,
    missing_data,
    occurrences_since,
    spec_columns,
    spec_topics,
    summary,
)
from hil.timing.expr import MAX_MAGNITUDE
from hil.timing.render import svg
from hil.timing.source import (
    RecordingSource,
    infer_places,
    recorded_checks,
    recorded_constants,
    recorded_specs,
)
from hil.timing.spec import (
    DEFAULT_PLACES,
    LINE_RE,
    PLACE_RE,
    Spec,
    SpecError,
    load_spec,
    shipped_specs,
)


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
                             "recording (default there: re-check every check_timing step as "
                             "run; with --spec IDs the plan checked, only those steps; with a "
                             "spec file or a spec the plan did not check, the whole recording)")
    parser.add_argument("--svg", metavar="DIR", help="also write one SVG diagram per spec")
    parser.add_argument("-v", "--verbose", action="store_true",
                        help="also list verdicts that are not applicable (skipped)")


def _pairs(items: list[str], what: str, number: bool = False) -> dict[str, Any]:
    """NAME=VALUE flags -> {name: value}; with `number`, each value a finite number within
    the expression limits (ValueError naming the flag)."""
    out: dict[str, Any] = {}
    for item in items:
        key, sep, val = item.partition("=")
        key = key.strip()
        if not sep or not key:
            raise ValueError(f"{what} {item!r}: expected NAME=VALUE")
        if number:
            out[key] = _number(val.strip(), f"{what} {item!r}")
        else:
            out[key] = val.strip()
    return out


def _number(val: str, what: str) -> int | float:
    try:
        num: int | float = int(val, 0)
    except ValueError:  # also a text of more than 4300 digits
        try:
            num = float(val)
        except ValueError:
            raise ValueError(f"{what}: {val[:40]!r} is not a number") from None
    if isinstance(num, float) and not math.isfinite(num):
        raise ValueError(f"{what}: {val[:40]!r} is not a finite number")
    if abs(num) > MAX_MAGNITUDE:
        raise ValueError(f"{what}: {val[:40]!r} is beyond the magnitude limit (|x| <= 2**64)")
    return num


def _known(names: set[str], most: int = 15) -> str:
    shown = sorted(names)
    more = f", … ({len(shown) - most} more)" if len(shown) > most else ""
    return ", ".join(shown[:most]) + more or "none"


def _bindable(spec: Spec) -> set[str]:
    """The placeholders and DI/DO functions `spec` reads: `--bind` may set only these."""
    out = set(DEFAULT_PLACES) | set(spec.bind)
    texts = list(spec.resolution)
    for s in spec.signals.values():
        if s.function:
            out.add(s.function)
        texts += [s.topic or "", *(s.alarm or []), *(str(v) for v in s.where.values())]
    for t in texts:
        out.update(PLACE_RE.findall(t))
    return out


_PLACE_VALUE = re.compile(r"[A-Za-z0-9_.-]+")


def check_flags(specs: list[Spec], binding: dict[str, str], params: dict[str, Any],
                consts: dict[str, Any], res: dict[str, Any]) -> dict[str, Any]:
    """Refuse flags the chosen specs cannot use (ValueError naming the flag); returns the
    `--param` values under their canonical names (p1-42 -> P1.042)."""
    from hil.profile.params import ParamTable, canonical

    known = set().union(*(s.constants for s in specs)) if specs else set()
    for k, val in consts.items():
        if k not in known:
            raise ValueError(f"--const {k}={val}: unknown constant {k!r} (constants of the "
                             f"chosen specs: {_known(known)})")
    table = ParamTable.load() if params else None
    out: dict[str, Any] = {}
    for k, val in params.items():
        if table is None or k not in table:
            raise ValueError(f"--param {k}={val}: unknown parameter {k!r}: not in the drive's "
                             "parameter table (P<group>.<nnn>, e.g. P1.042)")
        out[canonical(k)] = val
    bindable = set().union(*(_bindable(s) for s in specs)) if specs else set(DEFAULT_PLACES)
    for k, val in binding.items():
        if k not in bindable:
            raise ValueError(f"--bind {k}={val}: the chosen specs have no placeholder or "
                             f"function {k!r} (they have: {_known(bindable)})")
        if k.isupper() and k not in DEFAULT_PLACES:  # a DI/DO function, as in a spec's bind:
            if not LINE_RE.fullmatch(val):
                raise ValueError(f"--bind {k}={val}: {val!r} is not a line (DI1..DI10, "
                                 "DO1..DO6, STO_A, STO_B, FDBK, with :b for a b-contact, "
                                 "e.g. DI8:b)")
        elif not _PLACE_VALUE.fullmatch(val):
            raise ValueError(f"--bind {k}={val}: {val!r} is not a name (letters, digits, "
                             "_ . -)")
    for k, val in res.items():
        if val < 0:
            raise ValueError(f"--resolution {k}={val}: must not be negative")
    return out


def svg_dir(path: str, specs: list[Spec], names: list[str] | None = None) -> Path:
    """The `--svg` directory, created now (ValueError naming `--svg` when it cannot be: a
    regular file on the way, a diagram path that is a directory, no permission). `names`:
    the diagrams' file stems (default: the specs' ids)."""
    if not path.strip():
        raise ValueError("--svg: empty directory name")
    out = Path(path)
    if out.exists() and not out.is_dir():
        raise ValueError(f"--svg {path}: not a directory")
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as e:
        raise ValueError(f"--svg {path}: cannot create the directory: "
                         f"{e.strerror or e}") from None
    for stem in names if names is not None else [spec.id for spec in specs]:
        target = out / f"{stem}.svg"
        if target.exists() and not target.is_file():
            raise ValueError(f"--svg {path}: cannot write {target}: not a regular file")
    return out


def resolve_specs(names: list[str], *, recorded: bool = False) -> list[Spec]:
    """Spec files or shipped ids -> loaded specs (raises SpecError / FileNotFoundError).
    `recorded`: names a recording gives (its plan's spec ids): shipped ids only, never a
    path, so a recording cannot make `hil check` open a file of its choosing."""
    shipped = {p.stem: p for p in shipped_specs()}
    out = []
    for n in names:
        if recorded:
            if n not in shipped:
                raise FileNotFoundError(
                    f"the recording names spec {terminal_text(n)[:80]!r}, which is not a "
                    "shipped spec id: give its file with --spec FILE")
            out.append(load_spec(shipped[n]))
            continue
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
        # occurrences counted from 1, as the report's diagrams name them
        lines.append(f"{v.status.upper():<13}{terminal_text(v.spec):<20}{v.occurrence + 1:>3}  "
                     f"{terminal_text(v.constraint)}")
        lines.append(f"{'':<38}{terminal_text(v.message, 4 * TEXT_MAX)}")
    s = summary(verdicts)
    lines.append(", ".join(f"{n} {k}" for k, n in s.items()))
    return "\n".join(lines)


EXIT_PASS, EXIT_FAIL, EXIT_USAGE, EXIT_INCONCLUSIVE, EXIT_INCOMPLETE = 0, 1, 2, 3, 4


def exit_code(verdicts: list[Verdict]) -> int:
    s = summary(verdicts)
    return EXIT_FAIL if s["fail"] else EXIT_INCONCLUSIVE if s["inconclusive"] else EXIT_PASS


def _judged(verdicts: list[Verdict]) -> bool:
    return any(v.status != "skipped" for v in verdicts)


def _why_nothing(spec: Spec, verdicts: list[Verdict], source: Any, binding: dict) -> str:
    """One line: why `spec` judged nothing (its signals without data, else why not applicable)."""
    missing = missing_data(spec, source, binding)
    if missing:
        return f"spec {spec.id}: found no data for signal " + "; ".join(missing)
    whys = sorted({v.message for v in verdicts if v.spec == spec.id}) or ["no constraint"]
    return f"spec {spec.id}: nothing to judge: " + "; ".join(whys)


def not_hil(source: Any) -> str | None:
    """Why a readable MCAP is not a hil recording, or None when it is one."""
    return reader_not_hil(source.meta, source.schemas, source.topics())


def final_code(verdicts: list[Verdict], source: Any, incomplete: list[str]) -> int:
    """The exit code, printing on stderr why a result is incomplete (exit 4)."""
    why = reader_incomplete(source.path, corrupt=source.corrupt, error=source.error,
                            truncated=getattr(source, "truncated", False),
                            footer=getattr(source, "footer", False))
    if why:  # what the run did after the cut is unknown
        incomplete = [why, *incomplete]
    if (cut := repaired_cut(getattr(source, "meta", {}) or {})) is not None:
        incomplete = [f"{source.path}: {cut}; judged only what it holds", *incomplete]
    bad = getattr(source, "bad_messages", 0)
    if bad:  # what those messages said is not in the verdicts
        incomplete = [*incomplete, f"{source.path}: {bad} message(s) of a wrong shape were "
                      "skipped (the warning above names the first)"]
    if not _judged(verdicts):
        incomplete = [*incomplete, "nothing was judged"]
    result = (getattr(source, "meta", None) or {}).get("hil.result", {})
    if result.get("status") == "aborted":  # a whole file of a run that stopped early: what
        incomplete = [*incomplete, f"{source.path}: the run was aborted ("  # it never did
                      f"{result.get('reason') or 'no reason recorded'}): the steps after it "
                      "never ran"]
    code = exit_code(verdicts)
    if incomplete and code != EXIT_FAIL:
        for line in incomplete:
            print(f"hil check: incomplete: {line}", file=sys.stderr)
        return EXIT_INCOMPLETE
    for line in incomplete:
        print(f"hil check: {line}", file=sys.stderr)
    return code


def print_json(verdicts: list[Verdict]) -> None:
    """The verdicts as a JSON list on stdout, one at a time (an hour-long recording's tens
    of thousands of verdicts are never one string in memory)."""
    out = sys.stdout
    out.write("[")
    for i, v in enumerate(verdicts):
        text = dumps_strict(v.to_dict(), indent=2, default=str)
        out.write(("," if i else "") + "\n  " + text.replace("\n", "\n  "))
    out.write("\n]\n" if verdicts else "]\n")


def _read(args: argparse.Namespace, what: str, **kw: Any) -> RecordingSource | int:
    """The recording as `RecordingSource(**kw)`, with a progress bar saying `what` on a
    terminal; the exit code (said on stderr) when it cannot be read."""
    progress = ReadProgress(args.recording, what)
    try:
        return RecordingSource(args.recording, time=args.time, progress=progress,
                               at_rest=True, **kw)
    except ImportError as e:
        print(f"hil check: cannot read recordings ({e})", file=sys.stderr)
        return 2
    except Exception as e:
        why = str(e) if isinstance(e, RecordingError) else f"{args.recording}: cannot read: {e}"
        print(f"hil check: {why}", file=sys.stderr)
        return EXIT_USAGE
    finally:
        progress.close()


def read_plan(specs: list[Spec], bindings: list[dict[str, str]]
              ) -> tuple[set[str], dict[str, set[str]]]:
    """What judging `specs` reads of a recording, under any of `bindings`: the topics to
    keep, and among them the signal topics to hold as columns with the fields read (a
    recording of any length is then read in memory that grows with the changes of those
    fields, and a topic no spec reads, such as a busy bus's raw frames, is skipped)."""
    wanted: set[str] = {topics.TIMING_VERDICTS}
    columns: dict[str, set[str]] = {}
    for spec in specs:
        for bind in bindings:
            wanted |= spec_topics(spec, bind)
            for topic, fields in spec_columns(spec, bind).items():
                columns.setdefault(topic, set()).update(fields)
    return wanted, columns


def _write_svg(args: argparse.Namespace, target: Path, text: str) -> bool:
    """One `--svg` diagram; False (said on stderr) when it cannot be written."""
    try:
        target.write_text(text, encoding="utf-8")
    except OSError as e:
        print(f"hil check: --svg {args.svg}: cannot write {target}: {e.strerror or e}",
              file=sys.stderr)
        return False
    return True


def _unrecorded(spec: Spec, source: Any, bind: dict) -> list[str]:
    """`missing_data`'s lines for the signals whose topic is not in the recording at all
    ("SON: no data on /dio/drive1/DI1 field level")."""
    recorded = set(source.topics())
    return [m for m in missing_data(spec, source, bind)
            if m.split(" on ", 1)[-1].split(" field ")[0] not in recorded]


def _counts(judged: dict[str, int]) -> str:
    return ", ".join(f"{n} {k}" for k, n in sorted(judged.items())) or "nothing"


def _not_as_judged(run: dict, spec: Spec, vs: list[Verdict], src: Any,
                   bind: dict) -> str | None:
    """Why a re-made plan check does not judge what the run's own verdicts say it judged
    (the same pass, fail and inconclusive counts), else None. helper-137: a recording
    without its SON input passed, the run's pass turned "not applicable"."""
    got: dict[str, int] = {}
    for v in vs:
        if v.status != "skipped":
            got[v.status] = got.get(v.status, 0) + 1
    if "judged" not in run or got == run["judged"]:
        return None
    gone = _unrecorded(spec, src, bind)
    return (f"step {int(run['step']) + 1} spec {spec.id}: the run judged "
            f"{_counts(run['judged'])}, this check {_counts(got)}"
            + (f" (not in the recording: signal {'; '.join(gone)})" if gone else ""))


def _as_run(args: argparse.Namespace, runs: list[dict], binding: dict, params: dict,
            consts: dict, res: dict, incomplete: list[str]) -> int:
    """Re-judge every `check_timing` step of a plan recording on what the run had seen by then,
    with the step's binding, parameters, constants and `since` (the live verdicts, offline)."""
    verdicts: list[Verdict] = []
    cache: dict[int, RecordingSource] = {}
    specs: list[Spec] = []
    for run in runs:
        try:
            specs += resolve_specs([run["spec"]], recorded=True)
        except (SpecError, FileNotFoundError, ValueError) as e:
            print(f"hil check: step {run['step']}: {e}", file=sys.stderr)
            return 2
    # a spec checked at several steps draws one diagram per step: <spec>-step<N>.svg
    many = {sp.id for sp in specs if sum(x.id == sp.id for x in specs) > 1}
    stems = [f"{sp.id}-step{int(run['step']) + 1}" if sp.id in many else sp.id
             for run, sp in zip(runs, specs, strict=True)]
    try:
        params = check_flags(specs, binding, params, consts, res)
        out_dir = svg_dir(args.svg, specs, stems) if args.svg is not None else None
    except ValueError as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    read = read_plan(specs, [dict(run["binding"]) | binding for run in runs])
    overridden = bool(binding or params or consts or res) or args.time != "publish"
    for run, spec, stem in zip(runs, specs, stems, strict=True):
        until = int(run["until_ns"])
        if until not in cache:  # only the latest read is kept: memory of one, not of each
            cache.clear()  # step (the steps come in order; checks at one step share it)
            # (not at rest: a step is re-checked on what the harness had seen at its
            # time, as it was checked then, even in a file cut later)
            cache[until] = RecordingSource(args.recording, time=args.time, until_log_ns=until,
                                           topics=read[0], columns=read[1])
        src = cache[until]
        step_params, step_bind = (run["params"] | params) or None, dict(run["binding"]) | binding
        vs = check(spec, src, params=step_params, binding=step_bind,
                   constants=(run["constants"] | consts) or None, resolution=res)
        vs = occurrences_since(vs, run["since_ns"])
        verdicts.extend(vs)
        # as the run judged it: only when nothing was asked to be judged otherwise (a
        # --param, --const, --bind, --resolution or --time may change a verdict on purpose)
        if not overridden and (why := _not_as_judged(run, spec, vs, src, step_bind)):
            incomplete.append(why)
        if out_dir is not None and not _write_svg(
                args, out_dir / f"{stem}.svg", svg(spec, src, vs, step_params, step_bind)):
            return 2
    if args.json:
        print_json(verdicts)
    else:
        print(format_table(verdicts, args.verbose))
    return final_code(verdicts, next(iter(cache.values())), incomplete)


def main(args: argparse.Namespace) -> int:
    try:
        binding = _pairs(args.bind, "--bind")
        params = _pairs(args.param, "--param", number=True)
        consts = _pairs(args.const, "--const", number=True)
        res = _pairs(args.resolution, "--resolution", number=True)
    except ValueError as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    if any(not s.strip() for s in args.spec or ()):
        print("hil check: --spec '': empty; a shipped spec id (e.g. servo_on_brake) or a spec "
              "file", file=sys.stderr)
        return 2
    if not Path(args.recording).is_file():
        why = "not a regular file" if Path(args.recording).exists() else "no such file"
        print(f"hil check: {args.recording}: {why}", file=sys.stderr)
        return 2
    # first what the file says of itself, then only what the chosen specs read
    source = _read(args, "hil check: what the recording says of itself",
                   topics=[topics.TIMING_VERDICTS], cut=False)
    if isinstance(source, int):
        return source
    why = not_hil(source)
    empty = before_channels(source.truncated, source.corrupt, len(source.topics()))
    if empty is None and not source.topics():  # whole, but not one channel (a skipped
        empty = "holds no channel"               # pytest test's recording, say)
    if empty:
        if args.json:  # killed (or damaged) before its first channel, metadata or not
            print_json([])
        return final_code([], source, [f"{args.recording}: {empty.partition(':')[0]}: "
                                       "nothing to judge"])
    if why and not source.corrupt:
        print(f"hil check: {args.recording}: {why}", file=sys.stderr)
        return EXIT_USAGE
    rec_specs, rec_binding = recorded_specs(source.meta)
    runs = [] if args.whole else recorded_checks(source)
    # verdict records no one can read: the plan's own checks in them cannot be re-made
    lost = [] if args.whole or not source.bad_messages else [
        f"{args.recording}: {source.bad_messages} /timing/verdicts message(s) of a wrong shape "
        "were skipped (the warning above names the first): the plan checks they recorded "
        "are not re-made as the run made them"]
    if runs and args.spec:  # the plan's own checks of these spec ids, as they were made
        ids = set(args.spec)
        runs = [r for r in runs if r["spec"] in ids] \
            if ids <= {r["spec"] for r in runs} else []  # a file or another spec: whole
    if runs:  # a plan run: re-check each check step as it was made, with no bench
        return _as_run(args, runs, binding, params, consts, res, lost)
    if (not (args.whole or args.spec) and rec_specs and source.meta.get("hil.plan")
            and (source.truncated or repaired_cut(source.meta))):
        # the plan's checks each had their own since/bind/constants: judging the specs with
        # their defaults over the whole file instead is not what the plan checks
        if args.json:
            print_json([])
        return final_code([], source, [
            f"{args.recording}: it holds none of the plan's check_timing steps (cut or "
            f"damaged before the first), so the plan's checks ({', '.join(rec_specs)}) are "
            "not judged here with the specs' defaults in place of each step's since, bind "
            "and constants (--whole judges them so)"])
    try:
        specs = (resolve_specs(args.spec) if args.spec else
                 resolve_specs(rec_specs, recorded=True)) if (args.spec or rec_specs) else [
            load_spec(p) for p in shipped_specs()]
    except (SpecError, FileNotFoundError) as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    try:
        params = check_flags(specs, binding, params, consts, res)
        out_dir = svg_dir(args.svg, specs) if args.svg is not None else None
    except ValueError as e:
        print(f"hil check: {e}", file=sys.stderr)
        return 2
    bind = infer_places(source.topics()) | rec_binding | binding
    wanted, columns = read_plan(specs, [bind])
    source = _read(args, "hil check: the topics the specs read", topics=wanted, columns=columns)
    if isinstance(source, int):  # the file changed since the first read
        return source
    bench_consts = recorded_constants(source.meta)
    verdicts: list[Verdict] = []
    incomplete: list[str] = list(lost)
    survey = not (args.spec or rec_specs)  # every shipped spec: only where each applies
    for spec in specs:
        own = constants_for(spec, bench_consts)
        why = not_applicable(spec, source, bind) if survey else None
        vs = [Verdict(spec.id, c.name, "skipped", f"not applicable: {why}", kind=c.kind,
                      source=c.source) for c in spec.constraints] if why else check(
            spec, source, params=params, binding=bind, constants=(own | consts) or None,
            resolution=res)
        verdicts.extend(vs)
        if args.spec and not _judged(vs):  # a spec the user asked for must judge something
            incomplete.append(_why_nothing(spec, vs, source, bind))
        elif args.spec and not why:  # judged, but a signal may read a topic never recorded
            for m in _unrecorded(spec, source, bind):
                print(f"hil check: note: spec {spec.id}: signal {m} (a topic not in "
                      "the recording: its verdicts read it as never true)", file=sys.stderr)
        if out_dir is not None and not _write_svg(
                args, out_dir / f"{spec.id}.svg", svg(spec, source, vs, params, bind)):
            return 2
    if args.json:
        print_json(verdicts)
    else:
        print(format_table(verdicts, args.verbose))
    if not _judged(verdicts) and not args.spec:
        incomplete = [*lost, *(_why_nothing(sp, verdicts, source, bind) for sp in specs)]
    return final_code(verdicts, source, incomplete)
