"""Where the checker's samples come from: in-memory lists (tests, live) or an MCAP recording.

A `SignalSource` gives, per topic, the recorded messages as (t_ns, dict) in time order, and
per topic the observation resolution in ns when it knows it (recorded sampling period or
timestamp granularity). Fields are read with dotted paths (`a.b`).
"""

from __future__ import annotations

import bisect
import copy
import fnmatch
import heapq
import itertools
import json
import logging
import math
from array import array
from collections.abc import Callable, Iterable, Iterator, Mapping, Sequence
from pathlib import Path
from types import SimpleNamespace
from typing import Any, Protocol

from hil.record import topics
from hil.record.reader import Recording, Undecodable, decode, repaired_cut

_MISSING = object()
MISSING_FIELD = _MISSING  # what a column holds where its messages lack the field


class SignalSource(Protocol):
    def messages(self, topic: str) -> list[tuple[int, dict]]:
        """Messages of `topic` as (t_ns, payload dict), sorted by time ([] if none)."""

    def resolution(self, topic: str) -> int | None:
        """Observation resolution of `topic` in ns, or None when the source does not know."""

    def topics(self) -> list[str]:
        """Every topic the source holds."""

    def end_time(self) -> int | None:
        """Last timestamp in the source (ns), None when empty."""

    def start_time(self) -> int | None:
        """First timestamp in the source (ns), None when empty."""


def get_field(msg: Any, path: str) -> Any:
    """`msg["a"]["b"]` for path "a.b"; _MISSING when absent."""
    cur = msg
    for part in path.split("."):
        if isinstance(cur, Mapping) and part in cur:
            cur = cur[part]
        else:
            return _MISSING
    return cur


def samples(source: SignalSource, topic: str, field: str,
            where: Mapping[str, Any] | None = None, runs: bool = False
            ) -> Sequence[tuple[int, Any]]:
    """(t_ns, value) of `field` in `topic`, skipping messages without it or not matching
    `where` (field -> required value). `runs=True`: a source that stores its messages as
    columns may give, of each run of equal values, only its first and last sample (what a
    change-point trace needs: every change, and the sample before it)."""
    cols = getattr(source, "columns", None)
    table = cols(topic) if cols is not None else None
    if table is not None:
        return table.samples(field, where, runs)
    cache = getattr(source, "_samples_cache", None)
    key = (topic, field, tuple(sorted((where or {}).items(), key=repr)))
    msgs = source.messages(topic)
    n = len(msgs)
    if runs:  # the whole list once, then its runs once; a grown topic extends them
        got = cache.get((*key, "runs")) if cache is not None else None
        if got is not None and got[0] == n:
            return got[1]
        full = samples(source, topic, field, where)
        if got is None:
            out, k_last, start = [], 0, 0
        else:  # the last run may go on: redo it and what came after it
            _n, out, k_last, start = got
            out = out[:len(out) - k_last]
        tail, k_last, start = _runs(full, start)
        out = out + tail
        if cache is not None:
            cache[(*key, "runs")] = (n, out, k_last, start)
        return out
    got = cache.get(key) if cache is not None else None
    if got is not None and got[0] == n:
        return got[1]
    # a live source only grows (a topic re-sorted drops its entries): extend what was derived
    done, prev = got if got is not None else (0, [])
    out = []
    append = out.append
    flat = "." not in field
    for t, msg in msgs[done:] if done else msgs:
        if where and any(get_field(msg, k) != v for k, v in where.items()):
            continue
        # fast path for a plain top-level field
        val = msg.get(field, _MISSING) if flat and type(msg) is dict else get_field(msg, field)
        if val is not _MISSING:
            append((t, val))
    if prev:
        out = prev + out  # a new list: one handed out before stays as it was
    if cache is not None:
        cache[key] = (n, out)
    return out


def runs_of(full: list[tuple[int, Any]]) -> list[tuple[int, Any]]:
    """Of each run of equal values (`_same`) in `full`, its first and its last sample."""
    return _runs(full, 0)[0]


def _runs(full: Sequence[tuple[int, Any]], i: int) -> tuple[list[tuple[int, Any]], int, int]:
    """`runs_of(full[i:])`, the number of its entries the last run gave (0, 1 or 2) and the
    index in `full` where that run begins (what to redo when `full` grows)."""
    out: list[tuple[int, Any]] = []
    append = out.append
    n = len(full)
    k_last, last = 0, i
    while i < n:
        t, v = full[i]
        tv = type(v)
        j = i
        while j + 1 < n and type(full[j + 1][1]) is tv and full[j + 1][1] == v:
            j += 1
        append((t, v))
        k_last, last = 1, i
        if j > i:
            append(full[j])
            k_last = 2
        i = j + 1
    return out, k_last, last


def _same(a: Any, b: Any) -> bool:
    """One value, for a run: equal and of one type (True is not 1 to a `map`)."""
    return type(a) is type(b) and a == b


#: a column's runs go into a typed array once this many are all floats (or all ints)
_TYPED_AFTER = 1024
_INT64 = (-(2**63), 2**63 - 1)


