"""What a report shows, read from a recording alone (`load_run(path) -> RunData`)."""

from __future__ import annotations

import datetime
import json
from bisect import bisect_left, bisect_right
from collections.abc import Iterable, Iterator, Mapping, Sequence
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

from hil.record import topics
from hil.record.reader import Recording, decode, decode_record, repaired_cut
from hil.timing.source import MISSING_FIELD, ColumnTable, verdict_shape


@dataclass
class StepData:
    index: int
    label: str
    kind: str = ""
    line: int = 0
    file: str = ""
    drive: str = ""
    status: str = "skipped"
    message: str = ""
    t_start: int | None = None
    t_end: int | None = None
    duration_ns: int = 0


@dataclass
class RunData:
    path: str
    plan: str
    bench: str
    status: str
    steps: list[StepData] = field(default_factory=list)
    verdicts: list[dict] = field(default_factory=list)
    safety: list[dict] = field(default_factory=list)
    logs: list[dict] = field(default_factory=list)
    metadata: dict[str, dict[str, str]] = field(default_factory=dict)
    attachments: dict[str, str] = field(default_factory=dict)
    params: dict[str, dict[str, Any]] = field(default_factory=dict)  # drive -> values
    truth: dict[str, TruthSamples] = field(default_factory=dict)  # drive -> states
    truth_fields: frozenset[str] | None = None  # the state fields kept (None: all)
    # (t, topic, msg): msg as recorded bytes (decoded when shown, `_decode`) or a dict
    bus: list[tuple[int, str, bytes | dict]] = field(default_factory=list)
    bus_pending: bool = False  # the recording has bus messages not read yet (`bus_of`)
    bus_source_t: list[int] = field(default_factory=list)  # publish time of each bus entry
    # the file position (message ordinal) of each bus entry, and of each step's start and
    # end record: a step's bus log is what was written between the two (`bus_log`)
    bus_k: list[int] = field(default_factory=list)
    step_k: dict[int, list[int | None]] = field(default_factory=dict)
    truncated: bool = False
    #: the first unreadable record of a file damaged mid-file (not a killed run's cut end)
    damage: str | None = None
    #: why the status is not the one `hil.result` gives: an unknown status, or a result of
    #: pass that the recording's own failing steps or verdicts contradict ("" when none)
    status_note: str = ""
    bad_messages: int = 0  # records of a wrong shape the report skipped (a warning names one)
    t0: int = 0  # the plan start (first plan step event), else the first message: time zero

    def first_failure(self) -> StepData | None:
        """The first step that did not pass (nor was skipped), None if there is none."""
        return next((s for s in self.steps if s.status not in ("pass", "skipped")), None)

    def step(self, index: object) -> StepData | None:
        """The step with this index (a verdict's `step`), None if unknown."""
        return next((s for s in self.steps if s.index == index), None)

    def info(self) -> dict[str, str]:
        """Where and what ran: run date (UTC), hil version, host, bench, clock, git revision."""
        return run_info(self.metadata, self.bench)


def started_ns(run: Mapping[str, Any]) -> int:
    """`hil.run.started_ns` as ns; 0 when missing or damaged (text, more than 20 digits)."""
    t = str(run.get("started_ns") or "0")
    return int(t) if t.isascii() and t.isdigit() and len(t) <= 20 else 0


def run_info(meta: dict[str, dict[str, str]], bench: str = "") -> dict[str, str]:
    """The run's identity from a recording's metadata (`hil.run`, `hil.versions`)."""

    run, ver = meta.get("hil.run", {}), meta.get("hil.versions", {})
    date = "?"
    started = started_ns(run)
    if started:
        try:
            date = datetime.datetime.fromtimestamp(started / 1e9, datetime.UTC
                                                   ).strftime("%Y-%m-%d %H:%M:%S UTC")
        except (OverflowError, OSError, ValueError):  # past year 9999: a damaged record
            date = "?"
    out = {"date": date, "hil": ver.get("hil", "?"), "host": run.get("host", "?"),
           "bench": bench or run.get("bench", "?"),
           # the bench's clock (`hil.clock`): a virtual-time PASS is not a wall-clock one
           "clock": str(meta.get("hil.clock", {}).get("clock") or "?"),
           "git": ver.get("git_revision", "?"),
           "dut": dut_text(meta.get("hil.dut", {}))}
    try:  # the model's deviation knobs in effect: a reviewer must see them at once
        dev = json.loads(str(meta.get("hil.bench", {}).get("deviations") or "[]"))
    except (ValueError, RecursionError):
        dev = []
    if isinstance(dev, list) and dev:
        out["deviations"] = ", ".join(str(x) for x in dev)
    return out


