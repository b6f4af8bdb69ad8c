"""The recorder: every bus crossing and harness event into one MCAP file.

Callers (transports, faces, runner) only append a named item (hil/record/queue_items.py)
to a bounded queue; one writer
thread encodes, decodes (CANopen, Modbus), pairs transactions and writes. The writer closes
the open chunk at least every `flush_interval` s, so a `kill -9` loses at most that tail.
A full queue never blocks the caller: the item is dropped and counted (`Recorder.drops`,
and `drops` in the `hil.close` metadata record).
"""

from __future__ import annotations

import dataclasses
import enum
import functools
import importlib
import json
import logging
import os
import platform
import subprocess
import sys
import threading
import time
from binascii import hexlify
from collections import Counter, deque
from collections.abc import Callable, Mapping
from functools import cache
from importlib.metadata import PackageNotFoundError, version
from pathlib import Path
from typing import IO, Any

from hil import clock
from hil.protocol.canopen import PdoMaps
from hil.record import topics
from hil.record.mcapio import McapWriter
from hil.record.modbus_pairing import AduAssembler, ModbusPairing, guess_mode
from hil.record.queue_items import (
    AttachItem,
    BarrierItem,
    BytesItem,
    CanItem,
    MetadataItem,
    SerialItem,
)
from hil.record.schemas import SCHEMA_BYTES, schema_for_topic
from hil.record.sdo_pairing import SdoPairing, signed_parameter_objects

log_ = logging.getLogger(__name__)
# foxglove.LogLevel 1-5 -> logging levels (the same line also goes to Python logging)
_STD_LEVELS = {1: logging.DEBUG, 2: logging.INFO, 3: logging.WARNING, 4: logging.ERROR,
               5: logging.CRITICAL}

#: Values of the `publish_time_source` channel metadata key.
SOURCES = ("model", "adapter", "gateway", "harness")
VERDICT_STATUSES = ("pass", "fail", "inconclusive")
_LOG_NAMES = {"debug": 1, "info": 2, "warning": 3, "warn": 3, "error": 4, "fatal": 5, "critical": 5}
_DIRS = {"rx": "rx", "tx": "tx"}
_CAN_FMT = '{"id":%d,%s,"dlc":%d,"data":"%s","dir":"%s"}'
_J = ("false", "true")
# "ext".."esi" pre-formatted for every flag combination (hot path: one dict lookup)
_FLAGS = {
    (a, b, c, d, e, f): f'"ext":{_J[a]},"rtr":{_J[b]},"err":{_J[c]},"fd":{_J[d]},'
    f'"brs":{_J[e]},"esi":{_J[f]}'
    for a in (False, True)
    for b in (False, True)
    for c in (False, True)
    for d in (False, True)
    for e in (False, True)
    for f in (False, True)
}
_DECODE_CACHE_MAX = 4096


def _default(o: Any) -> Any:
    """json.dumps fallback: enums by name, bytes as hex, dataclasses as dicts, else str."""
    if isinstance(o, enum.Enum):
        return o.name
    if isinstance(o, bytes | bytearray | memoryview):
        return bytes(o).hex()
    if dataclasses.is_dataclass(o) and not isinstance(o, type):
        return dataclasses.asdict(o)
    if isinstance(o, set | frozenset | tuple):
        return list(o)
    return str(o)


# no circular-reference bookkeeping: a payload that contains itself ends in RecursionError,
# which `dumps` turns into an `error` object like any unencodable payload
_enc = json.JSONEncoder(separators=(",", ":"), default=_default, allow_nan=True,
                        check_circular=False).encode


def dumps(obj: Any) -> bytes:
    """Compact JSON bytes; never raises (unencodable input becomes an `error` object)."""
    return dumps_checked(obj)[0]


def dumps_checked(obj: Any) -> tuple[bytes, bool]:
    """`dumps(obj)`, and False where that is the `error` object instead of `obj`'s JSON."""
    try:
        return _enc(obj).encode(), True
    except (ValueError, TypeError, RecursionError) as exc:
        return _enc({"error": f"unencodable payload: {exc}"}).encode(), False


_SCALARS = frozenset((str, int, float, bool, type(None)))
_PLAIN = _SCALARS | {list}
_STR = frozenset((str,))
_BIG = 10**4000  # an int this long may exceed Python's int-to-str digit limit


