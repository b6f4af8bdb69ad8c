"""Faults on the wire and raw bus traffic: `fault`, `produce`, `sdo`, `nmt` (docs/faults.md).

    - produce: {heartbeat: 50ms, node: 127}   # harness traffic the drive monitors;
    - produce: {sync: 10ms}                   #   `off` stops it
    - produce: {guard: 20ms}                  #   (node guarding RTR to 700h + node)
    - sdo: {"1016:1": 0x007F0064, "1006": 10000}   # communication objects, SDO download
    - fault: {can: drop, match: {function: sync}, for: 200ms}   # drop|delay|corrupt|duplicate
    - fault: {can: drop, match: {function: sync}, every: 2}     # every 2nd frame (rate: random)
    - fault: {can: sdo_flood, count: 3}        # SDO requests back to back (AL111)
    - fault: {can: duplicate_pdo, cob_id: 0x205, data: "060000"}   # (AL112)
    - fault: {can: bus_error, count: 17}       # error frames (AL185)
    - fault: {rs485: silence, for: 2s}         # crc|partial|split|late|noise|silence
    - fault: {rs485: reply_late, delay: 700ms} # reply_late|reply_partial|reply_split|reply_noise
    - fault: {dio: stuck, line: DI5, level: false, for: 1s}   # bounce|stuck
    - fault: off                               # end every fault now
    - nmt: start                               # NMT command to the drive's node

Faults touch only what the harness sends; every start and end is on the /faults channel.
`fault:` needs `faults_allowed: true` in the bench file (default on virtual benches only):
`hil run --check` refuses it otherwise.
"""

from __future__ import annotations

import contextlib
import logging
import re
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import can

from hil import clock
from hil.bench.param_rules import sdo_parameter
from hil.bench.yamlio import Checker, join, parse_duration, shorten
from hil.drivers.cia402 import object_dictionary, value_refusal
from hil.plan.context import Outcome
from hil.plan.kinds.base import CheckContext, StepKind
from hil.plan.kinds.fields import check_can
from hil.plan.session import BenchError
from hil.profile.od import EDS_PATH
from hil.transport.cyclic import CyclicSender
from hil.transport.faults import (
    BURST_WINDOW_NS,
    CAN_ACTIONS,
    CAN_FUNCTIONS,
    DIO_FAULTS,
    SERIAL_FAULTS,
    CanMatch,
    FaultyCanBus,
    error_frames,
)
from hil.transport.sim import frame_bits
from hil.transport.urls import can_bitrate
from hil.units import fmt_ms

if TYPE_CHECKING:
    from hil.plan.context import StepContext
    from hil.plan.session import DriveIO
    from hil.plan.steps import Step

DI_LINES = 10  # physical DI1..DI10 of CN1
CAN_BURSTS = ("sdo_flood", "duplicate_pdo", "bus_error")
# the keys each RS-485 fault uses (hil/transport/faults.py FaultySerial); recorded on /faults
_SERIAL_PARAMS: dict[str, tuple[str, ...]] = {
    "crc": (), "partial": (), "silence": (), "split": ("gap_ms",), "late": ("delay_ms",),
    "noise": ("bytes", "gap_ms"), "reply_late": ("delay_ms",), "reply_partial": ("bytes",),
    "reply_split": ("bytes", "gap_ms"), "reply_noise": ("bytes",)}
MIN_PRODUCE_NS = 1_000_000  # produce: SYNC / heartbeat / guard at most every 1 ms
_OBJ_RE = re.compile(r"^(?:0x)?([0-9A-Fa-f]{4})h?(?::([0-9]{1,3}))?\Z")
_LINE_RE = re.compile(r"^(DI[0-9]{1,2}|STO_[AB])\Z")


NMT_COMMANDS = {"start": 0x01, "stop": 0x02, "pre-operational": 0x80, "reset_node": 0x81,
                "reset_communication": 0x82}


def _int(v: Checker, obj: Any, line: int, where: str, lo: int, hi: int) -> int:
    if isinstance(obj, bool) or not isinstance(obj, int) or not lo <= obj <= hi:
        raise v.err(line, where, f"{obj!r}: an integer {lo}..{hi}")
    return obj