def dut_text(dut: dict[str, str]) -> str:
    """The drives under test in one line: `drive1 fw 100, 1018h 000001DD/00006000/00000000`."""
    drives: dict[str, dict[str, str]] = {}
    for key, value in dut.items():
        name, _, field = key.rpartition(".")
        drives.setdefault(name, {})[field] = value
    parts = []
    for name, f in drives.items():
        text = f"{name} fw {f.get('firmware', '?')}"
        ident = [f.get(k, "") for k in ("vendor_id", "product_code", "revision", "serial")]
        ident = [x.removeprefix("0x") for x in ident if x and x != "unavailable"]
        if ident:
            text += " 1018h " + "/".join(ident)
        parts.append(text)
    return ", ".join(parts) or "?"


_STEP_TEXT = ("step", "kind", "drive", "file", "status", "message", "event")


def _number(x: Any) -> bool:
    return isinstance(x, int | float) and not isinstance(x, bool)


TEXT_KEPT = 4096  # characters of one text a page shows (a step message, a log line)


def clip(text: str) -> str:
    """`text`, or its first TEXT_KEPT characters and how many more there were: a recording
    whose messages hold 10 MB texts (1000:1 under zstd) made a 140 MB page (helper-137)."""
    if len(text) <= TEXT_KEPT:
        return text
    return f"{text[:TEXT_KEPT]}… ({len(text) - TEXT_KEPT:,} more characters not shown)"


def _clipped(msg: dict) -> dict:
    return {k: clip(v) if type(v) is str else v for k, v in msg.items()}


def _step_shape(msg: dict) -> None:
    """TypeError for a /plan/steps record the page cannot show (a reader skips and counts
    it as a message of the wrong shape): a text field that is not text."""
    for k in _STEP_TEXT:
        if msg.get(k) is not None and not isinstance(msg[k], str):
            raise TypeError(f"/plan/steps field {k!r} is {type(msg[k]).__name__}, not text")


def _is_bus(topic: str) -> bool:
    return (topic.startswith("/canopen/") or topic.startswith("/modbus/")
            or topic.startswith("/dio/") or topic.startswith("/can/"))


_RUNS: dict[tuple[str, int, int], RunData] = {}
# the same without the ground truth: what a run's JUnit and index read of every plan
_SUMMARIES: dict[tuple[str, int, int], RunData] = {}
_SUMMARIES_KEPT = 256


def forget(path: str | Path) -> None:
    """Drop what is kept of `path` (a recorder is about to write it again: the new file could
    have the old one's size within one mtime tick)."""
    name = str(Path(path).resolve())
    for cache in (_RUNS, _SUMMARIES):
        for key in [k for k in cache if k[0] == name]:
            del cache[key]


def _file_key(path: str | Path) -> tuple[str, int, int] | None:
    """What a kept read of `path` is filed under: resolved path, mtime and size."""
    try:
        st = Path(path).stat()
    except OSError:
        return None
    return str(Path(path).resolve()), st.st_mtime_ns, st.st_size


def kept_summary(path: str | Path) -> tuple[tuple[str, int, int], RunData] | None:
    """The summary (`truth=False` read) kept of `path` as it is on disk now, with its key;
    None if none is kept. A `hil run` worker hands it to the parent with the plan's result."""
    key = _file_key(path)
    if key is None or key not in _SUMMARIES:
        return None
    return key, _SUMMARIES[key]


