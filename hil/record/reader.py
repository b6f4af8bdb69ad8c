"""Read a recording back: messages, time series and edges for the timing checker.

`Recording.open()` reads every complete record and stops at the first broken one (a killed
run has no summary and may end mid-record): `truncated` and `error` say what happened.
"""

from __future__ import annotations

import json
import logging
import os
from collections.abc import Callable, Iterable, Iterator, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from hil.fileio import FileProblem, read_limited, require_regular
from hil.record.mcapio import FileBytes, Scan, iter_chunk, scan

log = logging.getLogger("hil.record")
_loads = json.loads
_UNSEEN: Any = object()


class Undecodable(dict):
    """What `decode` gives for bytes that are no JSON: {"error": ..., "raw": hex}."""


def decode(data: bytes) -> Any:
    """A message's JSON; an undecodable one as `Undecodable` (never raises)."""
    try:
        return _loads(data)
    except (ValueError, RecursionError) as exc:  # RecursionError: nested past the stack
        why = "nested too deep" if isinstance(exc, RecursionError) else str(exc)
        return Undecodable(error=f"undecodable message: {why}", raw=bytes(data[:64]).hex())


def decode_record(data: bytes | dict, topic: str) -> dict:
    """A record a reader interprets (a plan step, a verdict, a DI/DO level ...) as a dict:
    TypeError for one that is no JSON object, which a reader with `skip_bad_messages` on
    skips and counts (a warning names the first) rather than read as a junk record."""
    if isinstance(data, dict):
        return data
    obj = decode(data)
    if isinstance(obj, Undecodable):
        raise TypeError(f"{topic}: {obj['error']}")
    if not isinstance(obj, dict):
        raise TypeError(f"{topic}: a {type(obj).__name__}, not an object")
    return obj


# what a reader raises on a message of the wrong shape (a text where a number belongs, NaN
# for an integer, a list for an object, JSON nested past the stack): with skip_bad_messages
# on, that message is skipped and counted (`Recording.bad_messages`), the read goes on
BAD_MESSAGE = (ValueError, TypeError, KeyError, AttributeError, IndexError, OverflowError,
               RecursionError)
I64_MAX = (1 << 63) - 1  # the largest time (ns) a timeline of signed 64-bit stamps holds


_progress_text: str | None = None
_skip_bad = False


def skip_bad_messages(on: bool) -> None:
    """From now on in this process, `Recording.stream` skips and counts a message its
    `on_message` cannot take (BAD_MESSAGE) instead of raising it: what a command reading a
    recording it did not write does (`hil check`, `report`, `diff`, `export`, `inspect`)."""
    global _skip_bad
    _skip_bad = on


def progress_on_terminal(text: str | None) -> None:
    """From now on in this process, `Recording.stream` of a large file shows a progress bar
    saying `text` on a terminal (a command's main sets it; None: never)."""
    global _progress_text
    _progress_text = text


class RecordingError(Exception):
    """A file that cannot be read as a recording (message names the file and the reason)."""


@dataclass(frozen=True)
class ChannelInfo:
    id: int
    topic: str
    schema: str
    message_encoding: str
    metadata: dict[str, str]


@dataclass(frozen=True)
class AttachmentInfo:
    name: str
    media_type: str
    log_time: int
    create_time: int
    data: bytes


def _get(obj: Any, field: str) -> Any:
    """`field` of a decoded message; dotted paths (`a.b`) and list indexes (`a.0`) allowed."""
    if field in obj:
        return obj[field]
    cur = obj
    for part in field.split("."):
        if isinstance(cur, dict):
            if part not in cur:
                raise KeyError(field)
            cur = cur[part]
        elif isinstance(cur, list):
            cur = cur[int(part)]
        else:
            raise KeyError(field)
    return cur


