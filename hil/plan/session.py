"""The harness side of a bench: transports (tapped by the recorder) and drivers per drive.

`open_session(bench, recorder)` starts the virtual world first on a virtual bench, then
opens every harness-side transport from the (resolved) URLs, each with the recorder as tap:
CAN -> canopen.Network -> `Cia402Driver`; RS-485 -> `DeltaModbus`; DI/DO -> `DioPort`.
The same code runs on a real bench; only `world` is None there.
"""

from __future__ import annotations

import contextlib
from collections.abc import Callable
from typing import Any

import can
import canopen

from hil import clock
from hil.bench import virtual_module
from hil.bench.bench import CIA402_TIMEOUTS, Bench, DriveSpec
from hil.drivers.canopen_clock import ClockNetwork
from hil.drivers.cia402 import Cia402Driver, SdoError
from hil.drivers.delta_modbus import (
    DeltaModbus,
    ModbusExceptionError,
    ModbusReplyError,
    ModbusTimeoutError,
)
from hil.gateway.client import LeaseRefused, acquire
from hil.profile.params import parse_name
from hil.transport.can_bus import open_can
from hil.transport.dio import open_dio
from hil.transport.faults import FaultyCanBus, FaultyDio, FaultySerial, next_fault_id
from hil.transport.inline import can_inline, inline_pump
from hil.transport.pulse import open_pulse
from hil.transport.serial_line import open_serial


class BenchError(RuntimeError):
    """A bench resource that cannot be opened or used (names the resource and why)."""


class DriveIO:
    """Everything the runner does to one drive, whatever carries it."""

    def __init__(self, spec: DriveSpec, bench: Bench, *, dio: Any = None, cia: Any = None,
                 modbus: Any = None, pulse: Any = None) -> None:
        self.spec, self.bench = spec, bench
        self.dio, self._cia, self.modbus = dio, cia, modbus
        self.pulse = pulse  # the PLC's end of the drive's pulse line (docs/pulse.md)
        self._plc: Any = None

    def plc(self, params: Any, slice_ms: float = 10.0) -> Any:
        """The drive's PLC axis (`hil.drivers.plc_pulse.PulseMaster`) with FUN141 `params`;
        its position register and output count persist from step to step."""
        from hil.drivers.plc_pulse import PulseMaster
        if self.pulse is None:
            raise BenchError(f"drive {self.name}: no pulse line on this bench (`pulse:`)")
        if self._plc is None:
            self._plc = PulseMaster(self.pulse, params, slice_ms=slice_ms)
        else:
            params.check()
            self._plc.p = params
            self._plc.init_outputs()
            self._plc.slice_ns = max(1_000_000, round(slice_ms * 1_000_000))
        return self._plc

    @property
    def name(self) -> str:
        return self.spec.name

    # -- lines (electrical levels) -----------------------------------------------------------
    def set_line(self, line: str, level: bool) -> None:
        if self.dio is None:
            raise BenchError(f"drive {self.name}: no DI/DO lines on this bench")
        self.dio.set(line, level)

    def line(self, line: str) -> bool:
        if self.dio is None:
            raise BenchError(f"drive {self.name}: no DI/DO lines on this bench")
        return bool(self.dio.get(line))

    def set_function(self, func: str, active: bool) -> None:
        w = self.spec.di[func]
        self.set_line(w.line, w.level_for(active))

    def do_active(self, func: str) -> bool:
        w = self.spec.do[func]
        return w.active_from(self.line(w.line))

    # -- CiA 402 -----------------------------------------------------------------------------
    @property
    def cia(self) -> Any:
        if self._cia is None:
            raise BenchError(f"drive {self.name}: no CAN bus on this bench (CiA 402)")
        return self._cia

    # -- parameters --------------------------------------------------------------------------
    def read_param(self, name: str, via: str | None = None) -> int:
        via = via or self.spec.param_via
        if via == "modbus":
            if self.modbus is None:
                raise BenchError(f"drive {self.name}: no RS-485 line for {name} via modbus")
            return int(self.modbus.read_param(name))
        idx = _od_index(name)
        return int(self.cia.read(idx, 0))

    def write_param(self, name: str, value: int, via: str | None = None) -> None:
        via = via or self.spec.param_via
        if via == "modbus":
            if self.modbus is None:
                raise BenchError(f"drive {self.name}: no RS-485 line for {name} via modbus")
            self.modbus.write_param(name, value)
            return
        self.cia.write(_od_index(name), 0, value)

    def alarm(self, via: str | None = None) -> str | None:
        """Active alarm as P0.001 shows it (AL500 -> 0x0500, L17584), None when clear."""
        v = self.read_param("P0.001", via) & 0xFFFF
        return None if v == 0 else f"AL{v:03X}"