def keep_summary(key: tuple[str, int, int], data: RunData) -> bool:
    """Keep a summary read in another process (a worker's `kept_summary`), if the file is
    still the one it was read from (same path, mtime and size); True if kept. The run's JUnit
    and index then read no recording again."""
    if _file_key(key[0]) != key:
        return False
    while len(_SUMMARIES) >= _SUMMARIES_KEPT:
        del _SUMMARIES[next(iter(_SUMMARIES))]
    _SUMMARIES[key] = data
    return True


def load_run(path: str | Path, *, truth: bool = True,
             messages: Iterable[tuple[str, int, int, bytes | dict]] | None = None) -> RunData:
    """The report's view of a recording; the last two files read are kept (by path, size and
    mtime), so a plan's JUnit and HTML report read its recording once. `truth=False`: without
    the ground-truth samples (`truth` stays empty), for what shows no plot (the run's JUnit and
    index); those are kept for the last 256 recordings read, so a run's end reads no file
    again."""
    key = _file_key(path)
    if key is not None:
        if key in _RUNS:
            return _RUNS[key]
        if not truth and key in _SUMMARIES:
            return _SUMMARIES[key]
    data = _load_run(path, truth=truth, messages=messages)
    if key is not None:
        if truth:
            while len(_RUNS) >= 2:
                del _RUNS[next(iter(_RUNS))]
            _RUNS[key] = data
        while len(_SUMMARIES) >= _SUMMARIES_KEPT:
            del _SUMMARIES[next(iter(_SUMMARIES))]
        _SUMMARIES[key] = replace(data, truth={}, bus=[]) if truth else data
    return data