class Column:
    """One field of a topic in runs: `starts[k]` is the first message index of run k, whose
    value is `values[k]` (`_MISSING`: the messages of that run lack the field). The values of
    a field that is always a float (or always an int) are kept in a typed array: 8 bytes a
    run, what matters for a field that changes at every message. While every message is a run
    of its own (a speed that changes at every sample), `starts` is the `range` 0..n-1 and costs
    nothing; it becomes an array at the first run of two."""

    __slots__ = ("_last", "_tried", "starts", "values")

    def __init__(self) -> None:
        self.starts: range | array = range(0)
        self.values: list[Any] | array = []
        self._last = -1  # the last message index given a value
        self._tried = False  # the values were looked at for a typed array

    def put(self, i: int, v: Any) -> None:
        values = self.values
        if self._last == i - 1 and values and _same(values[-1], v):
            self._last = i
            return
        if self._last < i - 1 and (not values or values[-1] is not _MISSING):
            self._start(self._last + 1)  # the messages between had no such field
            self._append(_MISSING)
        self._start(i)
        self._append(v)
        self._last = i

    def _start(self, i: int) -> None:
        """A run begins at message `i`."""
        starts = self.starts
        if type(starts) is range:
            if i == len(starts):  # still one run a message: 0..i
                self.starts = range(i + 1)
                return
            self.starts = starts = array("q", starts)
        starts.append(i)

    def _append(self, v: Any) -> None:
        values = self.values
        if type(values) is list:
            values.append(v)
            if not self._tried and len(values) >= _TYPED_AFTER:
                self._tried = True
                kind = type(values[0])
                if kind is float and all(type(x) is float for x in values):
                    self.values = array("d", values)
                elif kind is int and all(type(x) is int and _INT64[0] <= x <= _INT64[1]
                                         for x in values):
                    self.values = array("q", values)
            return
        if (type(v) is float and values.typecode == "d") or (
                type(v) is int and values.typecode == "q" and _INT64[0] <= v <= _INT64[1]):
            values.append(v)
        else:  # another kind of value: objects from now on
            self.values = [*values, v]

    def close(self, n: int) -> None:
        """`n` messages in all: the tail without the field is a missing run."""
        if self._last < n - 1 and (not self.values or self.values[-1] is not _MISSING):
            self._start(self._last + 1)
            self._append(_MISSING)
        self._last = n - 1

    def value_list(self, n: int) -> list[Any]:
        out: list[Any] = []
        for k, v in enumerate(self.values):
            end = self.starts[k + 1] if k + 1 < len(self.starts) else n
            out.extend([v] * (end - self.starts[k]))
        return out


class ColumnTable:
    """The messages of one topic as columns: their times (sorted) and, per top-level field,
    its values in runs. A field that rarely changes costs a few runs however long the
    recording; a value that changes every message costs a reference to it."""

    def __init__(self, fields: set[str] | None = None) -> None:
        self.times = array("q")
        self.cols: dict[str, Column] = {}
        self._only = fields  # None: every field
        self._sorted = True

    def __len__(self) -> int:
        return len(self.times)

    def add_again(self, t: int) -> None:
        """A message equal to the one added before it (its bytes were): only its time."""
        i = len(self.times)
        if t < self.times[-1]:
            self._sorted = False
        self.times.append(t)
        for col in self.cols.values():
            if col._last == i - 1 and col.values[-1] is not _MISSING:
                col._last = i

    def add(self, t: int, msg: dict) -> None:
        times = self.times
        i = len(times)
        if i and t < times[-1]:
            self._sorted = False
        times.append(t)
        cols = self.cols
        only = self._only
        for k, v in msg.items():
            if only is not None and k not in only:
                continue
            col = cols.get(k)
            if col is None:
                col = cols[k] = Column()
            col.put(i, v)

    def finish(self) -> None:
        """After the last `add`: close the runs, and put the messages in time order (a
        stable sort: equal times keep file order)."""
        n = len(self.times)
        for col in self.cols.values():
            col.close(n)
        if self._sorted:
            return
        order = sorted(range(n), key=self.times.__getitem__)
        self.times = array("q", (self.times[i] for i in order))
        for name, col in list(self.cols.items()):
            vals = col.value_list(n)
            new = Column()
            for j, i in enumerate(order):
                v = vals[i]
                if v is not _MISSING:
                    new.put(j, v)
            new.close(n)
            self.cols[name] = new
        self._sorted = True

    def cut(self, t_end: int) -> None:
        """Drop the messages at `t_end` or later (a damaged file's unsure tail)."""
        n = bisect.bisect_left(self.times, t_end)
        if n == len(self.times):
            return
        del self.times[n:]
        for col in self.cols.values():
            k = bisect.bisect_left(col.starts, n)
            col.starts = col.starts[:k]  # a range stays a range
            del col.values[k:]
            col._last = n - 1

    def any_at(self, t: int, field: str, pred: Callable[[Any], bool]) -> bool:
        """Whether a message at time `t` has `field` and its value passes `pred`."""
        col = self.cols.get(field)
        if col is None:
            return False
        i = bisect.bisect_left(self.times, t)
        j = bisect.bisect_right(self.times, t)
        while i < j:
            k = bisect.bisect_right(col.starts, i) - 1
            v = col.values[k]
            if v is not _MISSING and pred(v):
                return True
            i = col.starts[k + 1] if k + 1 < len(col.starts) else j
        return False

    def rows(self) -> list[tuple[int, dict]]:
        """The messages again, as (t, dict) with the kept fields."""
        n = len(self.times)
        rows: list[tuple[int, dict]] = [(t, {}) for t in self.times]
        for name, col in self.cols.items():
            for i, v in enumerate(col.value_list(n)):
                if v is not _MISSING:
                    rows[i][1][name] = v
        return rows

    def _segments(self, names: list[str]) -> Iterator[tuple[int, int, list[Any]]]:
        """(first index, end index, [value of each name]) over which no named column
        changes, in order (the columns' run starts merged, not collected)."""
        n = len(self.times)
        cols = [self.cols.get(name) for name in names]
        if len(cols) == 1 and cols[0] is not None:  # one column: its runs are the segments
            starts, values = cols[0].starts, cols[0].values
            for k, a in enumerate(starts):
                if a >= n:
                    break
                end = starts[k + 1] if k + 1 < len(starts) else n
                yield a, min(end, n), [values[k]]
            return
        pos = [0] * len(cols)
        bounds = heapq.merge(*(c.starts for c in cols if c is not None))
        b = 0
        for nxt in itertools.chain(bounds, (n,)):
            if nxt <= b:
                continue
            vals = []
            for j, c in enumerate(cols):
                if c is None or not c.starts:
                    vals.append(_MISSING)
                    continue
                k = pos[j]
                while k + 1 < len(c.starts) and c.starts[k + 1] <= b:
                    k += 1
                pos[j] = k
                vals.append(c.values[k] if c.starts[k] <= b else _MISSING)
            yield b, min(nxt, n), vals
            b = nxt
            if b >= n:
                break

    def samples(self, field: str, where: Mapping[str, Any] | None,
                runs: bool) -> SampleList:
        head, _, rest = field.partition(".")
        conds = list((where or {}).items())
        names = [head] + [k.partition(".")[0] for k, _v in conds]
        times = self.times
        col = self.cols.get(head)
        typed = col is not None and type(col.values) is array and not rest and not conds
        ts = array("q")
        vs: Any = array(col.values.typecode) if typed else []  # type: ignore[union-attr]
        first = 0  # where the run of the last sample begins
        for a, b, vals in self._segments(names):
            v = vals[0]
            if v is not _MISSING and rest:
                v = get_field(v, rest)
            if v is _MISSING:
                continue
            ok = True
            for j, (k, want) in enumerate(conds):
                w = vals[j + 1]
                sub = k.partition(".")[2]
                if w is not _MISSING and sub:
                    w = get_field(w, sub)
                if w is _MISSING or w != want:
                    ok = False
                    break
            if not ok:
                continue
            if runs:  # of each run of equal values: its first and its last sample
                for t in ((times[a], times[b - 1]) if b - 1 > a else (times[a],)):
                    if vs and _same(vs[-1], v):
                        if len(vs) - 1 > first:
                            ts[-1] = t  # the run goes on: a new last sample
                            continue
                    else:
                        first = len(vs)
                    ts.append(t)
                    vs.append(v)
            else:
                ts.extend(times[a:b])
                vs.extend([v] * (b - a))
        return SampleList(ts, vs)


