"""Fault injection on the harness's own side of a transport (docs/faults.md).

Wrappers that stop, delay, garble or multiply what the *harness sends*; what the drive
sends is passed through untouched (on a real bench only our side may be touched):

* `FaultyCanBus`  - a `can.BusABC` around the harness's bus: drop / delay / corrupt /
  duplicate frames matched by COB-ID, range or CANopen function, for a duration, at a rate;
  plus `burst()` for floods, duplicate PDOs and error frames.
* `FaultySerial`  - around a `SerialLine`: CRC errors, partial / split / late requests,
  line noise, master silence.
* `FaultyDio`     - around a `DioPort`: contact bounce, a stuck input.

Every fault start and end goes to the recorder's /faults channel (`Recorder.fault`), so a
reviewer sees cause and effect on one timeline. With nothing injected each wrapper is a
plain pass-through (benchmarks/bench_faults.py measures the cost).
"""

from __future__ import annotations

import itertools
import random
import threading
from collections.abc import Iterable
from dataclasses import dataclass, field
from typing import Any, Protocol

import can

from hil import clock
from hil.protocol.canopen import FUNCTION_SPANS, is_function
from hil.transport import inline
from hil.transport.cyclic import ClockPeriodic

CAN_ACTIONS = ("drop", "delay", "corrupt", "duplicate")
# CANopen functions a fault may match: the classification of hil.protocol.canopen
CAN_FUNCTIONS = tuple(FUNCTION_SPANS)
# on the harness's requests (what it writes) / on the replies it reads (its own receiver)
REQUEST_FAULTS = ("crc", "partial", "split", "late", "noise", "silence")
REPLY_FAULTS = ("reply_late", "reply_partial", "reply_split", "reply_noise")
SERIAL_FAULTS = REQUEST_FAULTS + REPLY_FAULTS
DIO_FAULTS = ("bounce", "stuck")
_process_fault_ids = itertools.count(1)


def next_fault_id() -> int:
    """A /faults id: unique in the process; on a virtual clock, counted per run from 1 (so
    the run repeats itself exactly, docs/clock.md)."""
    clk = clock.current()
    if isinstance(clk, clock.VirtualClock):
        return next(clk.media.setdefault("fault_ids", itertools.count(1)))
    return next(_process_fault_ids)
# Bursts whose frames must go out within a window: AL111/AL112 "within 1 ms" (L19933, L19941).
BURST_WINDOW_NS = {"sdo_flood": 1_000_000, "duplicate_pdo": 1_000_000}


class FaultSink(Protocol):
    def fault(self, fault: str, transport: str, active: bool, fault_id: int, *,
              t: int | None = None, **detail: Any) -> None: ...


@dataclass(frozen=True)
class CanMatch:
    """Which frames a CAN fault touches; empty = every frame the harness sends."""

    cob_ids: frozenset[int] = frozenset()
    ranges: tuple[tuple[int, int], ...] = ()
    functions: tuple[str, ...] = ()

    def __post_init__(self) -> None:
        for f in self.functions:
            if f not in CAN_FUNCTIONS:
                raise ValueError(f"unknown CANopen function {f!r}; known: "
                                 f"{', '.join(CAN_FUNCTIONS)}")

    def __call__(self, msg: can.Message) -> bool:
        if not (self.cob_ids or self.ranges or self.functions):
            return True
        cid = msg.arbitration_id
        if cid in self.cob_ids or any(lo <= cid <= hi for lo, hi in self.ranges):
            return True
        return any(is_function(f, cid) for f in self.functions)

    def target(self) -> str:
        """One string naming what is matched ("heartbeat", "0x205", "any"), for timing specs."""
        parts = [*self.functions, *(f"0x{c:03X}" for c in sorted(self.cob_ids)),
                 *(f"0x{a:03X}-0x{b:03X}" for a, b in self.ranges)]
        return ",".join(parts) or "any"

    def describe(self) -> dict[str, Any]:
        out: dict[str, Any] = {}
        if self.cob_ids:
            out["cob_id"] = [f"0x{c:03X}" for c in sorted(self.cob_ids)]
        if self.ranges:
            out["range"] = [f"0x{a:03X}-0x{b:03X}" for a, b in self.ranges]
        if self.functions:
            out["function"] = list(self.functions)
        return out