def _load_run(path: str | Path, *, truth: bool = True,
              messages: Iterable[tuple[str, int, int, bytes | dict]] | None = None) -> RunData:
    """Read `path` twice, neither time holding the file or its chunks: first its metadata
    outside the chunks (which fields of the ground truth to keep), then each message as it
    comes (a recording of any length costs what the report keeps of it). What the report
    says of the file (metadata, attachments, cut or whole) is what that second, full read
    found, as `Recording.open` would. `messages`: the recording's messages as its recorder
    wrote them ((topic, log time, publish time, bytes or their decoded dict), in file
    order), taken instead of the second read when the file's head says it is whole (the
    runner's own report of a recording it has just closed)."""
    head = Recording.head(path)
    keep = truth_fields(_spec_ids(head.metadata()))
    data = RunData(str(path), Path(path).stem, "?", "", truth_fields=keep)
    steps: dict[int, StepData] = {}
    t_first: int | None = None
    t_plan: int | None = None

    kinds: dict[str, str] = {}  # topic -> what `take` does with it, worked out once

    def kind_of(topic: str) -> str:
        if topic.startswith("/can/"):
            return "skip"  # raw frames: /canopen/<bus> has them decoded
        if _is_bus(topic):  # read again when shown: only failing checks and steps show them
            return "bus"
        if topic in (topics.PLAN_STEPS, topics.TIMING_VERDICTS, topics.SAFETY, topics.LOG):
            return topic
        if topic.startswith("/drive/") and topic.endswith("/state"):
            return "state" if truth else "skip"  # a summary: no ground truth, not decoded
        if topic.startswith("/drive/") and topic.endswith("/params"):
            return "params"
        return "skip"  # nothing on the page reads it: never decoded

    def take(topic: str, lt: int, pt: int, raw: bytes) -> None:
        nonlocal t_first, t_plan
        t_first = lt if t_first is None else min(t_first, lt)
        kind = kinds.get(topic)
        if kind is None:
            kind = kinds[topic] = kind_of(topic)
        if kind == "skip":
            return
        if kind == "bus":
            data.bus_pending = True
            return
        if kind == "state":
            d = topic.split("/")[2]
            samples = data.truth.get(d)
            if samples is None:
                samples = data.truth[d] = TruthSamples(keep)
            samples.add(pt or lt, raw)
            return
        msg = decode_record(raw, topic)
        if kind == topics.PLAN_STEPS:
            _step_shape(msg)
            t_plan = lt if t_plan is None else min(t_plan, lt)
            idx = int(msg.get("index") if msg.get("index") is not None else -1)
            sd = steps.setdefault(idx, StepData(idx, clip(str(msg.get("step", "")))))
            sd.kind = msg.get("kind", sd.kind) or sd.kind
            sd.line = int(msg.get("line") or sd.line or 0)
            sd.drive = msg.get("drive", sd.drive) or sd.drive
            sd.file = msg.get("file", sd.file) or sd.file
            if msg.get("event") == "start":
                sd.t_start = lt
            else:
                sd.t_end = lt
                sd.status = msg.get("status") or sd.status
                sd.message = clip(msg.get("message") or "")
                sd.duration_ns = int(msg.get("duration_ns") or 0)
        elif kind == topics.TIMING_VERDICTS:
            verdict_shape(msg)
            data.verdicts.append({**_clipped(msg), "_t": lt})
        elif kind == topics.SAFETY:
            data.safety.append({**_clipped(msg), "_t": lt})
        elif kind == topics.LOG:
            data.logs.append({**_clipped(msg), "_t": lt})
        else:  # params
            d = topic.split("/")[2]
            data.params.setdefault(d, {}).update(msg.get("values") or {})

    if messages is not None and not head.truncated and not head.error:
        for topic, lt, pt, raw in messages:
            take(topic, lt, pt, raw)
        rec = head
    else:
        rec = Recording.stream(path, None, take)
    for samples in data.truth.values():
        samples.finish()
    data.metadata = meta = rec.metadata()
    # a repaired copy of a cut or damaged run is as cut as its source (the footer is new)
    data.truncated = rec.truncated or repaired_cut(meta) is not None
    data.bad_messages = getattr(rec, "bad_messages", 0)
    if rec.corrupt:
        data.damage = rec.error or "a record could not be read"
    elif (rep := meta.get("hil.repair", {})).get("source_damaged") == "true":
        data.damage = f"repaired from a damaged recording: {rep.get('source_error') or '?'}"
    run_meta = meta.get("hil.run", {})
    data.plan = run_meta.get("plan", data.plan)
    # a pytest test's recording names its bench only in `hil.bench`
    data.bench = run_meta.get("bench") or meta.get("hil.bench", {}).get("name") or data.bench
    data.status = meta.get("hil.result", {}).get("status", "")
    for bad in rec.bad_attachments:  # "'plan.yaml' at offset 1572: CRC mismatch"
        name, _, why = bad.partition(" at offset ")
        data.attachments[name.strip("'\"")] = f"<damaged at offset {why}; not shown>"
    for a in rec.attachments():
        try:
            data.attachments[a.name] = a.data.decode("utf-8")
        except UnicodeDecodeError:
            data.attachments[a.name] = f"<{len(a.data)} bytes>"
    data.t0 = t_plan or t_first or 0
    ended = bool(meta.get("hil.result"))  # the run closed its recording: only the file is cut
    if data.truncated:  # killed, damaged, or a run whose file lost its tail
        for sd in steps.values():  # a step the file has starting and not ending
            if sd.t_start is not None and sd.t_end is None and sd.status == "skipped":
                sd.status = "error"
                sd.message = ("cut short: the recording is damaged while it ran (what "
                              "followed could not be read)" if data.damage else
                              "cut short: the recording's tail is lost (the run ended; how "
                              "this step did was not kept)" if ended else
                              "cut short: the recording ends while it ran (the run was killed)")
        try:  # the plan's steps the file does not hold are said, not left out
            total = int(meta.get("hil.plan", {}).get("steps", 0))
        except (TypeError, ValueError):
            total = 0
        for k in range(min(total, 10_000)):
            steps.setdefault(k, StepData(k, "(not reached)", message=(
                "not shown: the recording is damaged before it" if data.damage else
                "not shown: the recording's tail is lost" if ended else
                "not reached: the recording ends before it")))
    data.steps = [steps[k] for k in sorted(steps)]
    if not data.status:
        bad = [s for s in data.steps if s.status not in ("pass", "skipped")]
        data.status = "fail" if bad else ("pass" if data.steps else "unknown")
        if data.truncated:  # no result: killed (cut short), or its end unreadable (damaged:
            data.status = "incomplete" if data.damage else "aborted"  # how it ended is unknown)
    elif data.truncated and data.status == "pass":  # the run passed; the file holds part of it
        data.status = "incomplete"
    _reconcile_status(data)
    return data