class SampleList(Sequence):
    """(t, value) samples kept as two sequences, the times in an integer array: about 16
    bytes a sample, not a tuple each (a signal of a long recording may have millions)."""

    __slots__ = ("times", "values")

    def __init__(self, times: Sequence[int], values: Sequence[Any]) -> None:
        self.times, self.values = times, values

    def __len__(self) -> int:
        return len(self.times)

    def __iter__(self) -> Iterator[tuple[int, Any]]:
        return zip(self.times, self.values, strict=True)

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return list(zip(self.times[i], self.values[i], strict=True))
        return self.times[i], self.values[i]

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Sequence) and list(self) == list(other)

    __hash__ = None  # type: ignore[assignment]

    def __repr__(self) -> str:
        return f"SampleList({list(self)!r})"


class MemorySource:
    """An in-memory source: `MemorySource.from_series({(topic, field): [(t, v), ...]})`."""

    def __init__(self, messages: Mapping[str, list[tuple[int, dict]]] | None = None,
                 resolutions: Mapping[str, int] | None = None) -> None:
        self._msgs: dict[str, list[tuple[int, dict]]] = {}
        for topic, lst in (messages or {}).items():
            self._msgs[topic] = sorted(lst, key=lambda m: m[0])
        self._res = dict(resolutions or {})
        #: what the checker derived from each topic's messages, keyed by topic first; each
        #: entry knows how many messages it covers, so a live source that grew extends it
        self._samples_cache: dict[tuple, Any] = {}

    @classmethod
    def from_series(cls, series: Mapping[tuple[str, str], list[tuple[int, Any]]],
                    resolutions: Mapping[str, int] | None = None,
                    params: Mapping[str, Any] | None = None, params_topic: str | None = None,
                    ) -> MemorySource:
        """One message per sample; `params` becomes one message at t=0 on `params_topic`."""
        msgs: dict[str, list[tuple[int, dict]]] = {}
        for (topic, field), lst in series.items():
            for t, v in lst:
                msgs.setdefault(topic, []).append((int(t), _nest(field, v)))
        if params is not None:
            topic = params_topic or topics.drive_params("drive1")
            msgs.setdefault(topic, []).insert(0, (0, dict(params)))
        return cls(msgs, resolutions)

    def add(self, topic: str, t: int, msg: dict) -> None:
        """Append a message (live use: feed as it arrives, in time order)."""
        self._samples_cache.clear()
        lst = self._msgs.setdefault(topic, [])
        if lst and t < lst[-1][0]:
            bisect.insort(lst, (t, msg), key=lambda m: m[0])
        else:
            lst.append((t, msg))

    def put_topic(self, topic: str, msgs: list[tuple[int, dict]]) -> None:
        """All messages of `topic` at once (t_ns, payload), e.g. decoded elsewhere."""
        self._samples_cache.clear()
        self._msgs[topic] = sorted(msgs, key=lambda m: m[0])

    def _forget(self, topic: str) -> None:
        """Drop what was derived from `topic`'s messages (they were reordered)."""
        cache = self._samples_cache
        for key in [k for k in cache if k[0] == topic or k == ("_sampling", topic)]:
            del cache[key]

    def messages(self, topic: str) -> list[tuple[int, dict]]:
        return self._msgs.get(topic, [])

    def resolution(self, topic: str) -> int | None:
        for pat, ns in self._res.items():
            if fnmatch.fnmatchcase(topic, pat):
                return ns
        return None

    def topics(self) -> list[str]:
        return sorted(self._msgs)

    def end_time(self) -> int | None:
        ends = [lst[-1][0] for lst in self._msgs.values() if lst]
        return max(ends) if ends else None

    def start_time(self) -> int | None:
        starts = [lst[0][0] for lst in self._msgs.values() if lst]
        return min(starts) if starts else None