def json_plain(payload: dict, encoded: bool = False) -> dict | None:
    """A copy of `payload` (its lists copied too) when decoding `dumps(payload)` gives back
    exactly that, types included: string keys, and values that are str, int, float, bool,
    None or lists of those (not an enum, a tuple or an int subclass, which JSON would turn
    into something else, nor an int too long to encode). None otherwise. `encoded`: `dumps`
    gave `payload`'s own JSON (`dumps_checked`), so every int in it has a decimal form."""
    if not set(map(type, payload)) <= _STR:
        return None
    types = set(map(type, payload.values()))
    if not types <= _PLAIN:
        return None
    out = payload.copy()
    if list in types:
        for k, v in out.items():
            if type(v) is list:
                if not set(map(type, v)) <= _SCALARS:
                    return None
                out[k] = v = v.copy()
                if not encoded and int in set(map(type, v)) and not all(
                        -_BIG < x < _BIG for x in v if type(x) is int):
                    return None
    if not encoded and int in types and not all(
            -_BIG < v < _BIG for v in out.values() if type(v) is int):
        return None
    return out


@cache
def versions() -> dict[str, str]:
    """Versions of the stack and the git revision of the hil checkout (if any)."""

    out = {"python": platform.python_version(), "platform": platform.platform()}
    for key, dist in (
        ("hil", "hil"),
        ("python-can", "python-can"),
        ("canopen", "canopen"),
        ("pymodbus", "pymodbus"),
        ("zenoh", "eclipse-zenoh"),
        ("mcap", "mcap"),
    ):
        try:
            out[key] = version(dist)
        except PackageNotFoundError:
            out[key] = "not installed"
    root = Path(__file__).resolve().parents[2]
    try:
        rev = subprocess.run(
            ["git", "-C", str(root), "rev-parse", "HEAD"],
            capture_output=True,
            text=True,
            timeout=2,
            check=False,
        )
        out["git_revision"] = rev.stdout.strip() if rev.returncode == 0 else "unknown"
    except (OSError, subprocess.SubprocessError):
        out["git_revision"] = "unknown"
    if out["git_revision"] != "unknown":  # the code, drive data or plans differ from it
        try:  # (new files too; no index lock taken: several runs may ask at once)
            dirty = subprocess.run(
                ["git", "--no-optional-locks", "-C", str(root), "status", "--porcelain",
                 "--untracked-files=normal", "--", "hil", "fixtures", "plans"],
                capture_output=True, text=True, timeout=2, check=False)
            if dirty.returncode == 0 and dirty.stdout.strip():
                out["git_revision"] += "+dirty"
        except (OSError, subprocess.SubprocessError):
            pass  # the revision stands; whether it is clean is unknown
    return out


def _load(module: str, attr: str) -> tuple[Callable | None, str]:
    try:
        fn = getattr(importlib.import_module(module), attr)
    except ImportError as exc:
        return None, f"missing ({exc})"
    except AttributeError:
        return None, f"missing ({module} has no {attr})"
    except Exception as exc:  # a broken decoder module must not stop the recording
        return None, f"failed to import: {exc!r}"
    return fn, f"{module}.{attr}"


def _str_map(d: Mapping[str, Any]) -> dict[str, str]:
    return {str(k): v if isinstance(v, str) else dumps(v).decode() for k, v in d.items()}


def _plain(d: Any) -> dict:
    """A dict copy of a mapping or dataclass instance (events keep their class as `type`)."""
    if type(d) is dict:  # the common case first (a state sample at 1 kHz)
        return d.copy()
    if dataclasses.is_dataclass(d) and not isinstance(d, type):
        out = {"type": type(d).__name__}
        out.update({f.name: getattr(d, f.name) for f in dataclasses.fields(d)})
        return out
    if isinstance(d, Mapping):
        return dict(d)
    raise TypeError(f"expected a dict or dataclass instance, got {type(d).__name__}")