# what a timing verdict's status can be (hil.timing.checker.Verdict)
VERDICT_STATUSES = frozenset({"pass", "fail", "inconclusive", "skipped"})
# what a plan run's `hil.result` status can be (hil.plan.runner), and what the report adds
PLAN_STATUSES = frozenset({"pass", "fail", "error", "skipped", "aborted", "inconclusive",
                           "incomplete", "unknown"})


def _reconcile_status(data: RunData) -> None:
    """A recording whose result says what no run says (an unknown status) is an error; one
    whose result says pass while its own steps or verdicts failed is a failure: the page and
    the JUnit never show such a file as passed (a hand-edited or damaged metadata record)."""
    if data.status not in PLAN_STATUSES:
        data.status_note = (f"the recording's result status {data.status[:40]!r} is not a "
                            "plan status")
        data.status = "error"
        return
    said = data.metadata.get("hil.result", {}).get("status", "")
    if said != "pass" or data.status not in ("pass", "incomplete"):
        return
    # (a step the reader marked "cut short" is the file's loss, not the run's failure)
    step = next((s for s in data.steps if s.status in ("fail", "error")
                 and not s.message.startswith("cut short")), None)
    verdict = next((v for v in data.verdicts if v.get("status") == "fail"), None)
    odd = next((v for v in data.verdicts if v.get("status") not in VERDICT_STATUSES), None)
    if step is not None:
        why = f"step {step.index + 1} {step.label} {step.status}"
    elif verdict is not None:
        why = (f"timing verdict {verdict.get('spec', '?')}: {verdict.get('constraint', '?')} "
               "fail")
    elif odd is not None:  # "FAIL", "failed", "maybe": no checker wrote it (helper-137)
        data.status_note = (
            f"the recording's result says {said}, but timing verdict {odd.get('spec', '?')}: "
            f"{odd.get('constraint', '?')} has the status {str(odd.get('status'))[:40]!r}, "
            f"not one of {', '.join(sorted(VERDICT_STATUSES))}")
        data.status = "error"
        return
    else:
        return
    data.status_note = f"the recording's result says {said}, but {why}"
    data.status = "fail"


# the ground-truth fields the motion plot draws (html._plot)
PLOT_FIELDS = frozenset({"position_counts", "position", "pos", "speed_rpm", "velocity", "vel",
                         "torque_pct", "torque"})
_BASE_FIELDS = frozenset({"t", "periodic", "alarms", *PLOT_FIELDS})


def truth_fields(spec_ids: list[str] | None) -> frozenset[str] | None:
    """What a report keeps of each ground-truth sample: the plot's fields, `t`, `periodic`,
    `alarms`, and the state fields the recording's timing specs read (the ids its `timing`
    metadata lists). None (keep every field) when they are not known or not shipped."""
    if not spec_ids:
        return None
    from hil.timing.checker import state_fields
    from hil.timing.registry import load_spec_cached
    from hil.timing.spec import shipped_specs
    out = set(_BASE_FIELDS)
    shipped = {p.stem: p for p in shipped_specs()}
    for sid in spec_ids:
        path = shipped.get(sid)  # a shipped id only, never a path the recording names
        if path is None:
            return None
        try:
            out |= state_fields(load_spec_cached(path))
        except Exception:
            return None
    return frozenset(out)


def _spec_ids(meta: dict[str, Any]) -> list[str] | None:
    try:
        ids = json.loads(meta.get("timing", {}).get("specs", "null"))
    except (TypeError, ValueError, RecursionError):
        return None
    return [str(i) for i in ids] if isinstance(ids, list) else None


_NOISE = {"raw", "adu", "mode", "role", "data_hex", "frame"}
# ids and object indexes as CANopen people read them: 601h, 6040h (CiA 301 notation)
_HEX = {"cob_id": 3, "index": 4, "node": 0, "abort": 8, "code": 4, "error_code": 4}