class Recording:
    """A readable view of an MCAP recording (complete or truncated)."""

    def __init__(self, path: Path, sc: Scan) -> None:
        self.path = path
        self._scan = sc
        self.bad_messages = 0  # messages a reader could not take (`stream`), skipped
        self.channel_info: dict[int, ChannelInfo] = {}
        for cid, ch in sc.channels.items():
            schema = sc.schemas.get(ch.schema_id)
            self.channel_info[cid] = ChannelInfo(
                cid, ch.topic, schema.name if schema else "", ch.message_encoding, ch.metadata
            )
        self._by_topic = {c.topic: c.id for c in self.channel_info.values()}
        self.message_topics: list[str] | None = None  # known after `stream`

    @classmethod
    def open(cls, path: str | os.PathLike) -> Recording:
        """Read `path`; raises `RecordingError` (naming the file) if it is no MCAP at all."""
        p = Path(path)
        try:
            data = read_limited(p, None, "recording")  # not a device: /dev/zero never ends
        except FileProblem as exc:
            raise RecordingError(str(exc)) from exc
        except OSError as exc:
            raise RecordingError(f"{p}: cannot read: {exc.strerror or exc}") from exc
        try:
            sc = scan(data)
        except ValueError as exc:
            raise RecordingError(f"{p}: {exc}") from exc
        return cls(p, sc)

    @classmethod
    def stream(cls, path: str | os.PathLike, topics: Iterable[str] | None,
               on_message: Callable[[Any, int, int, bytes], None],
               progress: Callable[[int, int], None] | None = None, *,
               by_channel: bool = False, past_damage: bool = False) -> Recording:
        """Read `path` a record at a time and hand each message of `topics` (None: every
        topic) to `on_message(topic, log_time, publish_time, data)`, in file order, keeping
        no message and no chunk: a recording of any length is read in bounded memory. The
        Recording returned has the channels, metadata and the file's state, no messages.
        A chunk that cannot be read whole gives none of its messages (as `open`).
        `progress(bytes read, file size)` is told as the reading goes. `by_channel`: the
        message's channel id is handed over instead of its topic. `past_damage`: a whole
        record that cannot be read is stepped over and the messages after it are read too
        (`skipped`; what a repair recovers); by default the read stops there."""
        want = None if topics is None else set(topics)
        bad = {"n": 0, "first": ""}  # the messages `on_message` could not take (BAD_MESSAGE)
        take = on_message

        def skipping(topic: Any, lt: int, pt: int, data: bytes) -> None:
            try:
                take(topic, lt, pt, data)
            except BAD_MESSAGE as exc:
                if not bad["n"]:
                    why = f"{type(exc).__name__}: {exc}"
                    if isinstance(exc, OverflowError) and max(lt, pt) > I64_MAX:
                        which, t = ("publish", pt) if pt > I64_MAX else ("log", lt)
                        why = (f"a {which} time of {t} ns, past the 2^63 - 1 ns a timeline "
                               "holds")
                    bad["first"] = f"{topic} at log time {lt}: {why}"[:200]
                bad["n"] += 1

        if _skip_bad:  # a command reading a file it did not write (else: the caller's error)
            on_message = skipping

        topic_of: dict[int, str | None] = {}  # channel id -> its topic if wanted, else None
        seen: dict[int, str] = {}  # channel id -> topic, of each channel with a message
        kept: dict[int, bool] = {}  # channel id -> wanted (known channels only)
        failed: list[Exception] = []  # what `on_message` raised: the caller's, not damage

        def sink(raw: bytes, schemas: dict, channels: dict) -> None:
            if failed:  # the caller's own error, read on past damage: raised at the end
                return

            def keep(cid: int) -> bool:
                got = topic_of.get(cid, _UNSEEN)
                if got is _UNSEEN:
                    ch = channels.get(cid)
                    name = ch.topic if ch is not None else f"?{cid}"
                    got = name if want is None or name in want else None
                    if ch is not None:
                        topic_of[cid] = got
                        seen[cid] = name
                        kept[cid] = got is not None
                return got is not None

            got = list(iter_chunk(raw, schemas, channels, keep, kept))  # whole, or raises
            try:
                for cid, lt, pt, data in got:
                    on_message(cid if by_channel else topic_of.get(cid) or f"?{cid}",
                               lt, pt, data)
            except Exception as exc:
                failed.append(exc)  # `scan` stops here; raised again below, as it was
                raise

        bar = None
        if progress is None and _progress_text is not None:  # a CLI's reading, on a terminal
            from hil.record.progress import ReadProgress

            progress = bar = ReadProgress(str(path), _progress_text)
        try:
            rec = cls._scan_file(path, sink, progress, past_damage=past_damage)
        finally:
            if bar is not None:
                bar.close()
        if failed:
            raise failed[0]
        sc = rec._scan
        for cid, lt, pt, data in sc.loose:  # messages outside chunks (the writer makes none)
            name = rec.channel_info[cid].topic if cid in rec.channel_info else f"?{cid}"
            seen[cid] = name
            if want is None or name in want:
                on_message(cid if by_channel else name, lt, pt, data)
        sc.loose.clear()
        #: the topics with at least one message, wanted or not
        rec.message_topics = sorted(set(seen.values()))
        rec.bad_messages = bad["n"]
        if bad["n"]:
            log.warning("%s: %d message(s) of a wrong shape skipped (the first: %s)", path,
                        bad["n"], bad["first"])
        return rec

    @classmethod
    def survey(cls, path: str | os.PathLike) -> Recording:
        """Every record of `path` read once, no message kept: its channels, metadata and state
        (`stream` with no topic wanted)."""
        return cls.stream(path, (), lambda *_m: None)

    @classmethod
    def head(cls, path: str | os.PathLike) -> Recording:
        """What `path` says of itself outside its chunks: metadata, attachments, whether it
        ends whole, and the channels its summary lists (none for a cut file). Its chunks are
        stepped over unread (no message): cheap on a recording of any length."""
        return cls._scan_file(path, None, None, chunks=False)

    @classmethod
    def _scan_file(cls, path: str | os.PathLike, sink: Any,
                   progress: Callable[[int, int], None] | None, *,
                   chunks: bool = True, past_damage: bool = False) -> Recording:
        p = Path(path)
        try:
            require_regular(p, "recording")  # not a device: /dev/zero never ends
            fd = os.open(p, os.O_RDONLY | os.O_NONBLOCK)
        except FileProblem as exc:
            raise RecordingError(str(exc)) from exc
        except OSError as exc:
            raise RecordingError(f"{p}: cannot read: {exc.strerror or exc}") from exc
        with os.fdopen(fd, "rb") as f:
            try:
                size = os.fstat(fd).st_size
                on_read = (lambda off: progress(off, size)) if progress is not None else None
                sc = scan(FileBytes(f, size, on_read), sink, chunks=chunks,
                          past_damage=past_damage)
            except ValueError as exc:
                raise RecordingError(f"{p}: {exc}") from exc
            except OSError as exc:  # the disk failed mid-way (EIO): not a broken record
                raise RecordingError(f"{p}: cannot read: {exc.strerror or exc}") from exc
        return cls(p, sc)

    # -- state of the file ----------------------------------------------------------------------
    @property
    def truncated(self) -> bool:
        """True if the file has no footer (killed run) or ends in a broken record."""
        return not self._scan.has_footer or self._scan.error is not None

    @property
    def skipped(self) -> list[str]:
        """Why each whole record was stepped over unread (`stream(past_damage=True)`)."""
        return self._scan.skipped

    @property
    def error(self) -> str | None:
        """The first broken record (offset and reason), or None."""
        return self._scan.error

    @property
    def corrupt(self) -> bool:
        """True if a whole record is unreadable (bad CRC, bad compression): the file is damaged
        mid-way and everything after that record is lost, unlike a killed run's cut tail."""
        return self._scan.corrupt

    @property
    def cut_log_ns(self) -> int | None:
        """For a damaged file: the log time from which nothing was read (the unreadable
        chunk's first message, else just after the last message read before the damage);
        None for a file that is not damaged."""
        return self._scan.cut_log_ns

    @property
    def bad_attachments(self) -> list[str]:
        """Attachments left out because their CRC failed (name and offset each)."""
        return self._scan.bad_attachments

    @property
    def has_footer(self) -> bool:
        """The file has its footer record (its writer finished)."""
        return self._scan.has_footer

    @property
    def last_log_ns(self) -> int | None:
        """The latest log time of any message read."""
        return self._scan.last_log_ns

    @property
    def tail_log_ns(self) -> int | None:
        """For a file cut short with no damage (a killed run, or one still recording): the log
        time from which messages may be missing (the cut chunk's first, else just after the
        last read); None for a whole or a damaged file (`cut_log_ns`)."""
        return None if self._scan.corrupt else self._scan.tail_log_ns

    @property
    def size(self) -> int:
        return self._scan.size

    # -- content --------------------------------------------------------------------------------
    def topics(self) -> list[str]:
        return sorted(self._by_topic)

    def channels(self) -> list[ChannelInfo]:
        """Channels sorted by topic (topic, schema name, encoding, metadata such as
        `publish_time_source`)."""
        return sorted(self.channel_info.values(), key=lambda c: c.topic)

    def _raw(self, cids: set[int] | None) -> Iterator[tuple[int, int, int, bytes]]:
        sc = self._scan
        for cid, lt, pt, data in sc.loose:
            if cids is None or cid in cids:
                yield cid, lt, pt, data
        schemas, channels = {}, {}
        for chunk in sc.chunks:
            if cids is None:
                yield from iter_chunk(chunk, schemas, channels)
            else:
                for m in iter_chunk(chunk, schemas, channels):
                    if m[0] in cids:
                        yield m

    def _cids(self, topics: Iterable[str] | str | None) -> set[int] | None:
        if topics is None:
            return None
        if isinstance(topics, str):
            topics = [topics]
        return {self._by_topic[t] for t in topics if t in self._by_topic}

    def raw_messages(
        self, topics: Iterable[str] | str | None = None
    ) -> Iterator[tuple[str, int, int, bytes]]:
        """(topic, log_time, publish_time, undecoded bytes) in file order."""
        names = {cid: c.topic for cid, c in self.channel_info.items()}
        for cid, lt, pt, data in self._raw(self._cids(topics)):
            yield names.get(cid, f"?{cid}"), lt, pt, data

    def messages(
        self, topics: Iterable[str] | str | None = None
    ) -> Iterator[tuple[str, int, int, dict]]:
        """(topic, log_time, publish_time, decoded JSON) in file order."""
        names = {cid: c.topic for cid, c in self.channel_info.items()}
        for cid, lt, pt, data in self._raw(self._cids(topics)):
            yield names.get(cid, f"?{cid}"), lt, pt, decode(data)

    def counts(self) -> dict[str, int]:
        """Messages per topic (topics without messages count 0)."""
        out = dict.fromkeys(self._by_topic, 0)
        names = {cid: c.topic for cid, c in self.channel_info.items()}
        for cid, _lt, _pt, _d in self._raw(None):
            t = names.get(cid, f"?{cid}")
            out[t] = out.get(t, 0) + 1
        return out

    def series(self, topic: str, field: str, *, time: str = "publish") -> list[tuple[int, Any]]:
        """[(t_ns, value)] of `field` on `topic`, sorted by time (`publish` or `log`).
        Messages without the field are skipped."""
        if time not in ("publish", "log"):
            raise ValueError(f"time {time!r}: must be 'publish' or 'log'")
        use_pub = time == "publish"
        cids = self._cids(topic)
        out: list[tuple[int, Any]] = []
        if not cids:
            return out
        append = out.append
        for _cid, lt, pt, data in self._raw(cids):
            obj = _loads(data)
            try:
                v = obj[field] if field in obj else _get(obj, field)
            except (KeyError, IndexError, ValueError):
                continue
            append((pt if use_pub else lt, v))
        out.sort(key=lambda x: x[0])
        return out

    def edges(
        self, topic: str, field: str = "level", *, time: str = "publish"
    ) -> list[tuple[int, Any]]:
        """[(t_ns, new_value)] where `field` changes; the first sample is included (it is
        the initial level, a change from unknown)."""
        out: list[tuple[int, Any]] = []
        prev: Any = object()
        for t, v in self.series(topic, field, time=time):
            if v != prev:
                out.append((t, v))
                prev = v
        return out

    def metadata(self) -> dict[str, dict[str, str]]:
        """Metadata records by name (a repeated name merges, later keys win)."""
        out: dict[str, dict[str, str]] = {}
        for m in self._scan.metadata:
            out.setdefault(m.name, {}).update(m.metadata)
        return out

    def attachments(self) -> list[AttachmentInfo]:
        return [
            AttachmentInfo(a.name, a.media_type, a.log_time, a.create_time, a.data)
            for a in self._scan.attachments
        ]


