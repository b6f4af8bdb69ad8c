"""`Gateway`: a bench's CAN buses, RS-485 lines and DI/DO sets exported over zenoh.

One zenoh session per gateway; keys under `<lab>/<bench>` (hil.gateway.keys). Wire formats
are the transports' own, so a runner opens the exported buses with plain `zenoh:` URLs:

- CAN: `hil.transport.zenoh_can` samples; the sender time is the gateway's capture time
  (the adapter's timestamp, mapped onto the wall clock), so `ZenohMessage.sender_time_ns`
  on the runner is the bench's time, and its recorder uses it as publish_time.
- RS-485: `hil.transport.serial_line` chunks (`<key>/s2m` from the bench, `<key>/m2s` to
  it) with each character's end time, so Modbus line timing survives the hop.
- DI/DO: `<key>/<line>` = b"1"/b"0", attachment = capture wall ns (DESIGN.md layout).

Only the lease holder may send: every incoming sample must carry the holder's 16-byte token
as attachment (after the 8-byte time for DI/DO); anything else is dropped and counted
(`refused` in the health report). When a lease ends because its holder vanished
(liveliness token gone) or stopped renewing, the gateway drives the bench to its safe state
and records each action on `/safety` of its own MCAP recording.
"""

from __future__ import annotations

import contextlib
import json
import logging
import struct
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import can
import zenoh

from hil.gateway import keys
from hil.gateway.health import BusHealth
from hil.gateway.lease import NS, LeaseInfo, LeaseTable, iso
from hil.gateway.tls import TlsFiles, acl_section, check_exposure
from hil.protocol.canopen import SDO_REQUEST, SDO_RESPONSE
from hil.protocol.cia402 import CONTROLWORD
from hil.transport.can_bus import TappedBus, open_can
from hil.transport.dio import DioPort, is_input, open_dio
from hil.transport.serial_line import SerialLine, open_serial, pack_chunk, unpack_chunk
from hil.transport.urls import parse_url
from hil.transport.zenoh_can import SYNC_CHUNK
from hil.transport.zenoh_can import pack as pack_can
from hil.transport.zenoh_can import unpack as unpack_can
from hil.transport.zenoh_net import close_session, make_config, open_session, wait_connected

log = logging.getLogger(__name__)

TOKEN_LEN = 16
_T = struct.Struct("<q")
LEASE_TOPIC = "/gateway/lease"
HEALTH_TOPIC = "/gateway/health"

SafeStateFn = Callable[["Gateway", str], list[dict] | None]
CanFactory = Callable[[str, str], can.BusABC]
SerialFactory = Callable[[str, str], SerialLine]
DioFactory = Callable[[str, str, dict], DioPort]


@dataclass
class GatewayConfig:
    """How a gateway is reached and behaves (the `hil gateway` flags)."""

    lab: str = "lab"
    bench: str | None = None  # default: the bench file's `name`
    listen: list[str] = field(default_factory=list)
    connect: list[str] = field(default_factory=list)
    mode: str = "peer"
    tls: TlsFiles | None = None
    allow_cn: list[str] = field(default_factory=list)
    lease_timeout_s: float = 3.0
    health_period_s: float = 1.0
    record: Path | None = None
    safe_on_release: bool = True
    backoff_s: tuple[float, float] = (0.05, 2.0)  # reopen delay: first, max (doubling)
    # A chunk for the network ends after this much idle line; None: the line's Modbus t3.5,
    # so one chunk is one ADU however the adapter or pty delivers the bytes.
    serial_silence_s: float | None = None
    connect_timeout_s: float = 10.0


def _token_of(sample: zenoh.Sample, skip: int = 0) -> bytes | None:
    att = sample.attachment
    if att is None:
        return None
    raw = att.to_bytes()
    return raw[skip:] if len(raw) >= skip + TOKEN_LEN else None