def _nest(field: str, value: Any) -> dict:
    out: dict = {}
    cur = out
    parts = field.split(".")
    for p in parts[:-1]:
        cur = cur.setdefault(p, {})
    cur[parts[-1]] = value
    return out


class _LazySource(MemorySource):
    """A source that keeps each topic's messages as recorded bytes until `messages(topic)`
    is first asked for that topic, then decodes them once: a topic nothing reads (the raw
    frames of a busy bus, say) costs neither decoding nor a dict per message."""

    def __init__(self) -> None:
        super().__init__()
        #: per topic, what was read but not yet decoded: (t_ns, JSON bytes), file order (or
        #: the payload dict itself, where the recorder kept it: nothing to decode)
        self._raw: dict[str, list[tuple[int, bytes | dict]]] = {}
        self._raw_span: dict[str, list[int]] = {}  # per topic, [first t, last t] of `_raw`
        #: bytes -> decoded message, for a source whose readers never change a message (one
        #: dict then serves every message with those bytes); None: each is decoded anew
        self._shared: dict[bytes, tuple[dict, bool]] | None = None
        #: messages that were no JSON object, found as their topics were decoded (a file's
        #: scan adds those its reader could not take): what `hil check` says and exits 4 on
        self.bad_messages: int = 0

    def _keep_many(self, topic: str, msgs: list[tuple[int, bytes | dict]]) -> None:
        """Keep `msgs` (one topic's, in file order) undecoded until the topic is read."""
        lo, hi = min(t for t, _ in msgs), max(t for t, _ in msgs)
        pend = self._raw.get(topic)
        if pend is None:
            self._raw[topic] = msgs
            self._raw_span[topic] = [lo, hi]
        else:
            pend.extend(msgs)
            span = self._raw_span[topic]
            span[0], span[1] = min(span[0], lo), max(span[1], hi)

    def _keep_all(self, raw: dict[str, list[tuple[int, bytes]]]) -> None:
        """Every topic's undecoded messages at once (a file read)."""
        self._raw = {topic: lst for topic, lst in raw.items() if lst}
        self._raw_span = {topic: [min(t for t, _ in lst), max(t for t, _ in lst)]
                          for topic, lst in self._raw.items()}

    def messages(self, topic: str) -> list[tuple[int, dict]]:
        pend = self._raw.pop(topic, None)
        self._raw_span.pop(topic, None)
        if pend:
            lst = self._msgs.setdefault(topic, [])
            last = lst[-1][0] if lst else None
            ordered = True
            shared = self._shared
            bad0 = self.bad_messages
            for t, data in pend:
                if last is not None and t < last:
                    ordered = False
                last = t
                if type(data) is not dict:
                    if shared is None:
                        data, bad = _decode_obj(data)
                    else:  # a repeated message (a statusword poll) is decoded once
                        hit = shared.get(data)
                        if hit is None:
                            if len(shared) >= _SHARED_MAX:
                                shared.clear()
                            hit = shared[data] = _decode_obj(data)
                        data, bad = hit
                    if bad:  # judged as if it were not there: say so
                        self.bad_messages += 1
                lst.append((t, data))
            if self.bad_messages > bad0:
                logging.getLogger("hil.record").warning(
                    "%s: %s: %d message(s) of a wrong shape skipped",
                    getattr(self, "path", "the recording"), topic, self.bad_messages - bad0)
            if not ordered:
                lst.sort(key=lambda m: m[0])  # stable: equal times keep file order
                self._forget(topic)  # what was derived from its messages no longer holds
        return self._msgs.get(topic, [])

    def add(self, topic: str, t: int, msg: dict) -> None:
        self.messages(topic)  # what is pending comes first
        super().add(topic, t, msg)

    def put_topic(self, topic: str, msgs: list[tuple[int, dict]]) -> None:
        self._raw.pop(topic, None)
        self._raw_span.pop(topic, None)
        super().put_topic(topic, msgs)

    def topics(self) -> list[str]:
        return sorted(set(self._msgs) | set(self._raw))

    def end_time(self) -> int | None:
        ends = [lst[-1][0] for lst in self._msgs.values() if lst]
        ends += [span[1] for span in self._raw_span.values()]
        return max(ends) if ends else None

    def start_time(self) -> int | None:
        starts = [lst[0][0] for lst in self._msgs.values() if lst]
        starts += [span[0] for span in self._raw_span.values()]
        return min(starts) if starts else None