def refusal_code(exc: BaseException) -> int | None:
    """The drive's own refusal in an error: Modbus exception code (ModbusExceptionError.code)
    or SDO abort code (SdoError.abort_code); None for anything else (timeouts, local errors)."""

    if isinstance(exc, ModbusExceptionError):
        return int(exc.code)
    if isinstance(exc, SdoError) and exc.abort_code is not None:
        return int(exc.abort_code)
    return None


# What the harness itself found wrong on the line (`read: {..., expect_error: timeout}`):
# no (complete) reply in time, or a reply that is no valid answer (bad CRC, wrong station
# or function); comm_error = either. Never a value.
LINE_ERRORS = ("timeout", "bad_reply", "comm_error")


def line_error(exc: BaseException) -> str | None:
    """"timeout" / "bad_reply" for the harness master's own line errors, else None."""
    if isinstance(exc, ModbusTimeoutError):
        return "timeout"
    if isinstance(exc, ModbusReplyError):
        return "bad_reply"
    return None


def _od_index(name: str) -> int:
    """Parameter Px.yyy -> object 2xyyh (L16860: 2000h + group << 8 + index)."""

    group, index = parse_name(name)
    return 0x2000 + (group << 8) + index


class Session:
    """Open bench resources; `close()` releases them in reverse order."""

    def __init__(self, bench: Bench, recorder: Any, world: Any = None) -> None:
        self.bench, self.recorder, self.world = bench, recorder, world
        self.drives: dict[str, DriveIO] = {}
        self._closers: list[Callable[[], None]] = []
        self._safe_hooks: list[Callable[[], None]] = []
        self.lease: Any = None  # hil.gateway.client.Lease when the bench is behind a gateway
        # fault layers (bench faults_allowed) and CANopen networks, by bus / line / drive name
        self.nets: dict[str, Any] = {}
        self.fault_can: dict[str, Any] = {}
        self.fault_serial: dict[str, Any] = {}
        self.fault_dio: dict[str, Any] = {}

    def stop_faults(self, restore: bool = True) -> None:
        """End every injected fault now (`fault: off`; before a safe-state action needs the
        wire, with restore=False: a freed stuck DI keeps its level, no last command replayed)."""
        for layer in (*self.fault_can.values(), *self.fault_serial.values()):
            with contextlib.suppress(Exception):
                layer.stop_all()
        for dio in self.fault_dio.values():
            with contextlib.suppress(Exception):
                dio.stop_all(restore=restore)

    def check_lease(self) -> None:
        """Raise BenchError when the gateway lease was lost (the gateway made the bench safe)."""
        if self.lease is not None and self.lease.lost.is_set():
            why = self.lease.lost_reason or "expired"
            raise BenchError(f"lease of {self.lease.prefix} lost ({why}): the gateway drove "
                             "the bench to its safe state; nothing more is sent")

    def dead_drives(self) -> dict[str, str]:
        """Virtual drives whose process has died (name -> message); empty on a real bench."""
        dead = getattr(self.world, "dead", None)
        return dead() if callable(dead) else {}

    def check_alive(self) -> None:
        """Raise BenchError when a virtual drive's process has died."""
        dead = self.dead_drives()
        if dead:
            raise BenchError("; ".join(dead.values()))

    def drive(self, name: str | None) -> DriveIO:
        return self.drives[name or self.bench.default_drive]

    def idle(self, recorder: Any = None) -> None:
        """Every wired DI function inactive and 24 V on both STO channels, as an idle bench's
        wiring leaves them (b-contacts such as EMGS, NL, PL closed); every line's level is
        recorded first, so the first edge of a test is an edge in the recording."""
        rec = recorder or self.recorder
        for d in self.drives.values():
            if d.dio is None:
                continue
            now = clock.time_ns()
            for line, lv in sorted(d.dio.levels().items()):  # initial levels: known from t0
                rec.dio(d.name, line, bool(lv), now, None)
            for f in d.spec.di:
                d.set_function(f, False)
            for line in d.spec.sto.values():
                d.set_line(line, True)
        clock.sleep(0.02)  # beyond the P2.009 DI filter (L9229-9236) before the first step

    def before_safe(self, fn: Callable[[], None]) -> None:
        """Run `fn` before the safe state (an axis group's set-point stream stops first, so
        that its enabling controlwords cannot undo the safe state)."""
        self._safe_hooks.append(fn)

    def stop_streams(self) -> int:
        """Run the `before_safe` hooks (never raises); returns how many ran."""
        hooks, self._safe_hooks = self._safe_hooks, []
        for fn in hooks:
            with contextlib.suppress(Exception):
                fn()
        return len(hooks)

    def on_close(self, fn: Callable[[], None]) -> None:
        """Run `fn` when the session closes, before the transports opened so far close."""
        self._closers.append(fn)

    def close(self) -> None:
        for fn in reversed(self._closers):
            with contextlib.suppress(Exception):
                fn()
        self._closers.clear()
        if self.world is not None:
            with contextlib.suppress(Exception):
                self.world.close()
            self.world = None