def not_hil(metadata: dict[str, Any], schemas: Iterable[str], topics: list[str]) -> str | None:
    """Why a readable MCAP is not a hil recording, or None when it is one (it has the
    recorder's `hil.run` metadata or `hil.*` schema channels). `hil check` and `hil diff`."""
    if "hil.run" in metadata or any(s.startswith("hil.") for s in schemas):
        return None
    found = ", ".join(topics[:5]) or "none"
    return ("not a hil recording: no hil.run metadata and no hil.* channels "
            f"(channels: {found})")


# a file cut before its first channel (a run killed as it started): `hil check` judges it
# incomplete (exit 4) and export has nothing to export (exit 2); report and diff show the
# run's metadata when it has some (the recorder writes it first), else exit 2
CUT_EMPTY = "cut before its first channel: nothing was recorded (a run killed as it started)"


def not_hil_file(rec: Recording) -> str | None:
    """`not_hil` of a surveyed recording (`Recording.survey`); None for one whose damage hides
    what it is (a corrupt chunk: judged as incomplete, not as foreign). A file cut before its
    first channel is said to be that (`CUT_EMPTY`), not foreign."""
    if rec.corrupt:
        return None
    empty = before_channels(rec.truncated, rec.corrupt, len(rec.channels()))
    if empty == CUT_EMPTY and not rec.metadata():  # not even the run's metadata: nothing
        return CUT_EMPTY  # to show
    return not_hil(rec.metadata(), [c.schema for c in rec.channels()], rec.topics())