def _ids(v: Checker, obj: Any, line: int, where: str) -> list[int]:
    items = obj if isinstance(obj, list) else [obj]
    if not items:
        raise v.err(line, where, "one COB-ID 0..0x7FF or a list of them, not an empty list")
    return [_int(v, x, line, where, 0, 0x7FF) for x in items]


def _match(v: Checker, obj: Any, line: int, where: str) -> CanMatch:
    m = v.mapping(obj, line, where)
    v.keys(m, {"cob_id", "range", "function"}, where)
    out: dict[str, Any] = {"cob_ids": [], "ranges": [], "functions": []}
    if "cob_id" in m:
        out["cob_ids"] = _ids(v, m["cob_id"], m.kline("cob_id"), join(where, "cob_id"))
    if "range" in m:
        r = m["range"]
        w = join(where, "range")
        if not isinstance(r, list) or len(r) != 2:
            raise v.err(m.kline("range"), w, "two COB-IDs [first, last]")
        lo, hi = (_int(v, x, m.kline("range"), w, 0, 0x7FF) for x in r)
        if lo > hi:
            raise v.err(m.kline("range"), w, f"first 0x{lo:X} > last 0x{hi:X}")
        out["ranges"] = [(lo, hi)]
    if "function" in m:
        fs = m["function"] if isinstance(m["function"], list) else [m["function"]]
        for f in fs:
            if not isinstance(f, str) or f not in CAN_FUNCTIONS:
                raise v.err(m.kline("function"), join(where, "function"),
                            f"{f!r}: one of {', '.join(CAN_FUNCTIONS)}")
        out["functions"] = list(fs)
    return CanMatch(frozenset(out["cob_ids"]), tuple(out["ranges"]), tuple(out["functions"]))


def _rate(v: Checker, m: Any, where: str) -> float:
    if "rate" not in m:
        return 1.0
    r = m["rate"]
    if isinstance(r, bool) or not isinstance(r, int | float) or not 0 < r <= 1:
        raise v.err(m.kline("rate"), join(where, "rate"), f"{r!r}: a fraction in (0, 1]")
    return float(r)


def _bus_name(bus: str | None, d: Any) -> str:
    name = bus or d.spec.can
    if not name:
        raise RuntimeError(f"drive {d.name} has no CAN bus on this bench")
    return name


def _node(d: Any) -> int:
    return d.spec.node_id or 1


# AL111/AL112 need their frames "within 1 ms" (BURST_WINDOW_NS); a loaded host can stretch
# a burst past that, so such a burst is sent again (recorded `tight: false`, then `true`).
BURST_ATTEMPTS = 5


def _burst_frames(a: Any, node: int) -> list[can.Message]:
    """The frames of a burst fault: `count` of them."""
    if a.kind == "sdo_flood":  # 1000h uploads back to back: well within 1 ms
        req = bytes([0x40, 0x00, 0x10, 0x00, 0, 0, 0, 0])
        return [can.Message(arbitration_id=0x600 + node, data=req, is_extended_id=False)
                for _ in range(a.count)]
    if a.kind == "duplicate_pdo":
        return [can.Message(arbitration_id=a.cob_id, data=a.data, is_extended_id=False)
                for _ in range(a.count)]
    return error_frames(a.count)


def _burst(bus: FaultyCanBus, kind: str, frames: list[can.Message]) -> str:
    window = BURST_WINDOW_NS.get(kind)
    late: list[str] = []
    for _ in range(BURST_ATTEMPTS):
        n = bus.burst(kind, frames)
        spread = f"{bus.last_spread_ns / 1e3:.0f} µs"
        if window is None or bus.last_spread_ns < window:
            again = (f" (sent again: the host took {', '.join(late)} before, over the "
                     f"{window / 1e6:g} ms the fault needs)" if late else "")
            return f"{kind}: {n} frames back to back on can:{bus.name} in {spread}{again}"
        late.append(spread)
        if clock.is_virtual():  # the wire's own time, the same every try: the bus is full
            raise BenchError(f"{kind}: {len(frames)} frames took {spread} on can:{bus.name} "
                             f"with the traffic around them (the drive's answers), over the "
                             f"{window / 1e6:g} ms the fault needs: the fault was not "
                             "injected; send fewer")
        clock.sleep(0.002)  # apart from the stretched one
    raise BenchError(f"{kind}: the host could not send {len(frames)} frames within "
                     f"{window / 1e6:g} ms in {BURST_ATTEMPTS} tries ({', '.join(late)}): "
                     "the fault was not injected (host under load)")