class _Export:
    """Common part of an exported bus: health, reopen with backoff, refusal counting."""

    kind = ""

    def __init__(self, gw: Gateway, name: str, url: str, key: str) -> None:
        self.gw, self.name, self.url, self.key = gw, name, url, key
        self.health = BusHealth(self.kind, name, url, key)
        self._thread: threading.Thread | None = None
        self._opened_once = False
        self._refused_logged = 0.0
        self._entities: list[Any] = []

    def _declare(self) -> None:
        raise NotImplementedError

    def start(self) -> None:
        self._declare()
        self._thread = threading.Thread(target=self._run, daemon=True,
                                        name=f"gw-{self.kind}-{self.name}")
        self._thread.start()

    def _run(self) -> None:
        first, top = self.gw.config.backoff_s
        delay = first
        stop = self.gw._stop
        while not stop.is_set():
            if not self._is_open():
                try:
                    self._open()
                except Exception as e:  # an unplugged adapter fails in its own way
                    if self.health.down(e):
                        self.gw._link_changed(self, f"cannot open: {e}")
                    stop.wait(delay)
                    delay = min(delay * 2, top)
                    continue
                delay = first
                if self._opened_once:
                    with self.health.lock:
                        self.health.reopens += 1
                self._opened_once = True
                if self.health.up():
                    self.gw._link_changed(self, "open")
            self._poll()

    def _is_open(self) -> bool:
        raise NotImplementedError

    def _open(self) -> None:
        raise NotImplementedError

    def _poll(self) -> None:
        raise NotImplementedError

    def _lost(self, error: BaseException | str) -> None:
        self._close_backend()
        if self.health.down(error):
            self.gw._link_changed(self, f"lost: {self.health.last_error}")

    def _close_backend(self) -> None:
        raise NotImplementedError

    def _refuse(self, sample: zenoh.Sample) -> None:
        with self.health.lock:
            self.health.refused += 1
        now = time.monotonic()
        if now - self._refused_logged > 1.0:
            self._refused_logged = now
            self.gw._log("warning", f"{self.kind} {self.name}: dropped a sample on "
                         f"{sample.key_expr} from a peer without the lease")

    def stop(self) -> None:
        if self._thread is not None:
            self._thread.join(5)
        for e in self._entities:
            with contextlib.suppress(zenoh.ZError):
                e.undeclare()
        self._entities.clear()
        self._close_backend()


