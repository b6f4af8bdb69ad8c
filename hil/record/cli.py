"""`hil inspect FILE [--repair OUT]`: summarise a recording; rewrite a truncated one."""

from __future__ import annotations

import argparse
import contextlib
import heapq
import itertools
import sys
from array import array
from collections.abc import Mapping
from pathlib import Path

from hil.fileio import atomic_path
from hil.record.mcapio import McapWriter
from hil.record.reader import Recording, RecordingError
from hil.terminal import terminal_lines


def configure(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("file", type=Path, help="MCAP recording")
    parser.add_argument(
        "--repair",
        metavar="OUT",
        type=Path,
        help="write everything readable into a new, valid MCAP file",
    )
    parser.add_argument(
        "--gaps",
        type=_count,
        default=3,
        metavar="N",
        help="largest gaps to show per topic (default 3; 0: none)",
    )


def _count(text: str) -> int:
    """A whole number >= 0 (argparse type)."""
    try:
        n = int(text)
    except ValueError:
        raise argparse.ArgumentTypeError(f"{text!r}: a whole number >= 0") from None
    if n < 0:
        raise argparse.ArgumentTypeError(f"{text}: a whole number >= 0")
    return n


def _fmt_ns(ns: int) -> str:
    if ns >= 1_000_000_000:
        return f"{ns / 1e9:.3f} s"
    if ns >= 1_000_000:
        return f"{ns / 1e6:.3f} ms"
    return f"{ns / 1e3:.1f} µs"


def summarise(rec: Recording, gaps: int = 3,
              times: dict[str, array] | None = None) -> str:
    """The text `hil inspect` prints; `times`: each topic's log times, read already
    (`Recording.stream`), else read from `rec`."""
    lines = [f"file: {rec.path} ({rec.size:,} bytes)"]
    if rec.skipped:
        lines.append(f"DAMAGED: {len(rec.skipped)} unreadable record(s) stepped over, the "
                     "records around them read:")
        lines += [f"  {why}" for why in rec.skipped[:10]]
        if len(rec.skipped) > 10:
            lines.append(f"  ... and {len(rec.skipped) - 10} more")
        if not rec._scan.has_footer:
            lines.append("no footer/summary (the writer did not finish: killed run?)")
    elif rec.corrupt:  # damage, not a killed run's cut end
        lines.append(f"DAMAGED: {rec.error}; everything before it is readable")
    elif rec.truncated:
        why = rec.error or "no footer/summary (the writer did not finish: killed run?)"
        lines.append(f"TRUNCATED: {why}; everything before it is readable")
    elif rec._scan.index_error:  # whole in order, but its summary points elsewhere
        lines.append(f"INDEX DAMAGED: {rec._scan.index_error}: every message reads in order, "
                     "but a reader that follows the index (Foxglove) fails on it; --repair "
                     "writes a copy with a new index")
    else:
        lines.append("complete: footer and summary present")
    lines += [f"DAMAGED attachment {bad}: left out" for bad in rec.bad_attachments[:10]]
    if times is None:
        times = {}
        for topic, lt, _pt, _d in rec.raw_messages():
            times.setdefault(topic, array("Q")).append(lt)
    n_all = sum(len(ts) for ts in times.values())
    if n_all:
        t0 = min(min(ts) for ts in times.values() if ts)
        t1 = max(max(ts) for ts in times.values() if ts)
        lines.append(f"messages: {n_all:,}  span: {_fmt_ns(t1 - t0)}  (log_time {t0} .. {t1})")
    else:
        lines.append("messages: 0")
    lines.append("channels:")
    per_topic: dict[str, int] = {}
    for c in rec.channels():
        per_topic[c.topic] = per_topic.get(c.topic, 0) + 1
    shown_topics: set[str] = set()
    for c in rec.channels():
        if c.topic in shown_topics:  # another writer's second channel of one topic: the
            continue  # topic's messages are counted once, with the channels said
        shown_topics.add(c.topic)
        ts = times.get(c.topic, array("Q"))
        src = c.metadata.get("publish_time_source", "?")
        many = f"  ({per_topic[c.topic]} channels of this topic)" if per_topic[c.topic] > 1 else ""
        lines.append(f"  {c.topic:<32} {len(ts):>9,}  {c.schema:<20} publish_time: {src}{many}")
        if len(ts) > 1 and gaps > 0:
            ts = sorted(ts)
            worst = heapq.nlargest(gaps, ((b - a, a) for a, b in itertools.pairwise(ts)))
            shown = ", ".join(f"{_fmt_ns(g)} after +{_fmt_ns(a - ts[0])}" for g, a in worst[:gaps])
            lines.append(f"  {'':<32} largest gaps: {shown}")
    meta = rec.metadata()
    close = meta.get("hil.close")
    if close is None:
        lines.append("drops: unknown (no hil.close metadata: the recorder did not close)")
    else:
        lines.append(
            f"drops: {close.get('drops', '?')}  writer errors: {close.get('errors', '?')}"
            f"  verdicts: pass {close.get('verdicts_pass', '?')}, fail "
            f"{close.get('verdicts_fail', '?')}, inconclusive "
            f"{close.get('verdicts_inconclusive', '?')}"
        )
    lines.append("metadata: " + (", ".join(sorted(meta)) or "none"))
    att = rec.attachments()
    lines.append(
        "attachments: "
        + (", ".join(f"{a.name} ({a.media_type}, {len(a.data)} B)" for a in att) or "none")
    )
    return "\n".join(lines)


def _source_cut(rec: Recording, before: Mapping[str, str]) -> str:
    """The log time from which `rec`'s messages may be missing (damage, or a killed run's
    cut end), the earlier of its own and a repaired source's; "" for a whole file."""
    own = rec.cut_log_ns if rec.corrupt else rec.tail_log_ns
    cuts = [] if own is None else [own]
    with contextlib.suppress(TypeError, ValueError):
        cuts.append(int(before.get("source_cut_log_ns")))
    return str(min(cuts)) if cuts else ""


def repair(rec: Recording, out: Path, *, stream: bool = False) -> int:
    """Rewrite everything readable of `rec` into a complete MCAP file; return messages.
    `stream`: `rec` was streamed (it holds no message): its messages are read again from
    its file, a record at a time, and written as they come."""
    if out.resolve() == rec.path.resolve():
        raise ValueError(f"--repair {out}: must differ from the input file")
    n = 0
    out.parent.mkdir(parents=True, exist_ok=True)  # as report, diff and export make theirs
    # through a temporary file renamed at the end: a failed repair (a full disk, a file size
    # limit) leaves an existing OUT as it was
    with atomic_path(out) as tmp, open(tmp, "wb") as f:
        w = McapWriter(f, library="hil inspect --repair")
        schema_ids: dict[int, int] = {}
        chan_ids: dict[int, int] = {}
        sc = rec._scan
        for cid, ch in sorted(sc.channels.items()):
            s = sc.schemas.get(ch.schema_id)
            sid = 0
            if s is not None:
                if s.id not in schema_ids:
                    schema_ids[s.id] = w.add_schema(s.name, s.encoding, s.data)
                sid = schema_ids[s.id]
            chan_ids[cid] = w.add_channel(ch.topic, ch.message_encoding, sid, ch.metadata)
        for m in sc.metadata:
            w.add_metadata(m.name, m.metadata)
        for a in sc.attachments:
            w.add_attachment(a.name, a.media_type, a.data, a.log_time, a.create_time)

        def write(cid: int, lt: int, pt: int, data: bytes) -> None:
            nonlocal n
            if cid in chan_ids:
                w.add_message(chan_ids[cid], lt, pt, data)
                n += 1

        if stream:
            Recording.stream(rec.path, None, write, by_channel=True,
                             past_damage=bool(rec.skipped))
        else:
            for cid, lt, pt, data in rec._raw(None):
                write(cid, lt, pt, data)
        before = rec.metadata().get("hil.repair", {})  # a repair of a repaired copy: the
        # first source's cut stays said (a later record of the name wins)
        w.add_metadata(
            "hil.repair",
            {
                "source": str(rec.path),
                "source_truncated": str(rec.truncated
                                        or before.get("source_truncated") == "true").lower(),
                "source_error": rec.error or before.get("source_error", ""),
                # where the source was cut or damaged: what followed is unknown (a checker
                # of this copy judges only what came before it)
                "source_cut_log_ns": _source_cut(rec, before),
                "source_damaged": str(rec.corrupt
                                      or before.get("source_damaged") == "true").lower(),
                "messages": str(n),
                "skipped_records": str(len(rec.skipped)),
            },
        )
        w.finish()
    return n


def main(args: argparse.Namespace) -> int:
    times: dict[str, array] = {}

    def take(topic: str, lt: int, _pt: int, _data: bytes) -> None:
        ts = times.get(topic)
        if ts is None:
            ts = times[topic] = array("Q")
        ts.append(lt)

    if args.repair:  # said before the file is read, as every output that names an input
        from hil.fileio import FileProblem, refuse_input

        try:
            refuse_input(args.repair, [args.file], "--repair")
        except FileProblem as exc:
            print(f"hil inspect: {exc}", file=sys.stderr)
            return 2
        if Path(args.repair).is_dir():  # (said before the summary, not after it)
            print(f"hil inspect: --repair {args.repair}: a directory; give the name of the "
                  "MCAP file to write", file=sys.stderr)
            return 2
    try:  # a message at a time: the file is never held whole; past a damaged record (a
        # chunk whose CRC fails): what lies after it is said and repaired too
        rec = Recording.stream(args.file, None, take, past_damage=True)
    except RecordingError as exc:
        print(f"hil inspect: {exc}", file=sys.stderr)
        return 2
    print(terminal_lines(summarise(rec, args.gaps, times)))  # names from the file: no escapes
    if args.repair:
        try:
            n = repair(rec, args.repair, stream=True)
        except RecordingError as exc:  # the file changed since it was read
            print(f"hil inspect: {exc}", file=sys.stderr)
            return 2
        except (OSError, ValueError) as exc:
            print(f"hil inspect: cannot repair {args.file}: {exc}", file=sys.stderr)
            return 2
        print(f"repaired: {n:,} messages written to {args.repair}")
    return 0