def _repaired_cut(rec: Any, meta: Mapping[str, Mapping[str, str]]) -> tuple[int, str] | None:
    """A `hil inspect --repair` copy of a cut or damaged file: (the log time from which its
    source's messages may be missing, "damage" or "end"); None for any other file. The copy
    is whole, and the chunks its repair read past a hole are in it: judged only up to the
    hole all the same, as its source is."""
    if repaired_cut(meta) is None:
        return None
    rep = meta.get("hil.repair", {})
    kind = "damage" if rep.get("source_damaged") == "true" else "end"
    try:
        return int(rep["source_cut_log_ns"]), kind
    except (KeyError, TypeError, ValueError):  # a copy an older hil repaired: at its end
        last = rec.last_log_ns
        return (last + 1 if last is not None else 0), kind


class RecordingSource(_LazySource):
    """Messages of an MCAP recording, read once through `hil.record.reader.Recording`.

    `time="publish"` uses the source's own timestamps (default), `"log"` the harness's.
    Resolution per topic comes from channel metadata key `resolution_ns`, or from a metadata
    record `timing` with `resolution_ns` = JSON {topic: ns}.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None,
                 time: str = "publish", until_log_ns: int | None = None,
                 columns: Mapping[str, Iterable[str] | None] | None = None,
                 progress: Callable[[int, int], None] | None = None,
                 at_rest: bool = False, cut: bool = True) -> None:
        """`until_log_ns`: only what the harness had seen by then (re-checking a live check).
        `at_rest`: the file is read as it will stay (`hil check`, `hil report`): one with no
        footer is a killed run's, and what came after its end is unknown, as after damage
        (`cut_ns`); a plan's own check of its recording so far leaves it False. `cut=False`:
        every message read is kept, none dropped at a cut (the plan's own records of what it
        checked, which stand whole where they were written: `hil check` finding its steps).
        `columns`: topic -> the fields to keep (None: all) of topics to hold as columns
        (`ColumnTable`) rather than as messages: what a long recording's checks read, in
        memory that grows with the changes of those fields, not with the messages. The
        file is read a record at a time, never whole; `progress(bytes read, size)` is told
        as it goes."""

        if time not in ("publish", "log"):
            raise ValueError(f"time must be 'publish' or 'log', not {time!r}")
        super().__init__()
        raw: dict[str, list[tuple[int, bytes]]] = {}
        tables = {topic: ColumnTable(None if f is None else set(f))
                  for topic, f in (columns or {}).items()}
        last: dict[str, bytes] = {}  # per column topic, the bytes of its last message
        wanted = None if topics is None else set(topics) | set(tables)
        lag = 0  # the largest publish-to-log delay read
        use_pub = time == "publish"
        loads = _decode_obj

        def take(topic: str, log_t: int, pub_t: int, data: bytes) -> None:
            nonlocal lag
            if until_log_ns is not None and log_t > until_log_ns:
                return
            t = pub_t if use_pub and pub_t else log_t
            if log_t - t > lag:
                lag = log_t - t
            table = tables.get(topic)
            if table is not None:
                if last.get(topic) == data:  # a repeated state: not decoded again
                    table.add_again(t)
                else:
                    obj, bad = loads(data)
                    if bad:  # judged as if it were not there: counted
                        self.bad_messages += 1
                    table.add(t, obj)
                    last[topic] = data
                return
            lst = raw.get(topic)
            if lst is None:
                lst = raw[topic] = []
            lst.append((t, data))

        rec = Recording.stream(str(path), wanted, take, progress)
        #: a damaged file: the time (of this source's clock) up to which every message
        #: is known to have been read; what came later is dropped, so nothing is judged
        #: on a part of the recording that lost some of its messages (None: whole file)
        self.cut_ns: int | None = None
        #: what the cut is: "damage" mid-file, or the "end" of a killed run's file
        self.cut_kind: str | None = None
        self.meta = _metadata(rec)
        at: int | None = None  # where this source is cut
        if cut and rec.corrupt:  # the damaged chunk's first log time, else past what was read
            at, self.cut_kind = rec.cut_log_ns, "damage"
        elif cut and (repaired := _repaired_cut(rec, self.meta)) is not None:
            at, self.cut_kind = repaired
        elif cut and at_rest and (at := rec.tail_log_ns) is not None:
            self.cut_kind = "end"
        for table in tables.values():
            table.finish()
        if at is not None:
            self.cut_ns = at - lag  # a message stamped this late may be in the lost chunk
            for topic, lst in raw.items():
                raw[topic] = [m for m in lst if m[0] < self.cut_ns]
            for table in tables.values():
                table.cut(self.cut_ns)
        self._keep_all(raw)
        self._tables = {topic: table for topic, table in tables.items() if len(table)}
        #: every topic with a message in the file, kept or not
        self._file_topics = set(rec.message_topics or ())
        res = _resolutions(rec, self.meta)
        #: the first broken record (None if the file is whole) and whether it is damage
        #: mid-file (`corrupt`) rather than a killed run's cut tail
        self.error: str | None = rec.error
        self.corrupt: bool = rec.corrupt
        self.truncated: bool = rec.truncated  # no footer: a killed (or running) recorder
        self.footer: bool = rec.has_footer  # (a file with its footer may still be cut short)
        if self.bad_messages:  # in the columns read above
            logging.getLogger("hil.record").warning(
                "%s: %d message(s) of a wrong shape skipped", path, self.bad_messages)
        self.bad_messages += rec.bad_messages  # of a wrong shape, skipped (`hil check`)
        self.schemas: set[str] = {c.schema for c in rec.channels()}
        self._res = res
        self.path = str(path)

    def columns(self, topic: str) -> ColumnTable | None:
        """The topic's columns, when it is held as columns."""
        return self._tables.get(topic)

    def put_table(self, topic: str, table: ColumnTable) -> None:
        """All messages of `topic` at once as columns, read elsewhere (`finish`ed)."""
        self._samples_cache.clear()
        self._raw.pop(topic, None)
        self._raw_span.pop(topic, None)
        self._msgs.pop(topic, None)
        if len(table):
            self._tables[topic] = table

    def messages(self, topic: str) -> list[tuple[int, dict]]:
        table = self._tables.get(topic)
        if table is None:
            return super().messages(topic)
        if topic not in self._msgs:  # rebuilt once, for a reader that wants messages
            self._msgs[topic] = table.rows()
        return self._msgs[topic]

    def topics(self) -> list[str]:
        """Every topic with a message in the file, including those not kept (`topics=`)."""
        return sorted(set(super().topics()) | set(self._tables) | self._file_topics)

    def end_time(self) -> int | None:
        ends = [t.times[-1] for t in self._tables.values()]
        if (other := super().end_time()) is not None:
            ends.append(other)
        return max(ends) if ends else None

    def start_time(self) -> int | None:
        starts = [t.times[0] for t in self._tables.values()]
        if (other := super().start_time()) is not None:
            starts.append(other)
        return min(starts) if starts else None