@dataclass
class Fault:
    """One injected fault: `kind` on `transport`, active until `end_ns` (monotonic)."""

    kind: str
    transport: str
    end_ns: int | None = None
    rate: float = 1.0
    params: dict[str, Any] = field(default_factory=dict)
    match: CanMatch | None = None
    every: int = 1  # hit only every n-th matching frame (1st..n-1th pass): deterministic
    id: int = field(default_factory=next_fault_id)
    seen: int = 0  # matching frames so far
    on_end: Any = None  # called once the end is recorded (a stuck line let go)

    def hits(self, rng: random.Random) -> bool:
        if self.every > 1:
            self.seen += 1
            return self.seen % self.every == 0
        return self.rate >= 1.0 or rng.random() < self.rate


class _Faults:
    """Active faults of one transport, their recording and their expiry."""

    def __init__(self, transport: str, sink: FaultSink | None, seed: int | None) -> None:
        self.transport = transport
        self.sink = sink
        if seed is None and clock.is_virtual():  # a virtual-time run repeats itself exactly
            seed = 0
        self.rng = random.Random(seed)
        self.active: list[Fault] = []
        self._lock = threading.Lock()
        self._timers: dict[int, Any] = {}  # threading.Timer or a clock event

    def start(self, fault: Fault, duration_ns: int | None) -> Fault:
        if duration_ns is not None:
            fault.end_ns = clock.monotonic_ns() + duration_ns
        self._record(fault, True)
        with self._lock:
            self.active = [*self.active, fault]  # copy on write: senders read without a lock
        if duration_ns is not None:
            self._timers[fault.id] = clock.call_later(duration_ns / 1e9, self.stop, fault)
        return fault

    def stop(self, fault: Fault) -> None:
        with self._lock:
            if fault not in self.active:
                return
            self.active = [f for f in self.active if f is not fault]
            timer = self._timers.pop(fault.id, None)
        if timer is not None and timer is not threading.current_thread():
            timer.cancel()
        self._record(fault, False)
        if fault.on_end is not None:
            fault.on_end()

    def stop_all(self) -> None:
        for f in list(self.active):
            self.stop(f)

    def span(self, kind: str, t0: int, t1: int, **detail: Any) -> None:
        """A fault that was one action (a burst), recorded after it: start at `t0`, end at
        `t1` (wall ns), both with `detail` (what it measured, e.g. its spread)."""
        f = Fault(kind, self.transport, params=detail)
        self._record(f, True, t0)
        self._record(f, False, t1)

    def current(self) -> list[Fault]:
        now = clock.monotonic_ns()
        out = []
        for f in self.active:
            if f.end_ns is not None and now >= f.end_ns:
                self.stop(f)
            else:
                out.append(f)
        return out

    def _record(self, f: Fault, active: bool, t: int | None = None) -> None:
        if self.sink is None:
            return
        detail = dict(f.params)
        if f.match is not None:
            detail["match"] = f.match.describe()
            detail["target"] = f.match.target()
        if f.rate < 1.0:
            detail["rate"] = f.rate
        try:
            self.sink.fault(f.kind, self.transport, active, f.id, t=t, **detail)
        except Exception:  # a recording problem must not change what is injected
            pass


