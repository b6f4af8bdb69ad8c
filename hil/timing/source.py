"""Where the checker's samples come from: in-memory lists (tests, live) or an MCAP recording.

A `SignalSource` gives, per topic, the recorded messages as (t_ns, dict) in time order, and
per topic the observation resolution in ns when it knows it (recorded sampling period or
timestamp granularity). Fields are read with dotted paths (`a.b`).
"""

from __future__ import annotations

import bisect
import fnmatch
import json
from collections.abc import Iterable, Mapping
from pathlib import Path
from typing import Any, Protocol

from hil.record import topics
from hil.record.reader import Recording, decode

_MISSING = object()


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
            where: Mapping[str, Any] | None = None) -> list[tuple[int, Any]]:
    """(t_ns, value) of `field` in `topic`, skipping messages without it or not matching
    `where` (field -> required value)."""
    cache = getattr(source, "_samples_cache", None)
    key = (topic, field, tuple(sorted((where or {}).items(), key=repr)))
    if cache is not None and key in cache:
        return cache[key]
    out = []
    append = out.append
    flat = "." not in field
    for t, msg in source.messages(topic):
        if where and any(get_field(msg, k) != v for k, v in where.items()):
            continue
        # fast path for a plain top-level field
        val = msg.get(field, _MISSING) if flat and type(msg) is dict else get_field(msg, field)
        if val is not _MISSING:
            append((t, val))
    if cache is not None:
        cache[key] = out
    return out


class MemorySource:
    """An in-memory source: `MemorySource.from_series({(topic, field): [(t, v), ...]})`."""

    def __init__(self, messages: Mapping[str, list[tuple[int, dict]]] | None = None,
                 resolutions: Mapping[str, int] | None = None) -> None:
        self._msgs: dict[str, list[tuple[int, dict]]] = {}
        for topic, lst in (messages or {}).items():
            self._msgs[topic] = sorted(lst, key=lambda m: m[0])
        self._res = dict(resolutions or {})
        self._samples_cache: dict[tuple, list[tuple[int, Any]]] = {}

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
        #: per topic, what was read but not yet decoded: (t_ns, JSON bytes), file order
        self._raw: dict[str, list[tuple[int, bytes]]] = {}
        self._raw_span: dict[str, list[int]] = {}  # per topic, [first t, last t] of `_raw`

    def _keep(self, topic: str, t: int, data: bytes) -> None:
        pend = self._raw.get(topic)
        if pend is None:
            pend = self._raw[topic] = []
            self._raw_span[topic] = [t, t]
        else:
            span = self._raw_span[topic]
            if t < span[0]:
                span[0] = t
            elif t > span[1]:
                span[1] = t
        pend.append((t, data))

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
            for t, data in pend:
                obj = decode(data)
                if last is not None and t < last:
                    ordered = False
                last = t
                lst.append((t, obj if isinstance(obj, dict) else {"value": obj}))
            if not ordered:
                lst.sort(key=lambda m: m[0])  # stable: equal times keep file order
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


class RecordingSource(_LazySource):
    """Messages of an MCAP recording, read once through `hil.record.reader.Recording`.

    `time="publish"` uses the source's own timestamps (default), `"log"` the harness's.
    Resolution per topic comes from channel metadata key `resolution_ns`, or from a metadata
    record `timing` with `resolution_ns` = JSON {topic: ns}.
    """

    def __init__(self, path: str | Path, topics: Iterable[str] | None = None,
                 time: str = "publish", until_log_ns: int | None = None) -> None:
        """`until_log_ns`: only what the harness had seen by then (re-checking a live check)."""

        if time not in ("publish", "log"):
            raise ValueError(f"time must be 'publish' or 'log', not {time!r}")
        rec = Recording.open(str(path))
        super().__init__()
        try:
            raw: dict[str, list[tuple[int, bytes]]] = {}
            wanted = list(topics) if topics is not None else None
            lag = 0  # the largest publish-to-log delay read
            for topic, log_t, pub_t, data in rec.raw_messages(topics=wanted):
                if until_log_ns is not None and log_t > until_log_ns:
                    continue
                t = pub_t if time == "publish" and pub_t else log_t
                lag = max(lag, log_t - t)
                lst = raw.get(topic)
                if lst is None:
                    lst = raw[topic] = []
                lst.append((int(t), data))
            #: a damaged file: the time (of this source's clock) up to which every message
            #: is known to have been read; what came later is dropped, so nothing is judged
            #: on a part of the recording that lost some of its messages (None: whole file)
            self.cut_ns: int | None = None
            cut = rec.cut_log_ns if rec.corrupt else None
            if cut is not None:
                self.cut_ns = cut - lag  # a message stamped this late may be in the lost chunk
                for topic, lst in raw.items():
                    raw[topic] = [m for m in lst if m[0] < self.cut_ns]
            self._keep_all(raw)
            self.meta = _metadata(rec)
            res = _resolutions(rec, self.meta)
            #: the first broken record (None if the file is whole) and whether it is damage
            #: mid-file (`corrupt`) rather than a killed run's cut tail
            self.error: str | None = rec.error
            self.corrupt: bool = rec.corrupt
            self.truncated: bool = rec.truncated  # no footer: a killed (or running) recorder
            self.schemas: set[str] = {c.schema for c in rec.channels()}
        finally:
            close = getattr(rec, "close", None)
            if close:
                close()
        self._res = dict(res)
        self.path = str(path)