_SHARED_MAX = 4096  # distinct messages a live source keeps decoded for reuse


def _decode_obj(data: bytes) -> tuple[dict, bool]:
    """A message as a dict, and whether it was of a wrong shape: no JSON (`Undecodable`), or
    JSON but not an object (every hil message is one). Such a one is judged as if it were
    not there."""
    obj = decode(data)
    if type(obj) is dict:
        return obj, False
    return (dict(obj), True) if isinstance(obj, Undecodable) else ({"value": obj}, True)


class LiveSource(_LazySource):
    """The recording of a running plan, for its `check_timing` steps: each message is decoded
    at most once from the recorder's `mirror` (`Recorder.keep_messages`), so a plan's checks
    cost what its recording holds, not that times the number of checks. Decoding is lazy, per
    topic: a topic no check reads (the bus frames of statusword polling, say) is never decoded.
    `refresh(rec)` (after `rec.flush()`) takes what was written since; the file gives metadata
    and resolutions, as `RecordingSource` reads them."""

    def __init__(self) -> None:
        super().__init__()
        self._shared = {}  # read by the checker only, which changes no message
        self._seen = 0
        self._head_key: tuple = ()
        self.meta: dict[str, dict[str, str]] = {}
        self.error: str | None = None
        self.corrupt = False
        self.truncated = True
        self.schemas: set[str] = set()
        self.path = ""

    def refresh(self, rec: Any) -> LiveSource:
        key = (len(rec.topic_of), getattr(rec, "metadata_count", None),
               getattr(rec, "closed", None))  # closed: the file's footer is there to read
        if key != self._head_key or key[1] is None:  # a new channel or metadata record
            written = getattr(rec, "written_metadata", None)
            if written is not None and not getattr(rec, "closed", True):
                # what the recorder wrote: the file's head, unread (once closed, the file
                # is read: its footer and `hil.close` are written outside the queue)
                meta: dict[str, dict[str, str]] = {}
                for name, data in list(written):  # copies: the writer thread may add a
                    meta.setdefault(name, {}).update(data)  # record or a channel now
                chans = [SimpleNamespace(topic=t, schema=sch, metadata=md)
                         for t, (sch, md) in rec.written_channels.copy().items()]
                self.meta, self._res = meta, _resolutions(SimpleNamespace(channels=chans), meta)
                # a recording being written has no footer yet, as the file read would say
                self.error, self.corrupt, self.truncated = None, False, True
                self.schemas, self.path = {c.schema for c in chans}, str(rec.path)
            else:
                head = RecordingSource(rec.path, topics=[])  # metadata, resolutions only
                self.meta, self._res = head.meta, head._res
                self.error, self.corrupt = head.error, head.corrupt
                self.truncated = head.truncated
                self.schemas, self.path = head.schemas, head.path
            self._head_key = key
        mirror = rec.keep_messages()
        n = len(mirror)
        if n == self._seen:
            return self
        names = rec.topic_of
        batch: dict[str, list[tuple[int, bytes | dict]]] = {}  # by topic (a topic may
        for cid, log_t, pub_t, data, obj in mirror[self._seen:n]:  # have two channels)
            topic = names.get(cid) or f"?{cid}"
            lst = batch.get(topic)
            if lst is None:
                lst = batch[topic] = []
            lst.append((int(pub_t or log_t), data if obj is None else obj))
        for topic, lst in batch.items():
            self._keep_many(topic, lst)
        self._seen = n
        return self


def _metadata(rec: Any) -> dict[str, dict[str, str]]:
    """Normalise `Recording.metadata()` into {name: {key: value}}."""
    try:
        meta = rec.metadata()
    except Exception:
        return {}
    if isinstance(meta, Mapping):
        return {str(k): dict(v) if isinstance(v, Mapping) else {"value": v}
                for k, v in meta.items()}
    out: dict[str, dict[str, str]] = {}
    for item in meta or []:
        name, data = (item.name, item.metadata) if hasattr(item, "name") else item
        out.setdefault(str(name), {}).update(dict(data))
    return out