class Recorder:
    """MCAP recorder implementing the transport `Tap` protocol plus harness events.

    Thread-safe: every public method may be called from any thread. Times are integer ns;
    `t` defaults to `time.time_ns()`.
    """

    def __init__(
        self,
        path: str | os.PathLike | IO[bytes],
        *,
        metadata: Mapping[str, Any] | None = None,
        chunk_size: int = 64 * 1024,
        flush_interval: float = 0.05,
        compression: str = "zstd",
        max_queue: int = 262_144,
        decode: bool = True,
    ) -> None:
        if not 0 < flush_interval <= 0.1:
            raise ValueError(f"flush_interval {flush_interval} s: must be in (0, 0.1]")
        if isinstance(path, str | os.PathLike):
            self.path: Path | None = Path(path)
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._f: IO[bytes] = open(self.path, "wb")  # noqa: SIM115 - closed in close()
            self._own_file = True
        else:
            self.path, self._f, self._own_file = None, path, False
        v = versions()
        self._w = McapWriter(
            self._f,
            chunk_size=chunk_size,
            compression=compression,
            library=f"hil/{v.get('hil', '?')} mcap-python/{v.get('mcap', '?')}",
        )
        self.flush_interval = flush_interval
        self.decode = decode
        self.drops = 0  #: items refused because the queue was full or the recorder closed
        self.errors = 0  #: items the writer thread failed to write
        self.last_error: str | None = None
        self._max_queue = max_queue
        self._q: deque = deque()
        self._lock = threading.Lock()
        self._open = True
        self._stopping = False
        self._schema_ids: dict[str, int] = {}
        self.topic_of: dict[int, str] = {}  # channel id -> topic
        self.metadata_count = 0  # metadata records added (a live reader's cache key)
        self.clock: Any = None  # the run's clock once bound (`bind_clock`); else the current
        #: what the file holds outside its messages, as written (by the writer thread): the
        #: metadata records in file order, and each channel's schema name and metadata; a
        #: live reader takes them instead of reading the file's head again (`LiveSource`)
        self.written_metadata: list[tuple[str, dict[str, str]]] = []
        self.written_channels: dict[str, tuple[str, dict[str, str]]] = {}
        #: see keep_messages(): (channel id, log time, publish time, bytes, payload or None)
        self.mirror: list[tuple[int, int, int, bytes, Any]] | None = None
        self.mirror_limit: int | None = None
        self.mirror_dropped = False
        self._channels: dict[str, int] = {}
        self._chan_meta: dict[str, dict[str, str]] = {}
        self._can_ch: dict[str, tuple] = {}
        self._serial_ch: dict[str, tuple] = {}
        self._serial_modes: dict[str, str] = {}
        self._verdicts: Counter[str] = Counter()
        self._failed: list[str] = []
        self._describe_frame: Callable | None = None
        self._describe_adu: Callable | None = None
        self._decoders: dict[str, str] = {}
        self._decoders_loaded = False
        self._handlers: dict[type, Callable[[Any], None]] = {
            CanItem: self._do_can, tuple: self._do_can,  # a frame: a plain tuple (can())
            SerialItem: self._do_serial, BytesItem: self._do_bytes,
            AttachItem: self._do_attach, MetadataItem: self._do_metadata,
            BarrierItem: self._do_barrier,
        }
        start = {
            "started_ns": str(time.time_ns()),
            "pid": str(os.getpid()),
            "host": platform.node(),
            "argv": " ".join(sys.argv),
        }
        if metadata:
            start.update(_str_map(metadata))
        self._w.add_metadata("hil.run", start)
        self._w.add_metadata("hil.versions", v)
        self.written_metadata += [("hil.run", start), ("hil.versions", dict(v))]
        self._w.flush()
        self._thread = threading.Thread(target=self._run, name="hil-recorder", daemon=True)
        self._thread.start()

    # -- Tap protocol (hot path: append and return) ---------------------------------------------
    def can(
        self, bus: str, frame: Any, direction: str, t: int, source_t: int | None = None
    ) -> None:
        """A python-can `Message` seen on `bus` ("rx"/"tx" as seen by the harness)."""
        if self._open and (len(self._q) < self._max_queue or self._room()):
            self._q.append((bus, frame, direction, t, source_t))  # CanItem's fields
        else:
            self._drop()

    def serial(
        self,
        port: str,
        data: bytes,
        direction: str,
        t: int,
        source_t: int | None = None,
        gaps_us: list[int] | None = None,
    ) -> None:
        """One RS-485 frame (an ADU, as delimited by the line silence) on `port`."""
        if self._open and self._room():
            self._q.append(SerialItem(port, bytes(data), direction, t, source_t,
                                      None if gaps_us is None else list(gaps_us)))
        else:
            self._drop()

    def dio(self, name: str, line: str, level: bool, t: int, source_t: int | None = None) -> None:
        """Electrical level of one DI/DO/STO line."""
        self._put(
            topics.dio(name, line),
            "hil.DioLevel",
            None,
            b'{"level":true}' if level else b'{"level":false}',
            t,
            source_t,
        )

    def pulse(self, name: str, kind: str, body: Mapping[str, Any], t: int,
              source_t: int | None = None) -> None:
        """A pulse-line message: a command segment (`seg`), an encoder-output window (`oab`)
        or a Z pulse (`oz`) (docs/pulse.md)."""
        self._put(topics.pulse(name, kind), "hil.PulseSegment", None,
                  dumps(_plain(body)), t, source_t)

    # -- harness events --------------------------------------------------------------------------
    def plan_step(
        self,
        step: str,
        event: str = "start",
        *,
        status: str | None = None,
        message: str = "",
        plan: str | None = None,
        index: int | None = None,
        t: int | None = None,
        **extra: Any,
    ) -> None:
        """A plan step starts (`event="start"`) or ends (`"end"`, with its status)."""
        if event not in ("start", "end"):
            raise ValueError(f"plan_step event {event!r}: must be 'start' or 'end'")
        payload = {
            "plan": plan,
            "step": step,
            "index": index,
            "event": event,
            "status": status,
            "message": message,
            **extra,
        }
        self._put(topics.PLAN_STEPS, "hil.PlanStep", "harness", dumps(payload), t, None)

    def log(
        self,
        level: int | str,
        message: str,
        name: str = "hil",
        *,
        file: str = "",
        line: int = 0,
        t: int | None = None,
        forward: bool = True,
    ) -> None:
        """A harness log line in the foxglove.Log shape (level 1-5 or a logging level).

        The line also goes to Python logging (what `--log-level` shows) unless `forward` is
        false: `LogHandler` passes false, as the record came from Python logging already.
        """
        lvl = self._level(level)
        t = self._time_ns() if t is None else t
        payload = {
            "timestamp": {"sec": t // 1_000_000_000, "nsec": t % 1_000_000_000},
            "level": lvl,
            "message": str(message),
            "name": name,
            "file": file,
            "line": int(line),
        }
        self._put(topics.LOG, "foxglove.Log", "harness", dumps(payload), t, None)
        if forward:  # marked, so a LogHandler on that logger does not record it twice
            logging.getLogger(name or "hil").log(_STD_LEVELS[lvl], "%s", message,
                                                 extra={"hil_recorded": True})

    def verdict(self, data: Any = None, /, *, t: int | None = None, **fields: Any) -> None:
        """One judged timing constraint: a dict/dataclass and/or fields; needs `status`
        pass | fail | inconclusive (plus e.g. spec, constraint, measured, limit, margin)."""
        payload = _plain(data) if data is not None else {}
        payload.update(fields)
        status = str(payload.get("status", "")).lower()
        if status not in VERDICT_STATUSES:
            raise ValueError(
                f"verdict status {payload.get('status')!r}: must be one of "
                f"{', '.join(VERDICT_STATUSES)}"
            )
        payload["status"] = status
        with self._lock:
            self._verdicts[status] += 1
            if status != "pass":
                self._failed.append(str(payload.get("constraint") or payload.get("spec") or "?"))
        self._put(topics.TIMING_VERDICTS, "hil.TimingVerdict", "harness", dumps(payload), t, None)

    def safety(
        self,
        action: str,
        reason: str,
        *,
        source: str = "runner",
        t: int | None = None,
        **extra: Any,
    ) -> None:
        """A safe-state action taken by the runner or the gateway."""
        payload = {"action": action, "reason": reason, "source": source, **extra}
        self._put(topics.SAFETY, "hil.SafetyAction", "harness", dumps(payload), t, None)

    def fault(self, fault: str, transport: str, active: bool, fault_id: int, *,
              t: int | None = None, **detail: Any) -> None:
        """An injected fault starts (active) or ends, on the /faults channel."""
        payload = {"fault": fault, "transport": transport, "active": bool(active),
                   "id": int(fault_id), "detail": _plain(detail)}
        self._put(topics.FAULTS, "hil.Fault", "harness", dumps(payload), t, None)

    # -- virtual-bench ground truth ---------------------------------------------------------------
    def drive_state(
        self,
        drive: str,
        state: Mapping[str, Any],
        *,
        t: int | None = None,
        source_t: int | None = None,
    ) -> None:
        """Model snapshot: CiA 402 `state` (recorded as a string), mode, position, ..."""
        payload = _plain(state)
        if "state" in payload and not isinstance(payload["state"], str):
            s = payload["state"]
            payload["state"] = s.name if isinstance(s, enum.Enum) else str(s)
        data, encoded = dumps_checked(payload)
        self._put(topics.drive_state(drive), "hil.DriveState", "model", data, t, source_t,
                  json_plain(payload, True) if encoded and self.mirror is not None else None)

    def drive_event(
        self, drive: str, event: Any, *, t: int | None = None, source_t: int | None = None
    ) -> None:
        """A model event (dict, or an event dataclass from hil.model.events)."""
        self._put(
            topics.drive_events(drive), "hil.DriveEvent", "model", dumps(_plain(event)), t, source_t
        )

    def input_delivery(self, drive: str, line: str, level: bool, sent_ns: int,
                       applied_ns: int) -> None:
        """A DI/STO edge the virtual drive applied: the harness's stamp of it and when the
        model applied it (both wall ns); publish_time = applied_ns."""
        payload = {"line": line, "level": bool(level), "sent_ns": int(sent_ns),
                   "applied_ns": int(applied_ns), "delay_ns": int(applied_ns - sent_ns)}
        self._put(topics.drive_inputs(drive), "hil.InputDelivery", "model", dumps(payload),
                  None, int(applied_ns))

    def drive_params(
        self,
        drive: str,
        values: Mapping[str, Any],
        *,
        snapshot: bool = False,
        t: int | None = None,
        source_t: int | None = None,
        source: str | None = None,
    ) -> None:
        """Parameter values as the drive reports them (`snapshot=True` for the full set;
        `source="read"` for values the harness read from the drive, which it held before)."""
        payload: dict[str, Any] = {"snapshot": snapshot, "values": dict(values)}
        if source is not None:
            payload["source"] = source
        self._put(
            topics.drive_params(drive), "hil.DriveParams", "model", dumps(payload), t, source_t
        )

    # -- generic ---------------------------------------------------------------------------------
    def write(
        self,
        topic: str,
        payload: Mapping[str, Any],
        log_time: int | None = None,
        publish_time: int | None = None,
    ) -> None:
        """Any JSON object on any topic (schema chosen from the topic, else `hil.Json`)."""
        self._put(
            topic, schema_for_topic(topic), None, dumps(_plain(payload)), log_time, publish_time
        )

    def declare_source(self, topic: str, source: str, **metadata: Any) -> None:
        """Set a topic's `publish_time_source` and extra channel metadata (e.g.
        `resolution_ns=1_000_000`), before its first message."""
        if source not in SOURCES:
            raise ValueError(f"publish_time_source {source!r}: must be one of {SOURCES}")
        self._chan_meta[topic] = {"publish_time_source": source, **_str_map(metadata)}

    def serial_mode(self, port: str, mode: str) -> None:
        """Modbus framing of `port` ("rtu" or "ascii"); default: guessed per frame."""
        if mode not in ("rtu", "ascii"):
            raise ValueError(f"Modbus mode {mode!r} for port {port!r}: must be 'rtu' or 'ascii'")
        self._serial_modes[port] = mode

    def attach(
        self,
        name: str,
        data: bytes,
        media_type: str = "application/octet-stream",
        *,
        t: int | None = None,
    ) -> None:
        """A file attachment (bench file, plan, EDS ...)."""
        t = self._time_ns() if t is None else t
        self._control(AttachItem(name, bytes(data), media_type, t))

    def add_metadata(self, name: str, data: Mapping[str, Any]) -> None:
        """A metadata record; non-string values are stored as JSON text."""
        self.metadata_count += 1
        self._control(MetadataItem(name, _str_map(data)))

    def keep_messages(self, limit: int | None = None) -> list[tuple[int, int, int, bytes, Any]]:
        """From now on, also keep every message written (channel id, log time, publish
        time, bytes, payload) in `mirror`, in file order, for a live checker that reads each
        message once (`hil.timing.source.LiveSource`) instead of re-reading the file. The
        payload is the ground truth's own dict where decoding the bytes gives exactly it
        (`json_plain`), so the checker need not decode it; None for any other message.

        `limit` (a mirror only the reports read, which can read the file instead): once the
        mirror holds that many messages it is dropped, its memory freed (about 2 KB a
        message), `mirror` is None again and `mirror_dropped` True; asking for it again
        then raises, as it would miss what was written meanwhile."""
        if self.mirror_dropped:
            raise RuntimeError(f"recorder: the mirror was dropped at its limit of "
                               f"{self.mirror_limit} messages")
        if self.mirror is None:
            mirror: list[tuple[int, int, int, bytes, Any]] = []
            write = self._w.add_message
            self.mirror_limit = limit

            def add_message(cid: int, log_time: int, publish_time: int, data: bytes,
                            *args: Any, obj: Any = None, **kw: Any) -> Any:
                out = write(cid, log_time, publish_time, data, *args, **kw)
                if self.mirror_dropped:  # (a message queued with its payload before)
                    return out
                mirror.append((cid, log_time, publish_time, data, obj))
                if limit is not None and len(mirror) >= limit:  # (the writer thread's)
                    self.mirror, self.mirror_dropped = None, True
                    mirror.clear()
                return out

            self._w.add_message = add_message  # type: ignore[method-assign]
            self.mirror = mirror  # only now: a payload is queued with its dict from here on
        elif limit != self.mirror_limit:
            raise ValueError(f"recorder: the mirror is kept with limit {self.mirror_limit}, "
                             f"not {limit}")
        return self.mirror

    def flush(self, timeout: float = 10.0) -> bool:
        """Wait until everything queued so far is written and flushed to the OS."""
        if not self._thread.is_alive():
            return False
        done = threading.Event()
        self._control(BarrierItem(done))
        return done.wait(timeout)

    @property
    def queued(self) -> int:
        return len(self._q)

    @property
    def closed(self) -> bool:
        """`close()` has begun: no item is taken any more."""
        return not self._open

    def bind_clock(self, clk: Any) -> None:
        """Stamp what the recorder stamps itself (a line or record without `t`, open
        transactions at `close`) on `clk` from now on, the run's clock, also once the run has
        ended: a pytest test's recording closes after `hil_session` put the wall clock back,
        and its last SDO or Modbus request still unanswered then belongs on the bench's time."""
        self.clock = clk

    def _time_ns(self) -> int:
        clk = self.clock
        return clk.time_ns() if clk is not None else clock.time_ns()

    def close(self) -> None:
        """Drain the queue, close open transactions, write `hil.close` and the summary."""
        with self._lock:
            if not self._open and self._stopping:
                return
            self._open = False
            self._stopping = True
        self._thread.join(timeout=60)
        with self._lock:
            self.drops += len(self._q)  # raced in after the writer stopped
            self._q.clear()
        t_end = self._time_ns()
        for _raw, _dec, sdo_ch, pairing, _cache, _pdos in self._can_ch.values():
            for txn in pairing.pending():
                self._safe(
                    lambda txn=txn, c=sdo_ch: self._w.add_message(c, t_end, t_end, dumps(txn))
                )
        for port, ch in self._serial_ch.items():
            self._safe(lambda port=port, ch=ch: self._close_serial(port, t_end, *ch))
        closing = {
            "closed_ns": str(time.time_ns()),
            "drops": str(self.drops),
            "errors": str(self.errors),
            "last_error": self.last_error or "",
            "messages": str(self._w.message_count + self._w._n),
            "verdicts_total": str(sum(self._verdicts.values())),
            **{f"verdicts_{s}": str(self._verdicts.get(s, 0)) for s in VERDICT_STATUSES},
            "verdicts_not_passed": ", ".join(self._failed),
            "decoders": json.dumps(self._decoders),
        }
        self._safe(lambda: self._w.add_metadata("hil.close", closing))
        self._safe(self._w.finish)
        if self._own_file:
            self._f.close()

    def __enter__(self) -> Recorder:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # -- internals (caller side) -------------------------------------------------------------
    def _room(self) -> bool:
        """Room in the queue. On a virtual clock the plan outruns the writer thread: there the
        producer waits (wall time, at most 30 s) for the writer rather than dropping."""
        if len(self._q) < self._max_queue:
            return True
        if not (self.clock or clock.current()).virtual:
            return False
        end = time.monotonic() + 30.0
        while len(self._q) >= self._max_queue and self._open and time.monotonic() < end:
            time.sleep(0.001)
        return len(self._q) < self._max_queue

    def _drop(self) -> None:
        with self._lock:
            self.drops += 1

    def _put(
        self,
        topic: str,
        schema: str,
        source: str | None,
        data: bytes,
        t: int | None,
        source_t: int | None,
        obj: Any = None,
    ) -> None:
        if t is None:
            t = self._time_ns()
        if self._open and self._room():
            self._q.append(BytesItem(topic, schema, source, data, t, source_t, obj))
        else:
            self._drop()

    def _control(self, item: AttachItem | MetadataItem | BarrierItem) -> None:
        if self._open:
            self._q.append(item)  # control items are never dropped for space
        else:
            self._drop()

    @staticmethod
    def _level(level: int | str) -> int:
        if isinstance(level, str):
            lvl = _LOG_NAMES.get(level.lower())
            if lvl is None:
                raise ValueError(f"log level {level!r}: must be one of {sorted(_LOG_NAMES)}")
            return lvl
        if isinstance(level, int) and 0 <= level <= 5:
            return level
        if isinstance(level, int) and level >= 10:  # logging.DEBUG..CRITICAL
            return min(5, level // 10)
        raise ValueError(
            f"log level {level!r}: must be 1-5 (foxglove.LogLevel) or a logging level (10-50)"
        )

    # -- writer thread ---------------------------------------------------------------------------
    def _run(self) -> None:
        q = self._q
        pop = q.popleft
        handlers = self._handlers
        interval = self.flush_interval
        next_flush = time.monotonic() + interval
        dirty = False
        while True:
            n = 0
            try:
                while n < 4096:
                    item = pop()
                    try:
                        handlers[type(item)](item)
                    except Exception as exc:
                        self._error(exc)
                    n += 1
            except IndexError:
                pass
            if n:
                dirty = True
            now = time.monotonic()
            if now >= next_flush:
                if dirty:
                    self._safe(self._w.flush)
                    dirty = False
                next_flush = now + interval
            if n == 0:
                if self._stopping and not q:
                    break
                time.sleep(0.002)

    def _safe(self, fn: Callable[[], Any]) -> None:
        try:
            fn()
        except Exception as exc:
            self._error(exc)

    def _error(self, exc: BaseException) -> None:
        self.errors += 1
        self.last_error = f"{type(exc).__name__}: {exc}"
        if self.errors <= 10:
            log_.warning("recorder: %s", self.last_error)

    def _channel(self, topic: str, schema: str, source: str) -> int:
        sid = self._schema_ids.get(schema)
        if sid is None:
            sid = self._schema_ids[schema] = self._w.add_schema(
                schema, "jsonschema", SCHEMA_BYTES[schema]
            )
        meta = {"publish_time_source": source, **self._chan_meta.get(topic, {})}
        cid = self._channels[topic] = self._w.add_channel(topic, "json", sid, meta)
        self.written_channels[topic] = (schema, meta)
        self.topic_of[cid] = topic
        return cid

    def _load_decoders(self) -> None:
        self._decoders_loaded = True
        if not self.decode:
            self._decoders = {"canopen": "disabled", "modbus": "disabled"}
            return
        self._describe_frame, self._decoders["canopen"] = _load(
            "hil.protocol.canopen", "describe_frame"
        )
        if self._describe_frame is not None:  # the A3's signed P-parameters read signed
            self._describe_frame = functools.partial(
                self._describe_frame, signed_params=signed_parameter_objects())
        self._describe_adu, self._decoders["modbus"] = _load("hil.protocol.modbus", "describe_adu")

    def _do_bytes(self, item: BytesItem) -> None:
        topic, schema, source, data, t, st, obj = item
        cid = self._channels.get(topic)
        if cid is None:
            cid = self._channel(topic, schema, source or ("harness" if st is None else "adapter"))
        if obj is None:
            self._w.add_message(cid, t, t if st is None else st, data)
        else:  # only with the mirror kept (`drive_state`): its add_message takes the payload
            self._w.add_message(cid, t, t if st is None else st, data, obj=obj)

    def _can_channels(self, bus: str, st: int | None) -> tuple:
        if not self._decoders_loaded:
            self._load_decoders()
        src = "harness" if st is None else "adapter"
        raw = self._channel(topics.can_raw(bus), "hil.CanFrame", src)
        dec = None
        if self._describe_frame is not None:
            dec = self._channel(topics.canopen(bus), "hil.CanOpenFrame", src)
        sdo = self._channel(topics.canopen_sdo(bus), "hil.SdoTransaction", src)
        ch = self._can_ch[bus] = (raw, dec, sdo, SdoPairing(), {}, PdoMaps())
        return ch

    def _do_can(self, item: CanItem) -> None:
        bus, frame, direction, t, st = item
        ch = self._can_ch.get(bus)
        if ch is None:
            ch = self._can_channels(bus, st)
        raw_cid, dec_cid, sdo_cid, pairing, cache_, pdos = ch
        pt = t if st is None else st
        d = _DIRS.get(direction) or json.dumps(str(direction))[1:-1]
        data = bytes(frame.data or b"")
        hxb = hexlify(data)
        cid = frame.arbitration_id
        ext = frame.is_extended_id
        err = frame.is_error_frame
        w = self._w
        rtr = frame.is_remote_frame
        # the raw frame's JSON around its data, per frame shape (a bus repeats its shapes)
        shape = (cid, frame.dlc, d, ext, rtr, err, frame.is_fd, frame.bitrate_switch,
                 frame.error_state_indicator)
        around = cache_.get(shape)
        if around is None:
            flags = _FLAGS.get(shape[3:]) or _FLAGS[tuple(bool(x) for x in shape[3:])]
            pre, post = (_CAN_FMT % (cid, flags, frame.dlc, "\0", d)).encode().split(b"\0")
            if len(cache_) >= _DECODE_CACHE_MAX:
                cache_.clear()
            around = cache_[shape] = (pre, post)
        w.add_message(raw_cid, t, pt, around[0] + hxb + around[1])
        if ext or err:
            return  # CANopen uses 11-bit identifiers
        if cid == 0 and len(data) >= 2 and data[0] in (0x81, 0x82):
            pdos.nmt_reset(data[1])  # reset node / communication: PDOs back to defaults
        is_pdo_ = 0x180 <= cid <= 0x57F  # hil.protocol.canopen.is_pdo, inline: every frame
        pdo = pdos.decode(cid, data) if dec_cid is not None and not rtr and is_pdo_ else None
        if pdo is not None:  # a PDO whose mapping the bus configured: its objects by name
            base = json.loads(self._describe_can(cid, data, hxb.decode(), False))
            w.add_message(dec_cid, t, pt, dumps({"dir": d, **base, **pdo}))
        elif dec_cid is not None:
            # PDO payloads change every frame: their decoding is a fixed prefix (direction
            # included) + the data
            pre = None if rtr else cache_.get((cid, len(data), d))
            if pre is not None:
                w.add_message(dec_cid, t, pt, pre + hxb + b'"}')
            else:
                key = (cid, rtr, data)
                enc = cache_.get(key)
                if enc is None:
                    enc = self._describe_can(cid, data, hxb.decode(), key[1])
                    if len(cache_) >= _DECODE_CACHE_MAX:
                        cache_.clear()
                    cache_[key] = enc
                dirb = d.encode()
                out = b'{"dir":"%s",' % dirb + enc[1:] if len(enc) > 2 else b'{"dir":"%s"}' % dirb
                if (
                    is_pdo_
                    and not rtr
                    and enc.endswith(b'"data":"' + hxb + b'"}')
                    and enc.count(b'"') == 14
                ):  # exactly kind/node/cob_id/dlc/data
                    cache_[(cid, len(data), d)] = out[: -len(hxb) - 2]
                w.add_message(dec_cid, t, pt, out)
        if 0x580 < cid <= 0x67F:  # is_sdo(cid)
            for txn in pairing.feed(cid, data, pt):
                w.add_message(sdo_cid, t, pt, dumps(txn))
                if (txn.get("access") == "download" and txn.get("status") == "ok"
                        and isinstance(txn.get("value"), int)):
                    pdos.sdo_download(int(txn["node"]), int(txn["index"]), int(txn["sub"]),
                                      int(txn["value"]))

    def _describe_can(self, cid: int, data: bytes, hx: str, remote: bool) -> bytes:
        try:
            if remote:
                out = self._describe_frame(cid, data, remote=True)
            else:
                out = self._describe_frame(cid, data)
            if not isinstance(out, Mapping):
                out = {"value": out}
            enc = dumps(out)
        except Exception as exc:
            enc = dumps(
                {
                    "id": cid,
                    "data": hx,
                    "error": f"describe_frame failed: {type(exc).__name__}: {exc}",
                }
            )
        return enc if enc[:1] == b"{" else dumps({"value": enc.decode()})

    def _do_serial(self, item: SerialItem) -> None:
        port, data, direction, t, st, gaps = item
        ch = self._serial_ch.get(port)
        if ch is None:
            if not self._decoders_loaded:
                self._load_decoders()
            src = "harness" if st is None else "adapter"
            ch = self._serial_ch[port] = (
                self._channel(topics.rs485_raw(port), "hil.SerialChunk", src),
                self._channel(topics.modbus(port), "hil.ModbusAdu", src),
                ModbusPairing(),
                AduAssembler(),
            )
        raw_cid, mb_cid, pairing, assembler = ch
        pt = t if st is None else st
        d = _DIRS.get(direction) or str(direction)
        self._w.add_message(
            raw_cid, t, pt, dumps({"dir": d, "data": data.hex(), "n": len(data), "gaps_us": gaps})
        )
        mode = self._serial_modes.get(port) or guess_mode(data)
        for adu, adir, apt in assembler.feed(data, d, mode, pt):
            self._modbus(mb_cid, pairing, adu, adir, mode, t, apt)

    def _close_serial(
        self, port: str, t: int, _raw: int, mb_ch: int, pairing: ModbusPairing,
        assembler: AduAssembler,
    ) -> None:
        """End of recording (at `t`): decode a half-received ADU, report unanswered
        requests."""
        mode = self._serial_modes.get(port, "")
        for adu, adir, apt in assembler.pending():
            self._modbus(mb_ch, pairing, adu, adir, mode or guess_mode(adu), t, apt)
        for rec in pairing.pending():
            self._w.add_message(mb_ch, t, t, dumps({"mode": mode, "raw": "", **rec}))

    def _modbus(
        self, mb_cid: int, pairing: ModbusPairing, data: bytes, d: str, mode: str, t: int, pt: int
    ) -> None:
        info, unanswered = pairing.feed(data, mode, d, pt)
        for rec in unanswered:
            self._w.add_message(mb_cid, t, pt, dumps({"mode": mode, "raw": "", **rec}))
        msg: dict[str, Any] = {"dir": d, "mode": mode, "raw": data.hex(), **info}
        if self._describe_adu is not None:
            try:
                adu = self._describe_adu(data, mode)
                msg["adu"] = adu if isinstance(adu, Mapping) else {"value": adu}
                if isinstance(adu, Mapping) and adu.get("error") and "error" not in msg:
                    msg["error"] = str(adu["error"])
            except Exception as exc:
                why = f"describe_adu failed: {type(exc).__name__}: {exc}"
                msg["adu"] = {"error": why}
                msg.setdefault("error", why)
        self._w.add_message(mb_cid, t, pt, dumps(msg))

    def _do_attach(self, item: AttachItem) -> None:
        self._w.add_attachment(item.name, item.media_type, item.data, item.t)

    def _do_metadata(self, item: MetadataItem) -> None:
        self._w.add_metadata(item.name, item.data)
        self.written_metadata.append((item.name, dict(item.data)))

    def _do_barrier(self, item: BarrierItem) -> None:
        self._w.flush()
        item.done.set()


class LogHandler(logging.Handler):
    """A `logging.Handler` that writes records to `/log` (foxglove.Log)."""

    def __init__(self, recorder: Recorder, level: int = logging.INFO) -> None:
        super().__init__(level)
        self.recorder = recorder

    def emit(self, record: logging.LogRecord) -> None:
        if getattr(record, "hil_recorded", False):  # it came from Recorder.log: on /log already
            return
        try:
            self.recorder.log(
                record.levelno,
                record.getMessage(),
                record.name,
                file=record.pathname,
                line=record.lineno,
                t=int(record.created * 1e9),
                forward=False,  # the record is already in Python logging: no loop
            )
        except Exception:
            self.handleError(record)