def _late_logger(ctx: Any, what: str) -> Any:
    """Record (on /log) that a producer woke late and restarted its cycle (no burst)."""
    def late(late_ns: int) -> None:
        with contextlib.suppress(Exception):
            ctx.rec.log(logging.WARNING, f"{what} producer woke {late_ns / 1e6:.1f} ms late "
                        "(host under load): cycle restarted, no catch-up burst",
                        "hil.produce", forward=False)
    return late


@dataclass(frozen=True)
class FaultArgs:
    transport: str  # can | rs485 | dio | off
    kind: str | None = None  # drop, delay, ... (CAN_ACTIONS, CAN_BURSTS, SERIAL/DIO_FAULTS)
    duration: int | None = None  # ns (`for:`; None: until `fault: off`)
    rate: float = 1.0  # the random fraction of matching frames / bytes
    match: CanMatch | None = None  # CAN actions: which frames
    every: int = 1  # CAN actions: each n-th matching frame
    delay: int = 0  # CAN delay, ns
    count: int | None = None  # CAN bursts: frames
    cob_id: int | None = None  # duplicate_pdo
    data: bytes | None = None  # duplicate_pdo
    params: dict[str, Any] = field(default_factory=dict)  # RS-485 / DI/DO fault parameters
    line: str | None = None  # DI/DO faults: the harness-driven line
    bus: str | None = None  # the CAN bus (default: the drive's)


@dataclass(frozen=True)
class ProduceArgs:
    node: int  # the heartbeat's node id
    heartbeat: int | None = None  # period ns; 0 = off; None = left as it is
    sync: int | None = None
    guard: int | None = None


@dataclass(frozen=True)
class SdoArgs:
    values: list[tuple[int, int, int]]  # (index, sub, value)
    keys: list[tuple[str, int]] = field(default_factory=list)  # each object as written, line


@dataclass(frozen=True)
class NmtArgs:
    command: str  # NMT_COMMANDS