def _resolutions(rec: Any, meta: dict[str, dict[str, str]]) -> dict[str, int]:
    res: dict[str, int] = {}
    raw = meta.get("timing", {}).get("resolution_ns")
    if raw:
        try:
            res.update({k: int(v) for k, v in json.loads(raw).items()})
        except (ValueError, AttributeError):
            pass
    chans = getattr(rec, "channels", None)
    if chans is not None:
        try:
            chans = chans() if callable(chans) else chans
            for ch in chans.values() if isinstance(chans, Mapping) else chans:
                md = getattr(ch, "metadata", None) or (ch.get("metadata") if isinstance(ch, dict)
                                                       else None)
                topic = getattr(ch, "topic", None) or (ch.get("topic") if isinstance(ch, dict)
                                                       else None)
                if md and topic and "resolution_ns" in md:
                    res[topic] = int(md["resolution_ns"])
        except Exception:
            pass
    return res


def recorded_specs(meta: Mapping[str, Mapping[str, str]]) -> tuple[list[str], dict[str, str]]:
    """Spec ids/paths and binding a recording says it was checked with (metadata `timing`:
    `specs` = JSON list, `binding` = JSON object)."""
    tm = meta.get("timing", {})
    specs, binding = [], {}
    try:
        specs = json.loads(tm["specs"]) if tm.get("specs") else []
        binding = json.loads(tm["binding"]) if tm.get("binding") else {}
        if not isinstance(specs, list) or not isinstance(binding, dict):
            raise TypeError("not a list of ids and a binding object")  # "emgs" is no list
    except (ValueError, TypeError, RecursionError):  # a damaged record: none recorded
        specs, binding = [], {}
    return [str(s) for s in specs], {str(k): str(v) for k, v in binding.items()}


_VERDICT_PAIRS = ("window_ms", "uncertainty_ms")


def _is_number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


def verdict_shape(msg: dict) -> None:
    """TypeError for a /timing/verdicts record of a wrong shape (a page cannot show it, a
    diff cannot compare it, a re-check cannot trust it): a status text, spec
    and constraint texts where given; occurrence and step whole numbers; a window and an
    uncertainty as two numbers (a bound may be null); a measured value a number."""
    if not isinstance(msg.get("status"), str):  # required (hil.TimingVerdict); spec and
        raise TypeError("verdict field 'status' is missing or not text")  # constraint are not
    for k in ("spec", "constraint", "message", "kind", "source"):
        if msg.get(k) is not None and not isinstance(msg[k], str):
            raise TypeError(f"verdict field {k!r} is not text")
    for k in ("occurrence", "step"):
        x = msg.get(k)
        if x is not None and (type(x) is not int):
            raise TypeError(f"verdict field {k!r} is not a whole number")
    for k in _VERDICT_PAIRS:
        x = msg.get(k)
        if x is not None and not (isinstance(x, list) and len(x) == 2
                                  and all(v is None or _is_number(v) for v in x)):
            raise TypeError(f"verdict field {k!r} is not a pair of numbers")
    for k in ("measured_ms", "t_ns", "from_ns"):
        if msg.get(k) is not None and not _is_number(msg[k]):
            raise TypeError(f"verdict field {k!r} is not a number")
    for k in ("binding", "check_params", "check_constants"):
        if msg.get(k) is not None and not isinstance(msg[k], dict):
            raise TypeError(f"verdict field {k!r} is not an object")


def _shaped(v: Any) -> bool:
    try:
        verdict_shape(v)
    except TypeError:
        return False
    return True


def _check_record(v: Any) -> bool:
    """A `/timing/verdicts` message a re-check can use: the shapes its recorder writes."""
    def whole(x: Any) -> bool:
        return isinstance(x, int) and not isinstance(x, bool)

    return (isinstance(v, dict) and whole(v.get("step")) and isinstance(v.get("spec"), str)
            and whole(v.get("check_until_ns"))
            and (v.get("check_since_ns") is None or whole(v.get("check_since_ns")))
            and isinstance(v.get("plan"), str | None)
            and all(isinstance(v.get(k) or {}, dict)
                    for k in ("binding", "check_params", "check_constants"))
            and all(type(x) is str for kv in (v.get("binding") or {}).items() for x in kv))


def recorded_checks(source: MemorySource) -> list[dict[str, Any]]:
    """The timing checks a plan run made, from its `/timing/verdicts` (one entry per plan
    step and spec): spec, binding, params, constants, since_ns, until_ns — what a faithful
    offline re-check needs."""
    seen: dict[tuple, dict[str, Any]] = {}
    damaged = 0
    for _t, v in source.messages(topics.TIMING_VERDICTS):
        if not _check_record(v) or not _shaped(v):  # not a check step's verdict, or a
            # damaged one: skipped
            if isinstance(v, dict) and "check_until_ns" in v:  # a check step's, damaged
                if not damaged:
                    logging.getLogger("hil.record").warning(
                        "%s: %s: a check step's verdict of a wrong shape skipped: %.200r",
                        getattr(source, "path", "the recording"), topics.TIMING_VERDICTS, v)
                damaged += 1
            continue
        key = (v.get("plan"), v["step"], v["spec"])
        if key not in seen:
            seen[key] = {"plan": v.get("plan"), "step": v["step"], "spec": v["spec"],
                         "binding": v.get("binding") or {}, "params": v.get("check_params") or {},
                         "constants": v.get("check_constants") or {},
                         "since_ns": v.get("check_since_ns"), "until_ns": v["check_until_ns"],
                         "judged": {}}
        status = v.get("status")  # what the run judged: a re-check must judge the same
        if status != "skipped":
            judged = seen[key]["judged"]
            judged[str(status)] = judged.get(str(status), 0) + 1
    if damaged and hasattr(source, "bad_messages"):  # counted: `hil check` is incomplete
        source.bad_messages += damaged
    return list(seen.values())