def _value(key: str, v: object) -> str:
    if key in _HEX and isinstance(v, int) and not isinstance(v, bool):
        return f"{v:0{_HEX[key]}X}h" if _HEX[key] else str(v)
    return json.dumps(v, default=str) if isinstance(v, dict | list) else str(v)


def _brief(msg: dict, width: int = 600) -> str:
    """One readable line per bus message: its own text if any, else `key=value` pairs."""
    text = msg.get("text") or msg.get("summary")
    adu = msg.get("adu")
    if not text and isinstance(adu, dict):  # a decoded Modbus ADU (hil.record topics)
        text = f"{msg.get('dir', '')} {adu.get('function_name') or adu.get('function')}"
        if adu.get("address") is not None:
            text += f" at {adu['address']:04X}h"
        if adu.get("values"):
            text += f" values {adu['values']}"
        if adu.get("exception") is not None:
            text += f" EXCEPTION {adu['exception']:02X}h {adu.get('exception_name') or ''}"
        if msg.get("rtt_us"):
            text += f" (rtt {msg['rtt_us'] / 1000:.1f} ms)"
        text += f"  [{adu.get('raw', '')}]"
    if not text:
        parts = []
        for k, v in msg.items():
            if k in _NOISE or v in (None, "", [], {}):
                continue
            parts.append(f"{k}={_value(k, v)}")
        text = " ".join(parts)
    text = str(text)
    return text if len(text) <= width else text[: width - 1] + "…"


class TruthSamples(Sequence):
    """A drive's ground-truth states as (t, dict) samples, held as columns (`ColumnTable`):
    a long recording's hundreds of thousands of samples in memory that grows with the
    changes of the kept fields (about 8 bytes a changing field a sample), not with a dict
    a sample (some 640 bytes each). Indexing and iterating rebuild the dicts as they go."""

    def __init__(self, keep: frozenset[str] | None) -> None:
        self.table = ColumnTable(None if keep is None else set(keep))
        self._last: bytes | None = None

    def add(self, t: int, raw: bytes | dict) -> None:
        if isinstance(raw, bytes | bytearray):
            if raw == self._last and len(self.table):  # a repeated state: only its time
                self.table.add_again(t)
                return
            self._last = bytes(raw)
        else:
            self._last = None
        self.table.add(t, _decode(raw))

    def finish(self) -> None:
        self.table.finish()
        self._last = None

    def __len__(self) -> int:
        return len(self.table)

    def _row(self, i: int) -> tuple[int, dict]:
        msg = {}
        for name, col in self.table.cols.items():
            k = bisect_right(col.starts, i) - 1
            if k >= 0 and (v := col.values[k]) is not MISSING_FIELD:
                msg[name] = v
        return self.table.times[i], msg

    def __getitem__(self, i: Any) -> Any:
        if isinstance(i, slice):
            return [self._row(j) for j in range(*i.indices(len(self)))]
        n = len(self)
        if not -n <= i < n:
            raise IndexError(i)
        return self._row(i % n)

    def column(self, name: str) -> list[Any] | None:
        """One field's value at every sample (MISSING_FIELD where a sample lacks it), None if
        no sample has it."""
        col = self.table.cols.get(name)
        return None if col is None else col.value_list(len(self.table))

    def __iter__(self) -> Iterator[tuple[int, dict]]:
        n = len(self.table)
        cols = [(name, col.value_list(n)) for name, col in self.table.cols.items()]
        for i, t in enumerate(self.table.times):
            yield t, {name: vals[i] for name, vals in cols if vals[i] is not MISSING_FIELD}


def _decode(raw: bytes | dict) -> dict:
    """A message's JSON (bus entries are kept as bytes until a report shows them)."""
    if isinstance(raw, dict):
        return raw
    obj = decode(raw)
    return obj if isinstance(obj, dict) else {"value": obj}