class Fault(StepKind):
    """`fault: {can: drop, match: {...}, for: 2s}` and the RS-485 / DI/DO faults."""

    name = "fault"
    args: FaultArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> FaultArgs:
        if obj in ("off", False):
            return FaultArgs("off")
        m = v.mapping(obj, line, where)
        kinds = [k for k in ("can", "rs485", "dio") if k in m]
        if len(kinds) != 1:
            raise v.err(line, where, "one of can: (drop, delay, corrupt, duplicate, sdo_flood, "
                        "duplicate_pdo, bus_error), rs485: (...) or dio: (...); or `fault: off`")
        t = kinds[0]
        kind = m[t]
        out: dict[str, Any] = {"transport": t, "kind": kind, "duration": None, "rate": 1.0}
        if "for" in m:
            out["duration"] = v.duration(m, "for", where)
            if out["duration"] <= 0:
                raise v.err(m.kline("for"), join(where, "for"), "must be > 0")
        if t == "can" and kind in CAN_ACTIONS:
            v.keys(m, {"can", "match", "for", "rate", "every", "delay", "bus"}, where)
            out["match"] = (_match(v, m["match"], m.kline("match"), join(where, "match"))
                            if "match" in m else CanMatch())
            out["rate"] = _rate(v, m, where)
            out["every"] = 1
            if "every" in m:
                out["every"] = _int(v, m["every"], m.kline("every"), join(where, "every"), 1, 1000)
                if "rate" in m:
                    raise v.err(m.kline("every"), join(where, "every"),
                                "every (each n-th frame) or rate (a random fraction), not both")
            out["delay"] = v.duration(m, "delay", where, 10_000_000 if kind == "delay" else 0)
        elif t == "can" and kind in CAN_BURSTS:
            v.keys(m, {"can", "count", "cob_id", "data", "bus"}, where)
            least = 2 if kind in BURST_WINDOW_NS else 1  # "more than one" (L19933, L19941)
            out["count"] = (_int(v, m["count"], m.kline("count"), join(where, "count"), least,
                                 1000)
                            if "count" in m else {"sdo_flood": 3, "duplicate_pdo": 2,
                                                  "bus_error": 17}[kind])
            if kind == "duplicate_pdo":
                if "cob_id" not in m:
                    raise v.err(line, join(where, "cob_id"), "missing: the RPDO's COB-ID")
                out["cob_id"] = _ids(v, m["cob_id"], m.kline("cob_id"), join(where, "cob_id"))[0]
                data = m.get("data", "")
                try:
                    if not isinstance(data, str):
                        raise ValueError
                    out["data"] = bytes.fromhex(data)
                except ValueError:
                    raise v.err(m.kline("data"), join(where, "data"),
                                f"{shorten(data)}: hex bytes as text, e.g. \"0F00\"") from None
                if len(out["data"]) > 8:  # a classic CAN data field (CiA 301)
                    raise v.err(m.kline("data"), join(where, "data"),
                                f"{len(out['data'])} bytes: a CAN frame carries at most 8")
        elif t == "rs485" and kind in SERIAL_FAULTS:
            v.keys(m, {"rs485", "for", "rate", "delay", "gap", "bytes", "line"}, where)
            out["rate"] = _rate(v, m, where)
            params = {"delay_ms": v.duration(m, "delay", where, 20_000_000) / 1e6,
                      "gap_ms": v.duration(m, "gap", where, 5_000_000) / 1e6,
                      "bytes": _int(v, m.get("bytes", 3), m.kline("bytes") if "bytes" in m
                                    else line, join(where, "bytes"), 1, 256)}
            out["params"] = {k: x for k, x in params.items() if k in _SERIAL_PARAMS[kind]}
        elif t == "dio" and kind in DIO_FAULTS:
            v.keys(m, {"dio", "line", "for", "level", "bounces", "period"}, where)
            ln = m.get("line")
            if not isinstance(ln, str) or not _LINE_RE.match(ln):
                raise v.err(m.kline("line") if "line" in m else line, join(where, "line"),
                            f"{ln!r}: a harness-driven line like DI5 or STO_A")
            out["line"] = ln
            if kind == "stuck":
                out["params"] = {"level": v.boolean(m, "level", where, False)}
            else:
                out["params"] = {"bounces": _int(v, m.get("bounces", 3), line,
                                                 join(where, "bounces"), 1, 100),
                                 "period_ms": v.duration(m, "period", where, 1_000_000) / 1e6}
        else:
            known = {"can": CAN_ACTIONS + CAN_BURSTS, "rs485": SERIAL_FAULTS, "dio": DIO_FAULTS}[t]
            raise v.err(m.kline(t), join(where, t), f"{kind!r}: one of {', '.join(known)}")
        if "bus" in m:
            out["bus"] = v.text(m, "bus", where)
        return FaultArgs(**out)

    def check(self, cc: CheckContext) -> None:
        if not cc.bench.faults_allowed:
            raise cc.err(f"fault injection is not allowed on bench {cc.bench.name!r} "
                         "(faults_allowed: false; docs/faults.md)")
        a, d = self.args, cc.drive
        t = a.transport
        if t == "can":
            bus = a.bus or d.can
            if bus is None:
                raise cc.err(f"drive {cc.dname} has no CAN bus on bench {cc.bench.name!r}")
            if bus not in cc.bench.can:
                raise cc.err(f"no CAN bus {bus!r} on bench {cc.bench.name!r} (buses: "
                             f"{', '.join(cc.bench.can) or 'none'})", "bus")
            window = BURST_WINDOW_NS.get(a.kind)
            if window is not None:  # the burst must fit the window on the wire at all
                bitrate = can_bitrate(cc.bench.can[bus])
                wire_ns = a.count * frame_bits(_burst_frames(a, 1)[0]) * 1e9 / bitrate
                if wire_ns >= window:
                    raise cc.err(f"{a.count} frames take {wire_ns / 1e3:.0f} µs on the wire at "
                                 f"{bitrate / 1e3:g} kbit/s, not within the {window / 1e6:g} ms "
                                 f"{a.kind} needs (AL111/AL112)", "count")
        elif t == "rs485" and d.rs485 is None:
            raise cc.err(f"drive {cc.dname} has no RS-485 line on bench {cc.bench.name!r}")
        elif t == "dio":
            line = a.line
            if d.dio is None:
                raise cc.err(f"drive {cc.dname} has no DI/DO lines on bench "
                             f"{cc.bench.name!r}", "line")
            if line.startswith("DI") and not 1 <= int(line[2:]) <= DI_LINES:
                raise cc.err(f"{line!r}: the A3 has DI1..DI{DI_LINES} on CN1", "line")

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        return Outcome(self._run(ctx, d))

    def _run(self, ctx: StepContext, d: DriveIO) -> str:
        a = self.args
        sess = ctx.session
        if a.transport == "off":
            sess.stop_faults()
            return "every fault ended"
        kind, dur = a.kind, a.duration
        if a.transport == "can":
            bus = sess.fault_can.get(_bus_name(a.bus, d))
            if bus is None:
                raise RuntimeError("no fault layer on this CAN bus (faults_allowed: false)")
            if kind in CAN_ACTIONS:
                match = a.match
                bus.inject(kind, match=match, duration_ns=dur, rate=a.rate, delay_ns=a.delay,
                           every=a.every)
                return f"{kind} {match.describe() or 'every frame'} on can:{bus.name}"
            return _burst(bus, kind, _burst_frames(a, _node(d)))
        if a.transport == "rs485":
            line = sess.fault_serial.get(d.spec.rs485 or "")
            if line is None:
                raise RuntimeError("no fault layer on this RS-485 line")
            line.inject(kind, duration_ns=dur, rate=a.rate, **a.params)
            return f"{kind} on rs485:{d.spec.rs485}"
        port = sess.fault_dio.get(d.name)
        if port is None:
            raise RuntimeError(f"no fault layer on the DI/DO of drive {d.name}")
        port.inject(kind, a.line, duration_ns=dur, **a.params)
        return f"{kind} on {a.line} of {d.name}"

    def describe(self) -> str:
        a = self.args
        if a.transport == "off":
            return "fault off"
        dur = f" for {fmt_ms(a.duration)}ms" if a.duration else ""
        return f"fault {a.transport} {a.kind}{dur}"