def open_session(bench: Bench, recorder: Any, *, world_factory: Callable | None = None) -> Session:
    """Build the bench: the virtual world (if any), then the harness side."""
    world = None
    urls: dict[str, str] = {}
    if bench.virtual:
        if world_factory is None:  # loaded by name: a real bench never imports the model
            vw = virtual_module("world")
            world_factory = vw.VirtualWorld if bench.process == "inproc" else vw.SubprocessWorld
        world = world_factory(bench, recorder)
        urls = world.harness_urls()
    else:
        urls = {f"can:{k}": u for k, u in bench.can.items()}
        urls |= {f"rs485:{k}": u for k, u in bench.rs485.items()}
        urls |= {f"dio:{n}": d.dio for n, d in bench.drives.items() if d.dio}
        urls |= {f"pulse:{n}": d.pulse for n, d in bench.drives.items() if d.pulse}
    s = Session(bench, recorder, world)
    try:
        if bench.gateway is not None:
            urls = _lease_urls(s, urls)
        _open_harness(s, urls)
    except BaseException:
        s.close()
        raise
    return s


def _lease_urls(s: Session, urls: dict[str, str]) -> dict[str, str]:
    """Take the bench's lease from its gateway; `gateway` transports become zenoh URLs."""

    gw = s.bench.gateway
    assert gw is not None
    try:
        s.lease = acquire(gw.lab, gw.bench, holder=gw.holder, connect=gw.connect, mode=gw.mode)
    except LeaseRefused as e:  # its message names the bench already
        raise BenchError(str(e)) from e
    except ConnectionError as e:
        raise BenchError(f"bench {gw.lab}/{gw.bench}: gateway not reachable at "
                         f"{', '.join(gw.connect)}: {e}") from e
    s._closers.insert(0, s.lease.release)  # released last, after every transport closed
    s.lease.on_fault = _link_fault_recorder(s.recorder, f"zenoh:{gw.lab}/{gw.bench}",
                                            ",".join(gw.connect))
    s.recorder.log("info", f"lease of {gw.lab}/{gw.bench} taken as {s.lease.holder}",
                   name="hil.gateway")
    out = dict(urls)
    for key, url in urls.items():
        base, _, query = url.partition("?")
        if base != "gateway":
            continue
        kind, _, name = key.partition(":")
        if kind == "can":
            out[key] = s.lease.can_url(name)
        elif kind == "rs485":
            baud = dict(p.split("=", 1) for p in query.split("&") if "=" in p).get("baud")
            out[key] = s.lease.serial_url(name, int(baud) if baud else None)
        else:
            out[key] = s.lease.dio_url(name)
    return out