class LiveSource(_LazySource):
    """The recording of a running plan, for its `check_timing` steps: each message is decoded
    at most once from the recorder's `mirror` (`Recorder.keep_messages`), so a plan's checks
    cost what its recording holds, not that times the number of checks. Decoding is lazy, per
    topic: a topic no check reads (the bus frames of statusword polling, say) is never decoded.
    `refresh(rec)` (after `rec.flush()`) takes what was written since; the file gives metadata
    and resolutions, as `RecordingSource` reads them."""

    def __init__(self) -> None:
        super().__init__()
        self._seen = 0
        self._head_key: tuple = ()
        self.meta: dict[str, dict[str, str]] = {}
        self.error: str | None = None
        self.corrupt = False
        self.truncated = True
        self.schemas: set[str] = set()
        self.path = ""

    def refresh(self, rec: Any) -> LiveSource:
        key = (len(rec.topic_of), getattr(rec, "metadata_count", None))
        if key != self._head_key or key[1] is None:  # a new channel or metadata record
            head = RecordingSource(rec.path, topics=[])  # metadata, resolutions; no messages
            self.meta, self._res = head.meta, head._res
            self.error, self.corrupt, self.truncated = head.error, head.corrupt, head.truncated
            self.schemas, self.path = head.schemas, head.path
            self._head_key = key
        mirror = rec.keep_messages()
        n = len(mirror)
        if n == self._seen:
            return self
        names = rec.topic_of
        keep = self._keep
        for cid, log_t, pub_t, data in mirror[self._seen:n]:
            keep(names.get(cid, f"?{cid}"), int(pub_t or log_t), data)
        self._seen = n
        self._samples_cache.clear()
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
        specs = list(json.loads(tm["specs"])) if tm.get("specs") else []
        binding = dict(json.loads(tm["binding"])) if tm.get("binding") else {}
    except (ValueError, TypeError):
        pass
    return [str(s) for s in specs], {str(k): str(v) for k, v in binding.items()}


def recorded_checks(source: MemorySource) -> list[dict[str, Any]]:
    """The timing checks a plan run made, from its `/timing/verdicts` (one entry per plan
    step and spec): spec, binding, params, constants, since_ns, until_ns — what a faithful
    offline re-check needs."""
    seen: dict[tuple, dict[str, Any]] = {}
    for _t, v in source.messages(topics.TIMING_VERDICTS):
        if "step" not in v or "spec" not in v or "check_until_ns" not in v:
            continue
        key = (v.get("plan"), v["step"], v["spec"])
        if key not in seen:
            seen[key] = {"plan": v.get("plan"), "step": v["step"], "spec": v["spec"],
                         "binding": v.get("binding") or {}, "params": v.get("check_params") or {},
                         "constants": v.get("check_constants") or {},
                         "since_ns": v.get("check_since_ns"), "until_ns": v["check_until_ns"]}
    return list(seen.values())


def recorded_constants(meta: Mapping[str, Mapping[str, str]]) -> dict[str, float]:
    """Spec constants the bench of the run overrode (metadata `timing`: `constants` JSON)."""
    try:
        raw = json.loads(meta.get("timing", {}).get("constants") or "{}")
        return {str(k): float(v) for k, v in dict(raw).items()}
    except (ValueError, TypeError):
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
    `ParamChanged` event) does not; the earliest state still covers times before the first
    record."""

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
        changes, held = [], []
        for t, msg in source.messages(topic):
            # recorder payload: {"snapshot": bool, "values": {name: value}, "source": "read"}
            d = msg.get("values", msg.get("params", msg)) if isinstance(msg, Mapping) else {}
            if isinstance(d, Mapping):
                vals = {k: v for k, v in d.items() if isinstance(v, int | float)}
                changes.append((t, vals))
                if isinstance(msg, Mapping) and (msg.get("snapshot")
                                                 or msg.get("source") == "read"):
                    held.append((t, vals))
        return cls(changes, overrides, held)

    def names(self) -> set[str]:
        """Every parameter with a recorded value (overrides not included)."""
        return set().union(*self._states) if self._states else set()

    def at(self, t: int | None) -> dict[str, Any]:
        """Values in force at `t` (the earliest state also covers times before it)."""
        if not self._states:
            return dict(self.overrides)
        i = 0 if t is None else max(0, bisect.bisect_right(self._times, t) - 1)
        return self._states[i] | self.overrides

    def change_times(self) -> list[int]:
        return list(self._times)