class FaultyCanBus(ClockPeriodic, can.BusABC):
    """The harness's CAN bus with a fault layer; received frames pass untouched."""

    def __init__(self, bus: can.BusABC, name: str, *, sink: FaultSink | None = None,
                 seed: int | None = None) -> None:
        self.bus = bus
        self.name = name
        self.faults = _Faults(f"can:{name}", sink, seed)
        self.last_spread_ns = 0  # of the last burst: first send to last return
        self.channel_info = f"{bus.channel_info} (fault layer)"
        self._can_protocol = bus.protocol
        super().__init__(channel=getattr(bus, "channel", name))

    # -- injection ---------------------------------------------------------------------
    def inject(self, action: str, *, match: CanMatch | None = None,
               duration_ns: int | None = None, rate: float = 1.0,
               delay_ns: int = 0, every: int = 1) -> Fault:
        """Start `action` (drop | delay | corrupt | duplicate) on matching frames we send:
        each with probability `rate`, or exactly every `every`-th one (e.g. 2: every other
        SYNC dropped, the cycle doubled without a timeout; AL301)."""
        if action not in CAN_ACTIONS:
            raise ValueError(f"CAN fault {action!r}: one of {', '.join(CAN_ACTIONS)}")
        if not 0.0 < rate <= 1.0:
            raise ValueError(f"rate {rate}: a fraction in (0, 1]")
        if every < 1 or (every > 1 and rate < 1.0):
            raise ValueError(f"every {every}: an integer >= 1, not with a rate")
        params: dict[str, Any] = {"every": every}  # recorded: specs tell the faults apart
        if action == "delay":
            params["delay_ms"] = delay_ns / 1e6
        f = Fault(action, self.faults.transport, rate=rate, params=params,
                  match=match or CanMatch(), every=every)
        return self.faults.start(f, duration_ns)

    def burst(self, kind: str, frames: Iterable[can.Message], *, within_ns: int | None = None,
              **detail: Any) -> int:
        """Send `frames` back to back (an SDO flood, a duplicate PDO, error frames);
        recorded as one fault `kind` from the first frame to the last, with its measured
        `spread_us` and, with a window (`within_ns`, default BURST_WINDOW_NS[kind]), `tight`
        (spread < window: a loaded host can stretch a burst past the window the fault
        needs, AL111/AL112's 1 ms). Returns the count; `last_spread_ns` keeps the spread."""
        frames = list(frames)
        if within_ns is None:
            within_ns = BURST_WINDOW_NS.get(kind)
        t0 = t1 = clock.time_ns()
        try:
            # back to back, as a flooding master queues them: the drive sees them all
            # before it answers any (virtual clock: one settle, the frames' wire time in the
            # spread; in process: handed over at the end, the drive's work not in it)
            with inline.hold(self.bus):
                try:
                    with clock.batch():
                        for m in frames:
                            self.bus.send(m)
                finally:
                    t1 = clock.time_ns()
        finally:
            self.last_spread_ns = t1 - t0
            info: dict[str, Any] = {"frames": len(frames), "spread_us": round((t1 - t0) / 1e3, 1)}
            if within_ns is not None:
                info["tight"] = t1 - t0 < within_ns
            self.faults.span(kind, t0, t1, **info, **detail)
        return len(frames)

    def stop_all(self) -> None:
        self.faults.stop_all()

    # -- BusABC ------------------------------------------------------------------------
    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        if not self.faults.active:  # passive: one attribute test
            self.bus.send(msg, timeout)
            return
        self._send_faulty(msg, timeout)

    def _send_faulty(self, msg: can.Message, timeout: float | None) -> None:
        copies = [msg]
        rng = self.faults.rng
        delay = 0
        for f in self.faults.current():
            if f.match is None or not f.match(msg) or not f.hits(rng):
                continue
            if f.kind == "drop":
                return
            if f.kind == "corrupt":
                copies = [_corrupt(m, rng) for m in copies]
            elif f.kind == "duplicate":
                copies = copies + copies
            elif f.kind == "delay":
                delay = max(delay, int(f.params.get("delay_ms", 0) * 1e6))
        if delay:
            clock.call_later(delay / 1e9, self._send_all, copies, timeout)
            return
        self._send_all(copies, timeout)

    def _send_all(self, copies: list[can.Message], timeout: float | None) -> None:
        for m in copies:
            try:
                self.bus.send(m, timeout)
            except Exception:
                if len(copies) == 1:
                    raise

    def recv(self, timeout: float | None = None) -> can.Message | None:
        return self.bus.recv(timeout)  # the drive's output: never touched

    def _recv_internal(self, timeout: float | None) -> tuple[can.Message | None, bool]:
        return self.bus.recv(timeout), True

    def set_filters(self, filters: Any = None) -> None:
        self.bus.set_filters(filters)

    @property
    def state(self) -> can.BusState:
        return self.bus.state

    def flush_tx_buffer(self) -> None:
        self.bus.flush_tx_buffer()

    def fileno(self) -> int:
        return self.bus.fileno()

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        self.faults.stop_all()
        super().shutdown()
        self.bus.shutdown()