class Produce(StepKind):
    """`produce: {heartbeat: 100ms, sync: off}`: the master's periodic frames."""

    name = "produce"
    args: ProduceArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> ProduceArgs:
        if obj in ("off", False):  # `produce: off`: every cyclic frame the harness sends
            return ProduceArgs(node=0x7F, heartbeat=0, sync=0, guard=0)
        m = v.mapping(obj, line, where)
        v.keys(m, {"heartbeat", "sync", "guard", "node"}, where)
        out: dict[str, Any] = {"node": _int(v, m.get("node", 0x7F), line, join(where, "node"),
                                            1, 127)}
        for k in ("heartbeat", "sync", "guard"):
            if k not in m:
                continue
            if m[k] in ("off", False):
                out[k] = 0
                continue
            try:
                out[k] = parse_duration(m[k])
            except ValueError as e:
                raise v.err(m.kline(k), join(where, k), str(e)) from None
            if out[k] < MIN_PRODUCE_NS:
                raise v.err(m.kline(k), join(where, k), "a period of at least 1ms, or off: the "
                            "A3 takes SYNC cycles of 1-10 ms (L17211-17244) and counts 1017h / "
                            "100Ch in ms; a shorter one floods the bus and starves the harness")
        if not any(k in out for k in ("heartbeat", "sync", "guard")):
            raise v.err(line, where,
                        "heartbeat: PERIOD, sync: PERIOD and/or guard: PERIOD (or off)")
        return ProduceArgs(**out)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        a = self.args
        net = ctx.session.nets.get(_bus_name(None, d))
        if net is None:
            raise RuntimeError(f"drive {d.name}: no CANopen network")
        tasks = ctx.store.setdefault("_produce", {})
        out = []
        for k in ("heartbeat", "sync", "guard"):
            period = getattr(a, k)
            if period is None:
                continue
            old = tasks.pop(k, None)
            if old is not None:
                old.stop()
            if not period:
                out.append(f"{k} off")
                continue
            if k == "heartbeat":
                msg = can.Message(arbitration_id=0x700 + a.node, data=b"\x05",
                                  is_extended_id=False)  # OPERATIONAL master
            elif k == "sync":
                msg = can.Message(arbitration_id=0x80, data=b"", is_extended_id=False)
            else:
                msg = can.Message(arbitration_id=0x700 + _node(d), is_remote_frame=True,
                                  is_extended_id=False)
            tasks[k] = CyclicSender(net.bus, msg, period / 1e9, on_late=_late_logger(ctx, k))
            ctx.session.on_close(tasks[k].stop)
            out.append(f"{k} every {fmt_ms(period)}ms")
        return Outcome(", ".join(out))

    def describe(self) -> str:
        a = self.args
        given = [(k, getattr(a, k)) for k in ("heartbeat", "sync", "guard")]
        return "produce " + ", ".join(f"{k} {'off' if not x else f'{fmt_ms(x)}ms'}"
                                      for k, x in given if x is not None)