def _link_fault_recorder(rec: Any, transport: str, target: str) -> Callable[..., None]:
    """Lease.on_fault -> the /faults channel: a lost gateway link (or a lease the gateway
    ended) is a fault on the wire like an injected one, with its start and its end."""
    fault_id = next_fault_id()

    def record(kind: str, active: bool, t_ns: int, reason: str) -> None:
        rec.fault(kind, transport, active, fault_id, t=t_ns, target=target, reason=reason)
        if active:
            rec.log("error", f"{transport}: {reason}", name="hil.gateway")
    return record


def _open_harness(s: Session, urls: dict[str, str]) -> None:
    bench, rec = s.bench, s.recorder
    faults = bench.faults_allowed  # a passive layer until a `fault:` step (docs/faults.md)
    nets: dict[str, Any] = {}
    for bname in bench.can:
        url = urls[f"can:{bname}"]
        try:
            bus = open_can(url, tap=rec, name=bname)
        except Exception as e:
            raise BenchError(f"CAN bus {bname} ({url}): {e}") from e
        if faults:
            bus = s.fault_can[bname] = FaultyCanBus(bus, bname, sink=rec)
        # in virtual time canopen's own waits (SDO/LSS replies, heartbeat, EMCY, PDO) too
        net = ClockNetwork(bus) if clock.is_virtual() else canopen.Network(bus)
        # frames handed to canopen inside the clock's delivery events (virtual clock), or in
        # the thread that delivers each (inline.py), instead of a Notifier thread
        if clock.is_virtual() or can_inline(bus):
            from hil.transport.sim import ListenerPump, pump
            net.notifier = ListenerPump(bus, net.listeners,
                                        pump if clock.is_virtual() else inline_pump)
        else:
            net.notifier = can.Notifier(bus, net.listeners, 0.05)
        nets[bname] = s.nets[bname] = net
        s._closers.append(bus.shutdown)
        s._closers.append(net.notifier.stop)
    lines: dict[str, Any] = {}
    for lname in bench.rs485:
        url = urls[f"rs485:{lname}"]
        try:
            lines[lname] = open_serial(url, tap=rec, name=lname)
        except Exception as e:
            raise BenchError(f"RS-485 line {lname} ({url}): {e}") from e
        s._closers.append(lines[lname].close)
        if faults:
            lines[lname] = s.fault_serial[lname] = FaultySerial(lines[lname], lname, sink=rec)
    t = bench.timeouts
    for name, spec in bench.drives.items():
        dio = cia = mb = pulse = None
        if spec.pulse:
            url = urls[f"pulse:{name}"]
            try:
                pulse = open_pulse(url, role="master", tap=rec, name=name)
            except Exception as e:
                raise BenchError(f"pulse line of drive {name} ({url}): {e}") from e
            s._closers.append(pulse.close)
        if spec.dio:
            url = urls[f"dio:{name}"]
            try:
                dio = open_dio(url, role="harness", tap=rec, name=name,
                               mapping=spec.dio_map or None)
            except Exception as e:
                raise BenchError(f"DI/DO of drive {name} ({url}): {e}") from e
            s._closers.append(dio.close)
            if faults:
                dio = s.fault_dio[name] = FaultyDio(dio, name, sink=rec)
        if spec.can:
            cia = Cia402Driver(nets[spec.can], spec.node_id or 1,  # on a ClockNetwork
                               timeouts={k: t[k] / 1e9 for k in CIA402_TIMEOUTS})
        if spec.rs485:
            line = lines[spec.rs485]
            mb = DeltaModbus(line, station=spec.station or 1, mode=spec.modbus_mode,  # type: ignore[arg-type]
                             timeout_s=t["modbus"] / 1e9, baud=line.baudrate,
                             port_name=spec.rs485)
        s.drives[name] = DriveIO(spec, bench, dio=dio, cia=cia, modbus=mb, pulse=pulse)