def _corrupt(msg: can.Message, rng: random.Random) -> can.Message:
    """A garbled frame. With data: one bit flipped (a payload error the CRC cannot see, as
    from a faulty master). Without data: an error frame (what a garbled frame becomes on a
    real bus when the receivers see a CRC error)."""
    if not msg.data:
        return can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False)
    data = bytearray(msg.data)
    i = rng.randrange(len(data))
    data[i] ^= 1 << rng.randrange(8)
    return can.Message(arbitration_id=msg.arbitration_id, data=bytes(data),
                       is_extended_id=msg.is_extended_id, is_remote_frame=msg.is_remote_frame)


def error_frames(n: int) -> list[can.Message]:
    """`n` error frames (AL185 burst on a virtual bus)."""
    return [can.Message(is_error_frame=True, arbitration_id=0, is_extended_id=False)
            for _ in range(n)]


class FaultySerial:
    """The harness's RS-485 line with a fault layer on what it writes and on what it reads;
    the drive's side of the line is never touched.

    Requests: crc: the CRC/LRC bytes garbled; partial: only the first half sent; split: the
    frame sent in two halves `gap_ms` apart (RTU: longer than t3.5 splits it in two frames);
    late: each request held back `delay_ms`; noise: `bytes` random bytes `gap_ms` ahead of
    each request; silence: nothing sent at all (master silence, AL020 after P3.004).

    Replies, as the harness's receiver sees the reply to each request (the harness master's
    own reaction is what they test): reply_late: nothing readable until `delay_ms` after the
    request; reply_partial: the reply cut after `bytes` bytes, the rest lost; reply_split:
    the reply's first `bytes` bytes, the rest `gap_ms` later; reply_noise: `bytes` random
    bytes ahead of the reply.

    `sleep` waits on the request side (a rig on a model clock passes its own).
    """

    def __init__(self, line: Any, name: str, *, sink: FaultSink | None = None,
                 seed: int | None = None, sleep: Any = None) -> None:
        self.line = line
        self.faults = _Faults(f"rs485:{name}", sink, seed)
        self._sleep = sleep or clock.sleep
        self._rx: dict[str, Fault] = {}  # reply faults of the current transaction
        self._rx_count = 0  # reply bytes handed over
        self._rx_hold: float | None = None  # monotonic s: nothing readable before
        self._rx_noise = b""  # noise still to hand over ahead of the reply
        self._rx_split = False  # the split gap was taken

    def __getattr__(self, name: str) -> Any:
        return getattr(self.line, name)

    def inject(self, kind: str, *, duration_ns: int | None = None, rate: float = 1.0,
               **params: Any) -> Fault:
        if kind not in SERIAL_FAULTS:
            raise ValueError(f"RS-485 fault {kind!r}: one of {', '.join(SERIAL_FAULTS)}")
        return self.faults.start(Fault(kind, self.faults.transport, rate=rate, params=params),
                                 duration_ns)

    def stop_all(self) -> None:
        self.faults.stop_all()

    def write(self, data: bytes, **kw: Any) -> Any:
        if not self.faults.active:
            self._rx = {}
            return self.line.write(data, **kw)
        rng = self.faults.rng
        data = bytes(data)
        hits = [f for f in self.faults.current() if f.hits(rng)]
        self._arm_reply([f for f in hits if f.kind in REPLY_FAULTS])
        for f in hits:
            if f.kind == "silence":
                return None
            if f.kind == "crc":
                data = data[:-1] + bytes([data[-1] ^ 0xFF])
            elif f.kind == "partial":
                data = data[: max(1, len(data) // 2)]
            elif f.kind == "noise":
                n = int(f.params.get("bytes", 3))
                self.line.write(bytes(rng.randrange(256) for _ in range(n)))
                self._sleep(float(f.params.get("gap_ms", 5)) / 1e3)
            elif f.kind == "late":
                self._sleep(float(f.params.get("delay_ms", 20)) / 1e3)
            elif f.kind == "split":
                half = max(1, len(data) // 2)
                self.line.write(data[:half], **kw)
                self._sleep(float(f.params.get("gap_ms", 5)) / 1e3)
                return self.line.write(data[half:])
        return self.line.write(data, **kw)

    def _arm_reply(self, faults: list[Fault]) -> None:
        """A new request: the reply faults that hit apply to its reply."""
        self._rx = {f.kind: f for f in faults}
        self._rx_count, self._rx_hold, self._rx_split = 0, None, False
        self._rx_noise = b""
        if (f := self._rx.get("reply_late")) is not None:
            self._rx_hold = clock.monotonic() + float(f.params.get("delay_ms", 20)) / 1e3
        if (f := self._rx.get("reply_noise")) is not None:
            rng = self.faults.rng
            self._rx_noise = bytes(rng.randrange(256) for _ in range(int(f.params.get("bytes",
                                                                                     3))))

    def read(self, n: int = 1, timeout: float | None = None) -> bytes:
        if not self._rx:
            return self.line.read(n, timeout)
        deadline = None if timeout is None else clock.monotonic() + timeout
        if self._rx_noise:
            out, self._rx_noise = self._rx_noise[:n], self._rx_noise[n:]
            return out
        if self._rx_hold is not None:  # late / split: nothing readable before the hold ends
            wait = self._rx_hold - clock.monotonic()
            if deadline is not None:
                wait = min(wait, deadline - clock.monotonic())
            if wait > 0:
                clock.sleep(wait)
            if clock.monotonic() < self._rx_hold:
                return b""
            self._rx_hold = None
        left = None if deadline is None else max(0.0, deadline - clock.monotonic())
        cut_f = self._rx.get("reply_partial") or self._rx.get("reply_split")
        cut = int(cut_f.params.get("bytes", 3)) if cut_f is not None else None
        if cut is not None and "reply_partial" in self._rx and self._rx_count >= cut:
            self.line.read(n, left)  # the rest of the reply is lost on its way to us
            return b""
        if cut is not None and self._rx_count < cut:
            n = min(n, cut - self._rx_count)
        data = self.line.read(n, left)
        self._rx_count += len(data)
        split = self._rx.get("reply_split")
        if split is not None and not self._rx_split and cut is not None and self._rx_count >= cut:
            self._rx_split = True
            self._rx_hold = clock.monotonic() + float(split.params.get("gap_ms", 5)) / 1e3
        return data


class FaultyDio:
    """The harness's DI/DO port with a fault layer on the DI lines it drives.

    bounce: each level change becomes `bounces` toggles `period_ms` apart before it
    settles; stuck: the line holds `level` whatever the harness sets, and when the fault
    ends it goes to the level the harness set last (as a freed contact would).
    """

    def __init__(self, port: Any, name: str, *, sink: FaultSink | None = None,
                 seed: int | None = None) -> None:
        self.port = port
        self.faults = _Faults(f"dio:{name}", sink, seed)
        self._wanted: dict[str, bool] = {}  # line -> the level the harness set last
        self._restore = True  # a stuck line freed goes to _wanted (not on the safe path)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.port, name)

    def inject(self, kind: str, line: str, *, duration_ns: int | None = None,
               **params: Any) -> Fault:
        if kind not in DIO_FAULTS:
            raise ValueError(f"DI/DO fault {kind!r}: one of {', '.join(DIO_FAULTS)}")
        f = Fault(kind, self.faults.transport, params={"line": line, **params})
        if kind == "stuck":
            self._wanted.setdefault(line, bool(self.port.get(line)))
            f.on_end = lambda: self._restore and self.port.set(line, self._wanted[line])
        self.faults.start(f, duration_ns)
        if kind == "stuck":
            self.port.set(line, bool(params.get("level", False)))
        return f

    def stop_all(self, restore: bool = True) -> None:
        """End every fault; restore=False (the safe-state path): a stuck line keeps its
        level rather than going to the level the harness set last."""
        self._restore = restore
        try:
            self.faults.stop_all()
        finally:
            self._restore = True

    def set(self, line: str, level: bool, *args: Any, **kw: Any) -> None:
        self._wanted[line] = bool(level)
        if not self.faults.active:
            self.port.set(line, level, *args, **kw)
            return
        for f in self.faults.current():
            if f.params.get("line") != line:
                continue
            if f.kind == "stuck":
                return
            if f.kind == "bounce":
                period = float(f.params.get("period_ms", 1)) / 1e3
                for _ in range(int(f.params.get("bounces", 3))):
                    self.port.set(line, level)
                    clock.sleep(period)
                    self.port.set(line, not level)
                    clock.sleep(period)
        self.port.set(line, level, *args, **kw)