class Sdo(StepKind):
    """`sdo: {1016h:1: 0x000A0064}`: raw object writes."""

    name = "sdo"
    args: SdoArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> SdoArgs:
        m = v.mapping(obj, line, where)
        values: list[tuple[int, int, int]] = []
        keys: list[tuple[str, int]] = []
        for k, x in m.items():
            if not isinstance(k, str):  # (keys keep their text: hil.yamlio)
                raise v.err(m.kline(k), join(where, str(k)), f"{k!r}: write the object as quoted "
                            "hex text, e.g. \"1017\" or \"1016:1\" (YAML reads 0x1017 as the "
                            "integer 4119)")
            mt = _OBJ_RE.match(k)
            if not mt:
                raise v.err(m.kline(k), join(where, shorten(k)), "an object like \"1016:1\" or "
                            "\"1006\"")
            index, sub = int(mt.group(1), 16), int(mt.group(2) or 0)
            if index == 0 or sub > 255:  # CiA 301: index 0000h is unused, sub-index 8 bits
                raise v.err(m.kline(k), join(where, k), "object index 0001h..FFFFh, sub-index "
                            "0..255")
            values.append((index, sub,
                           _int(v, x, m.kline(k), join(where, k), -(2**31), 2**32 - 1)))
            keys.append((k, m.kline(k)))
        if not values:
            raise v.err(line, where, "one or more objects: {\"1016:1\": 0x007F0064}")
        return SdoArgs(values, keys)

    def check(self, cc: CheckContext) -> None:
        """A value the object's type in the drive's EDS cannot carry is refused here: the
        driver encodes by that type and would send nothing (an object the EDS lacks goes
        as 32 bits, and the drive answers)."""
        check_can(cc)
        od = object_dictionary(EDS_PATH, cc.drive.node_id or 1)
        for (index, sub, value), (key, line) in zip(self.args.values, self.args.keys,
                                                     strict=True):
            why = value_refusal(od, index, sub, value)
            if why is not None:
                raise cc.err(f"{value}: {why} (fixtures/drive/a3.eds)", key, line)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        for index, sub, value in self.args.values:
            d.cia.write(index, sub, value)
            if (param := sdo_parameter(index, sub, value)) is not None:
                ctx.written(d.name, dict([param]))
        return Outcome(f"{len(self.args.values)} object(s) written")

    def describe(self) -> str:
        return "sdo " + ", ".join(f"{i:04X}h:{s}={x}" for i, s, x in self.args.values)


class Nmt(StepKind):
    """`nmt: stop`: an NMT command to the drive's node."""

    name = "nmt"
    args: NmtArgs

    @classmethod
    def parse(cls, v: Checker, obj: Any, line: int, where: str) -> NmtArgs:
        if not isinstance(obj, str) or obj not in NMT_COMMANDS:
            raise v.err(line, where, f"{obj!r}: one of {', '.join(NMT_COMMANDS)}")
        return NmtArgs(obj)

    def run(self, ctx: StepContext, step: Step, d: DriveIO) -> Outcome:
        net = ctx.session.nets.get(_bus_name(None, d))
        if net is None:
            raise RuntimeError(f"drive {d.name}: no CANopen network")
        net.send_message(0x000, bytes([NMT_COMMANDS[self.args.command], _node(d)]))
        return Outcome(f"NMT {self.args.command} to node {_node(d)}")

    def describe(self) -> str:
        return f"nmt {self.args.command}"


KINDS = (Fault, Produce, Sdo, Nmt)
