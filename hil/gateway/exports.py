"""The gateway's exported buses: one `_Export` per CAN bus, RS-485 line and DI/DO set.

Each export opens its bus on the bench, publishes what it sees under its zenoh key, accepts
only samples that carry the lease holder's token, and reopens its bus with backoff when the
link drops (health in `BusHealth`). Wire formats: hil/gateway/gateway.py's docstring.
"""

from __future__ import annotations

import contextlib
import logging
import struct
import threading
import time
from collections.abc import Callable
from typing import TYPE_CHECKING, Any

import can
import zenoh

from hil.gateway import keys
from hil.gateway.health import BusHealth
from hil.transport.can_bus import TappedBus
from hil.transport.dio import DioPort, is_input
from hil.transport.serial_line import SerialLine, pack_chunk, unpack_chunk
from hil.transport.urls import parse_url
from hil.transport.zenoh_can import SYNC_CHUNK
from hil.transport.zenoh_can import pack as pack_can
from hil.transport.zenoh_can import unpack as unpack_can
from hil.units import S

log = logging.getLogger(__name__)

TOKEN_LEN = 16
_T = struct.Struct("<q")

CanFactory = Callable[[str, str], can.BusABC]
SerialFactory = Callable[[str, str], SerialLine]
DioFactory = Callable[[str, str, dict], DioPort]

if TYPE_CHECKING:
    from hil.gateway.gateway import Gateway


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
        self._bad_logged = 0.0
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

    def _bad(self, why: str) -> None:
        """A sample from the holder that no device could send: dropped and counted (`bad`),
        logged at most once a second."""
        with self.health.lock:
            self.health.bad += 1
        now = time.monotonic()
        if now - self._bad_logged > 1.0:
            self._bad_logged = now
            self.gw._log("warning", why)

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
        t = int(msg.timestamp * S) + self._offset_ns
        if abs(t - now) > S:
            self._offset_ns = now - int(msg.timestamp * S)
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
            if msg.is_error_frame:  # a controller signals errors, it never sends one
                raise ValueError("an error frame: no controller sends one as a frame")
        except ValueError as e:
            self._bad(f"can {self.name}: bad sample: {e}")
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

    def discard_output(self) -> None:
        """Drop the bytes written to the line that have not left yet (the lease ended)."""
        line = self.line
        if line is not None:
            with contextlib.suppress(OSError):
                line.discard_output()

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
            self._bad(f"rs485 {self.name}: bad sample: {e}")
            return
        line = self.line
        if line is None:
            with self.health.lock:
                self.health.errors += 1
            return
        try:
            line.write(data)
        except OSError as e:
            if self.line is line:  # not a line the poll thread has reopened since
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
            self._bad(f"dio {self.name}: bad sample on {line}: not 0 or 1")
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