DAMAGED_EMPTY = "damaged before its first channel: nothing of the run could be read"


def before_channels(truncated: bool, corrupt: bool, channels: int) -> str | None:
    """Why a file has no channel to read, whatever metadata it holds (the recorder writes the
    run's metadata first): cut (no footer: `CUT_EMPTY`) or damaged (`DAMAGED_EMPTY`) before
    its first channel; None when it has one, or is whole. One rule for check and export
    (and for report and diff, which show the run's metadata if any)."""
    if channels:
        return None
    if corrupt:
        return DAMAGED_EMPTY
    return CUT_EMPTY if truncated else None


def virtual_bench(metadata: Mapping[str, Any]) -> bool:
    """Whether the recording's run was on a virtual bench (`hil.bench.virtual`)."""
    bench = metadata.get("hil.bench")
    return isinstance(bench, Mapping) and str(bench.get("virtual")).lower() == "true"


def repaired_cut(metadata: Mapping[str, Any]) -> str | None:
    """Why a file `hil inspect --repair` wrote holds only part of its run (its source was cut
    or damaged: the repaired copy has a footer, but what came after the cut is unknown), or
    None."""
    rep = metadata.get("hil.repair")
    if not isinstance(rep, Mapping):
        return None
    if rep.get("source_error"):
        return f"repaired from a damaged or cut recording ({str(rep['source_error'])[:200]})"
    if rep.get("source_truncated") == "true":
        return "repaired from a cut recording (no footer: the run was killed)"
    return None


def incomplete(path: str | os.PathLike, *, corrupt: bool, truncated: bool,
               error: str | None, footer: bool = False) -> str | None:
    """Why what a reader judged of a recording is incomplete (exit 4), or None. `footer`:
    the file has its footer (then an error is not a killed run's missing end)."""
    if corrupt:
        return f"{path}: damaged: {error}; nothing after it was read"
    if truncated and footer:  # a footer without its closing magic, say
        return f"{path}: cut short: {error}; judged only what it holds"
    if truncated:
        return (f"{path}: truncated (no footer: the run was killed or is still recording); "
                "judged only what it holds")
    return None