def recorded_constants(meta: Mapping[str, Mapping[str, str]]) -> dict[str, float]:
    """Spec constants the bench of the run overrode (metadata `timing`: `constants` JSON)."""
    try:
        raw = json.loads(meta.get("timing", {}).get("constants") or "{}")
        out = {str(k): float(v) for k, v in dict(raw).items()}
        if not all(map(math.isfinite, out.values())):
            raise ValueError("not a finite number")
        return out
    except (ValueError, TypeError, OverflowError, RecursionError):  # damaged: none recorded
        return {}


def infer_places(topics: Iterable[str]) -> dict[str, str]:
    """Placeholder values implied by the topics when unambiguous (one drive, one bus...)."""
    found: dict[str, set[str]] = {"drive": set(), "dio": set(), "bus": set()}
    for t in topics:
        parts = t.split("/")
        if len(parts) >= 4 and parts[1] == "drive":
            found["drive"].add(parts[2])
        elif len(parts) >= 4 and parts[1] == "dio":
            found["dio"].add(parts[2])
        elif len(parts) >= 3 and parts[1] == "canopen":
            found["bus"].add(parts[2])
    return {k: next(iter(v)) for k, v in found.items() if len(v) == 1}


class ParamTimeline:
    """Drive parameters over time: snapshot(s) from /drive/<name>/params plus overrides.

    A parameter's first value from a snapshot or a read (`"source": "read"`, what the drive
    reported when asked) also covers the times before it: the drive held that value since its
    last recorded change, and there was none. A first value from a plain change (a write, a
    `ParamChanged` event) does not, not even before the very first record (docs/timing.md)."""

    def __init__(self, changes: list[tuple[int, Mapping[str, Any]]] | None = None,
                 overrides: Mapping[str, Any] | None = None,
                 held: list[tuple[int, Mapping[str, Any]]] | None = None) -> None:
        """`changes`: (t, values) records; `held`: the records among them (snapshots,
        reads) whose values the drive held before they were taken."""
        self._times: list[int] = []
        self._states: list[dict[str, Any]] = []
        changes = sorted(changes or [], key=lambda c: c[0])
        first: dict[str, int] = {}  # name -> time of its first record
        for t, d in changes:
            for k in d:
                first.setdefault(str(k), t)
        before: dict[str, Any] = {}  # values that also hold before their first record
        for t, d in sorted(held or [], key=lambda c: c[0]):
            for k, v in d.items():
                if str(k) not in before and first.get(str(k), t) >= t:
                    before[str(k)] = v
        self._before = before  # in force before the first record
        cur: dict[str, Any] = {}
        for t, d in changes:
            cur = cur | {str(k): v for k, v in d.items()}
            if self._times and self._times[-1] == t:
                self._states[-1] = before | cur
            else:
                self._times.append(t)
                self._states.append(before | cur)
        self.overrides = dict(overrides or {})

    @classmethod
    def from_source(cls, source: SignalSource, topic: str,
                    overrides: Mapping[str, Any] | None = None) -> ParamTimeline:
        """The timeline of `topic`'s records. Built once per source and number of records
        (a plan's checks ask for it again and again while its recording grows): the records
        make the timeline, the overrides only what `at` answers."""
        msgs = source.messages(topic)
        cache = getattr(source, "_samples_cache", None)
        key = (topic, "_param_timeline")
        got = cache.get(key) if cache is not None else None
        if got is None or got[0] != len(msgs):
            got = (len(msgs), cls._from_messages(msgs))
            if cache is not None:
                cache[key] = got
        out = copy.copy(got[1])
        out.overrides = dict(overrides or {})
        return out

    @classmethod
    def _from_messages(cls, msgs: list[tuple[int, Any]]) -> ParamTimeline:
        changes, held = [], []
        for t, msg in msgs:
            # recorder payload: {"snapshot": bool, "values": {name: value}, "source": "read"}
            d = msg.get("values", msg.get("params", msg)) if isinstance(msg, Mapping) else {}
            if isinstance(d, Mapping):
                vals = {k: v for k, v in d.items() if isinstance(v, int | float)}
                changes.append((t, vals))
                if isinstance(msg, Mapping) and (msg.get("snapshot")
                                                 or msg.get("source") == "read"):
                    held.append((t, vals))
        return cls(changes, None, held)

    def names(self) -> set[str]:
        """Every parameter with a recorded value (overrides not included)."""
        return set().union(*self._states) if self._states else set()

    def at(self, t: int | None) -> dict[str, Any]:
        """Values in force at `t`; before the first record, those a snapshot or a read
        reported (held since before). `t` None: the earliest state."""
        if not self._states:
            return dict(self.overrides)
        if t is None:
            return self._states[0] | self.overrides
        i = bisect.bisect_right(self._times, t) - 1
        return (self._states[i] if i >= 0 else self._before) | self.overrides

    def change_times(self, names: Iterable[str] | None = None) -> list[int]:
        """The times of the records; with `names`, only the first and those where one of
        `names` changed (what an expression of those names can change at)."""
        if names is None:
            return list(self._times)
        names = tuple(names)
        states, out = self._states, self._times[:1]
        for i in range(1, len(states)):
            a, b = states[i - 1], states[i]
            if any(a.get(n) != b.get(n) for n in names):
                out.append(self._times[i])
        return out