class CanExport(_Export):
    """One CAN bus: frames from the bench to `<key>`, holder's frames from `<key>` to it."""

    kind = "can"

    def __init__(self, gw: Gateway, name: str, url: str, factory: CanFactory) -> None:
        super().__init__(gw, name, url, keys.can(gw.prefix, name))
        self._factory = factory
        self._bus: can.BusABC | None = None
        self._lock = threading.Lock()
        self._offset_ns = 0  # adapter clock -> wall clock
        self._waiters: list[tuple[Callable[[can.Message], bool], threading.Event, list]] = []
        self.interface = parse_url(url, "can").scheme

    def _declare(self) -> None:
        s = self.gw.session
        self._pub = s.declare_publisher(self.key, express=True,
                                        congestion_control=zenoh.CongestionControl.BLOCK,
                                        allowed_destination=zenoh.Locality.REMOTE)
        sync_key = f"{self.key}/{SYNC_CHUNK}"  # ZenohBus's join handshake
        self._entities += [
            self._pub,
            s.declare_subscriber(self.key, self._on_sample, allowed_origin=zenoh.Locality.REMOTE),
            s.declare_queryable(sync_key, lambda q: q.reply(sync_key, b""),
                                allowed_origin=zenoh.Locality.REMOTE),
        ]

    def _is_open(self) -> bool:
        return self._bus is not None

    def _open(self) -> None:
        raw = self._factory(self.name, self.url)
        rec = self.gw.recorder
        bus = TappedBus(raw, rec, self.name, interface=self.interface) if rec else raw
        with self._lock:
            self._bus = bus

    def _close_backend(self) -> None:
        with self._lock:
            bus, self._bus = self._bus, None
        if bus is not None:
            with contextlib.suppress(Exception):
                bus.shutdown()

    def _poll(self) -> None:
        bus = self._bus
        if bus is None:
            return
        try:
            msg = bus.recv(0.05)
        except (OSError, can.CanError, ValueError) as e:
            if self._bus is bus:
                self._lost(e)
            return
        if msg is not None:
            self._forward(msg)

    def capture_ns(self, msg: can.Message) -> int:
        """The frame's capture time on the wall clock: the adapter's timestamp, shifted by
        a fixed offset if the adapter clock is not the wall clock (re-synced if >1 s off)."""
        now = time.time_ns()
        if not msg.timestamp:
            return now
        t = int(msg.timestamp * NS) + self._offset_ns
        if abs(t - now) > NS:
            self._offset_ns = now - int(msg.timestamp * NS)
            t = now
        return t

    def _forward(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.health.error_frame(msg.arbitration_id, bytes(msg.data or b""))
            self.gw._health_dirty.set()
        try:
            self._pub.put(pack_can(msg, self.capture_ns(msg)))
        except zenoh.ZError as e:
            log.warning("gateway %s: publish failed: %s", self.key, e)
        with self.health.lock:
            self.health.rx += 1
        if self._waiters:
            for pred, ev, out in list(self._waiters):
                if not ev.is_set() and pred(msg):
                    out.append(msg)
                    ev.set()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if not self.gw.lease.allows(_token_of(sample)):
            self._refuse(sample)
            return
        try:
            msg = unpack_can(sample.payload.to_bytes(), time.time(), self.name)
        except ValueError as e:
            self.gw._log("warning", f"can {self.name}: bad sample: {e}")
            return
        with contextlib.suppress(OSError, can.CanError):
            self.send(msg)

    def send(self, msg: can.Message) -> None:
        """Put a frame on the bench bus (raises OSError if the bus is down)."""
        bus = self._bus
        if bus is None:
            raise OSError(f"CAN bus {self.name} ({self.url}) is down: "
                          f"{self.health.last_error or 'not open'}")
        out = can.Message(arbitration_id=msg.arbitration_id, is_extended_id=msg.is_extended_id,
                          is_remote_frame=msg.is_remote_frame, is_fd=msg.is_fd,
                          bitrate_switch=msg.bitrate_switch, dlc=msg.dlc,
                          error_state_indicator=msg.error_state_indicator,
                          data=None if msg.is_remote_frame else bytes(msg.data or b""),
                          check=False)
        try:
            bus.send(out)
        except (OSError, can.CanError) as e:
            if self._bus is bus:
                self._lost(e)
            raise OSError(f"CAN bus {self.name}: send failed: {e}") from e
        with self.health.lock:
            self.health.tx += 1

    def request(self, msg: can.Message, answer: Callable[[can.Message], bool],
                timeout_s: float) -> can.Message | None:
        """Send `msg` and wait for the first received frame matching `answer`."""
        ev, out = threading.Event(), []
        entry = (answer, ev, out)
        self._waiters.append(entry)
        try:
            self.send(msg)
            ev.wait(timeout_s)
        finally:
            self._waiters.remove(entry)
        return out[0] if out else None


class SerialExport(_Export):
    """One RS-485 line: chunks with character times both ways."""

    kind = "rs485"

    def __init__(self, gw: Gateway, name: str, url: str, factory: SerialFactory) -> None:
        super().__init__(gw, name, url, keys.rs485(gw.prefix, name))
        self._factory = factory
        self.line: SerialLine | None = None

    def _declare(self) -> None:
        s = self.gw.session
        self._pub = s.declare_publisher(f"{self.key}/s2m", express=True,
                                        congestion_control=zenoh.CongestionControl.BLOCK,
                                        allowed_destination=zenoh.Locality.REMOTE)
        self._entities += [self._pub, s.declare_subscriber(
            f"{self.key}/m2s", self._on_sample, allowed_origin=zenoh.Locality.REMOTE)]

    def _is_open(self) -> bool:
        return self.line is not None and not self.line.closed

    def _open(self) -> None:
        self.line = self._factory(self.name, self.url)

    def _close_backend(self) -> None:
        line, self.line = self.line, None
        if line is not None:
            with contextlib.suppress(Exception):
                line.close()

    def _poll(self) -> None:
        line = self.line
        if line is None:
            return
        silence = self.gw.config.serial_silence_s
        try:
            frame = line.read_frame(silence_s=silence, timeout=0.05)  # None: t3.5
        except OSError as e:
            self._lost(e)
            return
        if frame is None:
            if line.closed and not self.gw._stop.is_set():
                self._lost("serial line closed")
            return
        start = frame.t_start_ns
        payload = pack_chunk(frame.data, line.wall_ns(start), [t - start for t in frame.times_ns])
        try:
            self._pub.put(payload)
        except zenoh.ZError as e:
            log.warning("gateway %s: publish failed: %s", self.key, e)
        with self.health.lock:
            self.health.rx += len(frame.data)

    def _on_sample(self, sample: zenoh.Sample) -> None:
        if not self.gw.lease.allows(_token_of(sample)):
            self._refuse(sample)
            return
        try:
            data, _t0, _pub, _rel = unpack_chunk(sample.payload.to_bytes())
        except (ValueError, struct.error) as e:
            self.gw._log("warning", f"rs485 {self.name}: bad sample: {e}")
            return
        line = self.line
        if line is None:
            with self.health.lock:
                self.health.errors += 1
            return
        try:
            line.write(data)
        except OSError as e:
            self._lost(e)
            return
        with self.health.lock:
            self.health.tx += len(data)


class DioExport(_Export):
    """One drive's DI/DO/STO lines: outputs published on change, holder sets inputs."""

    kind = "dio"

    def __init__(self, gw: Gateway, name: str, url: str, mapping: dict,
                 factory: DioFactory) -> None:
        super().__init__(gw, name, url, keys.dio(gw.prefix, name))
        self._factory = factory
        self._mapping = mapping
        self.port: DioPort | None = None
        self._unsub: Callable[[], None] | None = None
        self._pubs: dict[str, zenoh.Publisher] = {}
        self._plock = threading.Lock()

    def _declare(self) -> None:
        s = self.gw.session
        self._entities += [
            s.declare_subscriber(f"{self.key}/*", self._on_sample,
                                 allowed_origin=zenoh.Locality.REMOTE),
            s.declare_queryable(f"{self.key}/**", self._on_query),
        ]

    def _is_open(self) -> bool:
        return self.port is not None

    def _open(self) -> None:
        port = self._factory(self.name, self.url, self._mapping)
        self.port = port
        self._unsub = port.subscribe(self._on_change)
        for line, level in port.levels().items():
            if not port.owns(line):
                self._publish(line, level, time.time_ns())

    def _poll(self) -> None:
        self.gw._stop.wait(0.2)

    def _close_backend(self) -> None:
        port, self.port = self.port, None
        if self._unsub is not None:
            self._unsub()
            self._unsub = None
        if port is not None:
            with contextlib.suppress(Exception):
                port.close()
        with self._plock:
            for p in self._pubs.values():
                with contextlib.suppress(zenoh.ZError):
                    p.undeclare()
            self._pubs.clear()

    def _publish(self, line: str, level: bool, t: int) -> None:
        with self._plock:
            pub = self._pubs.get(line)
            if pub is None:
                pub = self._pubs[line] = self.gw.session.declare_publisher(
                    f"{self.key}/{line}", express=True,
                    congestion_control=zenoh.CongestionControl.BLOCK,
                    allowed_destination=zenoh.Locality.REMOTE)
        pub.put(b"1" if level else b"0", attachment=_T.pack(t))

    def _on_change(self, line: str, level: bool, t: int) -> None:
        with contextlib.suppress(zenoh.ZError):
            self._publish(line, level, t)
        with self.health.lock:
            self.health.rx += 1

    def _on_sample(self, sample: zenoh.Sample) -> None:
        line = str(sample.key_expr).rsplit("/", 1)[-1]
        try:
            if not is_input(line):
                return
        except ValueError:
            return
        if not self.gw.lease.allows(_token_of(sample, _T.size)):
            self._refuse(sample)
            return
        payload = sample.payload.to_bytes()
        if payload not in (b"0", b"1"):
            return
        with contextlib.suppress(OSError, ValueError):
            self.set(line, payload == b"1")

    def set(self, line: str, level: bool) -> None:
        port = self.port
        if port is None:
            raise OSError(f"DI/DO {self.name} ({self.url}) is down")
        try:
            port.set(line, level)
        except OSError as e:
            self._lost(e)
            raise
        with self.health.lock:
            self.health.tx += 1

    def _on_query(self, query: zenoh.Query) -> None:
        port = self.port
        if port is None:
            return
        t = _T.pack(time.time_ns())
        for line, level in port.levels().items():
            key = f"{self.key}/{line}"
            if zenoh.KeyExpr(key).intersects(query.key_expr):
                query.reply(key, b"1" if level else b"0", attachment=t)


class Gateway:
    """Export `bench` (hil.plan.bench.Bench) under `<lab>/<bench>` (see module docstring).

    Factories replace how buses are opened (tests inject unpluggable adapters);
    `safe_state(gateway, reason)` replaces the bench file's safe state.
    """

    def __init__(self, bench: Any, config: GatewayConfig | None = None, *,
                 can_factory: CanFactory | None = None,
                 serial_factory: SerialFactory | None = None,
                 dio_factory: DioFactory | None = None,
                 safe_state: SafeStateFn | None = None,
                 recorder: Any = None) -> None:
        self.bench = bench
        self.config = config = config or GatewayConfig()
        self.name = config.bench or bench.name
        self.prefix = keys.prefix(config.lab, self.name)
        if not config.listen and not config.connect:
            raise ValueError("hil gateway: give at least one --listen or --connect endpoint")
        self._remote = check_exposure(config.listen, config.connect, config.tls,
                                      config.allow_cn)
        if config.tls is not None:
            config.tls.check()
        self.lease = LeaseTable(config.lease_timeout_s)
        self._own_recorder = recorder is None and config.record is not None
        if self._own_recorder:
            from hil.record.recorder import Recorder

            recorder = Recorder(config.record, metadata={"gateway": self.prefix,
                                                         "bench_file": bench.path})
        self.recorder = recorder
        self._safe_state = safe_state or default_safe_state
        self.safe_reports: list[dict] = []
        self._stop = threading.Event()
        self._health_dirty = threading.Event()
        self._threads: list[threading.Thread] = []
        self._entities: list[Any] = []
        self.session: zenoh.Session | None = None
        self.started_ns = 0
        can_factory = can_factory or (lambda _n, url: open_can(url))
        serial_factory = serial_factory or (
            lambda n, url: open_serial(url, tap=self.recorder, name=n))
        dio_factory = dio_factory or (lambda n, url, m: open_dio(
            url, role="harness", tap=self.recorder, name=n, mapping=m or None))
        self.can = {n: CanExport(self, n, u, can_factory) for n, u in bench.can.items()}
        self.rs485 = {n: SerialExport(self, n, u, serial_factory) for n, u in bench.rs485.items()}
        self.dio = {n: DioExport(self, n, d.dio, dict(d.dio_map), dio_factory)
                    for n, d in bench.drives.items() if d.dio}

    # -- lifecycle ------------------------------------------------------------------------
    def start(self) -> Gateway:
        try:
            self._start()
        except BaseException:
            self.stop()
            raise
        return self

    def _start(self) -> None:
        c = self.config
        cfg = make_config(c.mode, listen=c.listen, connect=c.connect, allow_remote=self._remote,
                          tls=c.tls.section() if c.tls else None)
        if c.allow_cn:
            cfg.insert_json5("access_control", json.dumps(acl_section(c.allow_cn)))
        self.session = s = open_session(cfg, what=f"hil gateway {self.prefix}")
        self.started_ns = time.time_ns()
        if c.connect:
            wait_connected(s, c.connect_timeout_s, what=f"hil gateway {self.prefix}",
                           endpoints=c.connect)
        if self.recorder is not None:
            self.recorder.add_metadata("hil.gateway", {
                "lab": c.lab, "bench": self.name, "prefix": self.prefix,
                "listen": c.listen, "connect": c.connect, "mode": c.mode,
                "tls": c.tls is not None, "allow_cn": c.allow_cn,
                "lease_timeout_s": c.lease_timeout_s, "zid": str(s.zid())})
            if getattr(self.bench, "text", ""):
                self.recorder.attach("bench.yaml", self.bench.text.encode(), "application/yaml")
        for export in self.exports():
            export.start()
        self._health_pub = s.declare_publisher(keys.health(self.prefix))
        self._entities += [
            self._health_pub,
            s.declare_queryable(keys.health(self.prefix),
                                lambda q: q.reply(keys.health(self.prefix), self._health_json())),
            s.declare_queryable(keys.info(self.prefix),
                                lambda q: q.reply(keys.info(self.prefix),
                                                  json.dumps(self.info()))),
            s.declare_queryable(keys.lease(self.prefix), self._on_lease_query),
            s.liveliness().declare_subscriber(keys.lease_alive(self.prefix), self._on_alive,
                                              history=True),
        ]
        t = threading.Thread(target=self._housekeeping, daemon=True, name="gw-housekeeping")
        t.start()
        self._threads.append(t)
        self._log("info", f"gateway {self.prefix} started: {self.describe()}")

    def exports(self) -> list[_Export]:
        return [*self.can.values(), *self.rs485.values(), *self.dio.values()]

    def wait_ready(self, timeout_s: float = 10.0) -> bool:
        """Wait until every export's link is up."""
        end = time.monotonic() + timeout_s
        while time.monotonic() < end:
            if all(e.health.link == "up" for e in self.exports()):
                return True
            time.sleep(0.005)
        return False

    def stop(self) -> None:
        """Stop exporting; a lease still held ends with the safe state."""
        if self.session is not None and self.lease.current is not None:
            info = self.lease.current
            self.lease.release(info.token)
            self._end(info, "gateway stopping", safe=True, wait=True)
        self._stop.set()
        for t in self._threads:
            t.join(5)
        for e in self._entities:
            with contextlib.suppress(zenoh.ZError):
                e.undeclare()
        self._entities.clear()
        for export in self.exports():
            export.stop()
        if self.session is not None:
            close_session(self.session)
            self.session = None
        if self._own_recorder and self.recorder is not None:
            self.recorder.close()
            self._own_recorder = False

    def __enter__(self) -> Gateway:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()

    # -- description and health ---------------------------------------------------------------
    def describe(self) -> str:
        parts = [f"{e.kind} {e.name} -> {e.key}" for e in self.exports()]
        eps = ", ".join(self.config.listen + self.config.connect)
        return f"{self.prefix} on {eps}: " + ("; ".join(parts) or "no buses")

    def info(self) -> dict:
        return {
            "lab": self.config.lab, "bench": self.name, "prefix": self.prefix,
            "can": {n: e.key for n, e in self.can.items()},
            "rs485": {n: e.key for n, e in self.rs485.items()},
            "dio": {n: e.key for n, e in self.dio.items()},
            "drives": {n: {"node_id": d.node_id, "can": d.can, "station": d.station,
                           "rs485": d.rs485, "dio": n if d.dio else None}
                       for n, d in self.bench.drives.items()},
            "lease_timeout_s": self.config.lease_timeout_s,
            "safe_state": self.bench.safe_state.controlword,
        }

    def health(self) -> dict:
        return {"lab": self.config.lab, "bench": self.name, "t_ns": time.time_ns(),
                "up_since_ns": self.started_ns, "lease": self.lease.status(),
                "buses": {f"{e.kind}/{e.name}": self._bus_health(e) for e in self.exports()}}

    def _bus_health(self, e: _Export) -> dict:
        snap = e.health.snapshot()
        if isinstance(e, CanExport) and e._bus is not None and snap["state"] != "bus-off":
            with contextlib.suppress(Exception):
                state = e._bus.state  # python-can: ACTIVE / PASSIVE / ERROR where offered
                snap["can_state"] = getattr(state, "name", str(state)).lower()
        return snap

    def _health_json(self) -> bytes:
        return json.dumps(self.health()).encode()

    def _link_changed(self, export: _Export, what: str) -> None:
        self._log("warning" if export.health.link == "down" else "info",
                  f"{export.kind} {export.name}: link {export.health.link} ({what})")
        self._health_dirty.set()

    def _housekeeping(self) -> None:
        period = self.config.health_period_s
        next_health = 0.0
        while not self._stop.wait(0.01):
            info = self.lease.expired()
            if info is not None:
                self._end(info, f"lease of {info.holder} expired: no keep-alive within "
                                f"{info.timeout_ns / NS:g} s", safe=True)
            now = time.monotonic()
            if self._health_dirty.is_set() or now >= next_health:
                self._health_dirty.clear()
                next_health = now + period
                doc = self.health()
                with contextlib.suppress(zenoh.ZError):
                    self._health_pub.put(json.dumps(doc))
                if self.recorder is not None:
                    self.recorder.write(HEALTH_TOPIC, doc)

    # -- leases ----------------------------------------------------------------------------
    def _on_lease_query(self, query: zenoh.Query) -> None:
        try:
            req = json.loads(query.payload.to_bytes()) if query.payload is not None else {}
            if not isinstance(req, dict):
                raise ValueError("not a JSON object")
            reply = self._lease_op(req)
        except (ValueError, TypeError) as e:
            reply = {"granted": False, "reason": f"bad request: {e}"}
        query.reply(keys.lease(self.prefix), json.dumps(reply))

    def _lease_op(self, req: dict) -> dict:
        op = req.get("op", "status")
        if op == "status":
            return self.lease.status()
        token = bytes.fromhex(str(req.get("token", "")))
        if op == "acquire":
            holder = str(req.get("holder", ""))
            before = self.lease.current
            granted, info = self.lease.acquire(holder, token, str(req.get("alive", "")))
            if granted and (before is None or before.token != token):
                self._lease_event("granted", holder, info)
            elif not granted:
                self._lease_event("refused", holder, info)
            return {"granted": granted, **info}
        if op == "renew":
            ok = self.lease.renew(token)
            return {"granted": ok, **self.lease.status()}
        if op == "release":
            ended = self.lease.release(token)
            if ended is not None:
                self._end(ended, f"released by {ended.holder}",
                          safe=self.config.safe_on_release)
            return {"released": ended is not None}
        raise ValueError(f"op {op!r}: must be acquire, renew, release or status")

    def _on_alive(self, sample: zenoh.Sample) -> None:
        if sample.kind != zenoh.SampleKind.DELETE:
            return
        alive_id = str(sample.key_expr).rsplit("/", 1)[-1]
        info = self.lease.gone(alive_id)
        if info is not None:
            self._end(info, f"holder {info.holder} disappeared (liveliness token gone)",
                      safe=True)

    def _lease_event(self, event: str, holder: str, info: dict) -> None:
        self._log("info", f"lease {event}: {holder} ({info.get('reason') or info.get('since')})")
        if self.recorder is not None:
            self.recorder.write(LEASE_TOPIC, {"event": event, "requester": holder, **info})

    def _end(self, info: LeaseInfo, reason: str, *, safe: bool, wait: bool = False) -> None:
        self._lease_event("ended", info.holder, {**info.public(), "reason": reason})
        if not safe:
            self.lease.safe_done()
            return

        def run() -> None:
            try:
                self.go_safe(reason, holder=info.holder)
            finally:
                self.lease.safe_done()

        if wait:
            run()
        else:
            t = threading.Thread(target=run, daemon=True, name="gw-safe-state")
            t.start()
            self._threads.append(t)

    # -- safe state --------------------------------------------------------------------------
    def go_safe(self, reason: str, *, holder: str = "") -> dict:
        """Drive the bench to its safe state now; every action recorded on /safety."""
        t0 = time.time_ns()
        if self.recorder is not None:
            self.recorder.safety("safe state start", reason, source="gateway", holder=holder)
        try:
            actions = self._safe_state(self, reason) or []
        except Exception as e:  # the safe state must never kill the gateway
            actions = [{"action": "safe state", "ok": False, "detail": f"{type(e).__name__}: {e}"}]
        ok = all(a.get("ok", True) for a in actions)
        report = {"reason": reason, "holder": holder, "ok": ok, "actions": actions,
                  "t_ns": t0, "duration_ms": (time.time_ns() - t0) / 1e6}
        self.safe_reports.append(report)
        if self.recorder is not None:
            self.recorder.safety("safe state done" if ok else "safe state INCOMPLETE", reason,
                                 source="gateway", holder=holder, ok=ok,
                                 duration_ms=report["duration_ms"])
        self._log("warning", f"safe state {'reached' if ok else 'INCOMPLETE'} ({reason})")
        return report

    def record_action(self, reason: str, drive: str, action: str, fn: Callable[[], Any],
                      **extra: Any) -> dict:
        """Run one safe-state action, never raising; record and return its outcome."""
        try:
            detail = fn()
            ok = detail is not False
            msg = detail if isinstance(detail, str) else ""
        except Exception as e:
            ok, msg = False, f"{type(e).__name__}: {e}"
        if self.recorder is not None:
            self.recorder.safety(action, reason, source="gateway", drive=drive, ok=ok,
                                 detail=msg, **extra)
        return {"drive": drive, "action": action, "ok": ok, "detail": msg, **extra}

    def _log(self, level: str, message: str) -> None:
        getattr(log, level if level != "warning" else "warning")(message)
        if self.recorder is not None:
            self.recorder.log(level, message, name="hil.gateway")


def sdo_write_controlword(node: int, value: int) -> can.Message:
    """Expedited SDO download of 2 bytes to 6040h:00 (CiA 301 ccs=1, n=2, e=1, s=1)."""
    data = bytes([0x2B, 0x40, 0x60, 0x00, value & 0xFF, value >> 8, 0, 0])
    return can.Message(arbitration_id=SDO_REQUEST + node, data=data, is_extended_id=False)


def default_safe_state(gw: Gateway, reason: str) -> list[dict]:
    """The bench file's `safe_state`: controlword by SDO to every CAN drive, DI functions
    (SON off) and STO levels on each drive's lines, then wait for BRKR off (brake engaged).
    Every action is attempted even if an earlier one failed."""
    bench = gw.bench
    safe = bench.safe_state
    timeout_s = safe.timeout_ns / NS
    actions: list[dict] = []
    cw = CONTROLWORD.get(safe.controlword)
    for name, d in bench.drives.items():
        if cw is not None and d.can and d.node_id and d.can in gw.can:
            export, node = gw.can[d.can], d.node_id

            def write(export: CanExport = export, node: int = node, cw: int = cw) -> str | bool:
                ans = export.request(
                    sdo_write_controlword(node, cw),
                    lambda m, node=node: m.arbitration_id == SDO_RESPONSE + node
                    and bytes(m.data[1:4]) == b"\x40\x60\x00",
                    min(timeout_s, 1.0))
                if ans is None:
                    return "sent; no SDO answer"
                if ans.data[0] == 0x60:
                    return "acknowledged"
                return False

            actions.append(gw.record_action(
                reason, name, f"controlword {safe.controlword} (0x{cw:04X})", write,
                bus=d.can, node_id=node))
        dio = gw.dio.get(name)
        if dio is None:
            continue
        for func, active in safe.di.items():
            wire = d.di.get(func)
            if wire is not None:
                level = wire.level_for(active)
                actions.append(gw.record_action(
                    reason, name, f"DI {func} {'on' if active else 'off'}",
                    lambda dio=dio, line=wire.line, level=level: dio.set(line, level),
                    line=wire.line, level=level))
        for ch, on in safe.sto.items():
            line = d.sto.get(ch, f"STO_{ch}")
            actions.append(gw.record_action(reason, name, f"STO {ch} {'on' if on else 'off'}",
                                            lambda dio=dio, line=line, on=on: dio.set(line, on),
                                            line=line, level=on))
    if safe.wait_brake:
        for name, d in bench.drives.items():
            wire, dio = d.do.get("BRKR"), gw.dio.get(name)
            if wire is None or dio is None:
                continue

            def brake(dio: DioExport = dio, wire: Any = wire) -> str | bool:
                port = dio.port
                if port is None:
                    return False
                port.wait_for(wire.line, wire.level_for(False), timeout_s)
                return "BRKR off: brake engaged"

            actions.append(gw.record_action(reason, name, "wait BRKR off (brake engaged)",
                                            brake, timeout_ms=timeout_s * 1e3))
    return actions


__all__ = [
    "Gateway",
    "GatewayConfig",
    "default_safe_state",
    "iso",
    "sdo_write_controlword",
]