def bus_of(run: RunData) -> list[tuple[int, str, bytes | dict]]:
    """The run's bus messages (CANopen, Modbus, DI/DO) in time order, read from the
    recording the first time a report shows them (a passing run never needs them)."""
    if run.bus_pending:
        run.bus_pending = False
        entries: list[tuple[int, str, bytes, int, int]] = []
        k = 0

        def take(topic: str, lt: int, pt: int, raw: bytes) -> None:
            nonlocal k
            k += 1
            if _is_bus(topic) and not topic.startswith("/can/"):
                entries.append((lt, topic, bytes(raw), pt or lt, k))
            elif topic == topics.PLAN_STEPS:
                _step_mark(run, raw, k)

        Recording.stream(run.path, None, take)  # a message at a time, not the whole file
        entries.sort(key=lambda e: e[0])  # stable: one instant's messages in file order
        run.bus = [(lt, topic, raw) for lt, topic, raw, _pt, _k in entries]
        run.bus_source_t = [e[3] for e in entries]
        run.bus_k = [e[4] for e in entries]
    return run.bus


def _step_mark(run: RunData, raw: bytes, k: int) -> None:
    """Note where step `index`'s start or end record lies in the file."""
    try:
        rec = json.loads(raw)
        index, event = int(rec["index"]), rec["event"]
    except (ValueError, TypeError, KeyError):
        return  # a damaged record: that step's log falls back on its times
    marks = run.step_k.setdefault(index, [None, None])
    if event == "start":
        marks[0] = k
    elif event == "end":
        marks[1] = k


def bus_log(run: RunData, step: StepData, limit: int = 200) -> list[tuple[int, str, str]]:
    """Decoded bus messages (CANopen, Modbus, DI/DO) seen during one step: those written
    between its start and end records. (By time alone, a step's log also took the answer to
    a request made before it and the safe state's first frames after it, logged at the
    same instant as its start or end.)"""
    if step.t_start is None:
        return []
    end = step.t_end if step.t_end is not None else 2**63
    out = []
    bus = bus_of(run)
    k0, k1 = run.step_k.get(step.index) or (None, None)
    if k0 is not None and run.bus_k:
        ks = run.bus_k
        last = k1 if k1 is not None else 2**63
        for i, (t, topic, msg) in enumerate(bus):
            if k0 < ks[i] < last:
                out.append((t, topic, _brief(_decode(msg))))
                if len(out) >= limit:
                    break
        return out
    for t, topic, msg in bus:
        if step.t_start <= t <= end:
            out.append((t, topic, _brief(_decode(msg))))
            if len(out) >= limit:
                break
    return out


def verdict_times(v: dict) -> tuple[int, int] | None:
    """(first, last) instant a verdict looked at: its reference and observed edges."""
    ts = [int(v[k]) for k in ("from_ns", "to_ns", "t_ns") if isinstance(v.get(k), int)]
    return (min(ts), max(ts)) if ts else None


def bus_around(run: RunData, v: dict, before: int = 12, after: int = 12,
               margin_ns: int = 20_000_000, limit: int = 300) -> list[tuple[int, str, str, bool]]:
    """The bus messages (CANopen, Modbus, DI/DO) around a judged constraint: every message
    between its reference and observed instants (+- `margin_ns`), and at least `before` /
    `after` messages either side. (t, topic, text, inside) with `inside` True for messages
    within the judged interval itself. `t` is on the checker's clock too (the source's
    publish time, which for model-driven lines precedes the harness's log time), so the
    times shown are those the verdict and its diagram give; the rows are in that order."""
    span = verdict_times(v)
    if span is None or not bus_of(run):
        return []
    lo, hi = span
    times = [t for t, _topic, _msg in run.bus]
    i = min(bisect_left(times, lo - margin_ns), max(0, bisect_left(times, lo) - before))
    j = max(bisect_right(times, hi + margin_ns), bisect_right(times, hi) + after)
    src = run.bus_source_t or times
    rows = [(src[k], topic, _brief(_decode(msg)), lo <= src[k] <= hi)
            for k, (_t, topic, msg) in enumerate(run.bus[i:j][:limit], start=i)]
    rows.sort(key=lambda r: r[0])  # stable: frames of one instant keep the wire's order
    return rows
