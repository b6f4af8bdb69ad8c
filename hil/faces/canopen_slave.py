"""The virtual A3's CANopen face: a CiA 301 slave (NMT, heartbeat, guarding, SDO, PDO, SYNC,
EMCY) on a python-can bus, in front of a `Drive` (2000h-2FFFh and 6000h-6FFFh objects).

Built on python-can only: canopen.LocalNode lacks NMT gating, PDO behaviour and EMCY/1001h/
1003h handling (docs/dev/feasibility.md §3). Choices where the manual is silent:
docs/manual-choices.md#canopen.

This module receives frames, dispatches them and runs the timers; the protocol lives in
`canopen_nmt.py` (NMT, heartbeat, guarding, EMCY), `canopen_sdo.py` (the SDO server) and
`canopen_pdo.py` (PDOs). The face translates and decides nothing: what the drive does about
its traffic (AL111, AL112, AL180, AL185, AL301, AL3E2, AL3E3) is the drive's own
supervision (`drive.comm`, hil/model/comm_supervision.py), which the face feeds.

Threading: `start()` runs one receive thread. Every frame is handled while holding `lock`
(the DriveHost's RLock), and so is every timer step. Timers (heartbeat, event timers,
inhibit times, guarding, SDO timeout) run in `tick(now_ns)`: either from our own thread
(`own_timer=True`, default, clock = time.monotonic_ns) or from the host's 1 ms ticker
(`own_timer=False`, pass `clock=host.model_now` and `host.add_tick(slave.tick)`).
"""

from __future__ import annotations

import logging
import threading
import time
from collections.abc import Callable
from typing import Any

import can

from hil import clock
from hil.faces.canopen_nmt import NmtErrorControl
from hil.faces.canopen_pdo import HARNESS_PDOS, PdoEngine, PdoRun
from hil.faces.canopen_sdo import SdoServer, Transfer
from hil.faces.last_resort import LastResort
from hil.model.events import AlarmChanged, PowerCycled
from hil.profile.od import ObjectDictionary
from hil.protocol import canopen as cop
from hil.units import MS, US

log = logging.getLogger(__name__)

# P3.001 digit Z -> bit rate (L10529-L10533; Z=3 is 800 kbit/s there, 750 kbit/s in L16844).
BITRATES = {0: 125_000, 1: 250_000, 2: 500_000, 3: 750_000, 4: 1_000_000}

IP_MODE = 7  # 6060h/6061h interpolated position (L17211)


def sent_ns(msg: can.Message) -> int:
    """When the frame was sent (wall ns): the zenoh sender stamp, python-can's timestamp
    (the virtual bus stamps at send), else now."""
    t = getattr(msg, "sender_time_ns", None)
    if t:
        return int(t)
    if msg.timestamp:
        return int(msg.timestamp * 1e9)
    return clock.time_ns()



class CanopenSlave(NmtErrorControl, SdoServer, PdoEngine):
    """CiA 301 slave for one drive. See the module docstring for threading."""

    def __init__(
        self,
        bus: can.BusABC,
        drive: Any,
        *,
        node_id: int | None = None,
        lock: threading.RLock | None = None,
        od: ObjectDictionary | None = None,
        pdo_defaults: str = "manual",
        own_timer: bool = True,
        clock: Callable[[], int] = time.monotonic_ns,
        sdo_timeout_ms: int = 1000,
        block_transfer: bool = False,
        on_nmt_reset: Callable[[str], None] | None = None,
        on_frame: Callable[[can.Message, int, int], None] | None = None,
    ) -> None:
        if pdo_defaults not in ("harness", "manual"):
            raise ValueError(f"pdo_defaults: {pdo_defaults!r} is not 'harness' or 'manual'")
        if block_transfer:
            raise ValueError("block_transfer: the A3 supports expedited SDO only (L16942)")
        self.bus = bus
        self.drive = drive
        self.lock = lock or threading.RLock()
        self.od = od or ObjectDictionary.a3()
        self.pdo_defaults = pdo_defaults
        self.own_timer = own_timer
        self.clock = clock
        self.sdo_timeout_ns = sdo_timeout_ms * MS
        self.comm = drive.comm  # the drive's supervision of this traffic (AL111 ... AL3E3)
        # a failing alarm path is counted and logged here, as any other failure of the face
        self.comm.on_error = lambda code, exc: self.last_resort(f"alarm {code}", exc)
        # (frame, its sender stamp, model time it acted) per frame handled: delivery delay
        self.on_frame = on_frame
        self.on_nmt_reset = on_nmt_reset or getattr(drive, "nmt_reset", None)
        self.on_nmt_stop = getattr(drive, "nmt_stop", None)
        self._fixed_node_id = node_id
        self.node_id = 0
        self.bitrate = 0
        self.state = "INITIALISING"
        self._emcy_shown: str | None = None
        self._emcy_sent: str | None = None  # the alarm of the last EMCY sent (None: 0000h)
        self._full_path_cobs: frozenset[int] | None = None  # see _passes_by
        self.stats = {"rx": 0, "tx": 0, "sdo_aborts": 0, "pdo_errors": 0, "tx_errors": 0}
        # anything no CiA 301 rule answers (a model bug, a failing callback): counted, logged
        # once per kind; SDO requests still get the general abort 0800 0000
        self.last_resort = LastResort(log, "CANopen")
        self._values: dict[tuple[int, int], Any] = {}
        self._pdo: dict[int, PdoRun] = {}
        self._transfer: Transfer | None = None
        self._hb_next: int | None = None
        self._guard_toggle = 0
        self._history_cleared: tuple | None = None
        self._sdo_replied = False  # the request being served was answered
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._unsubscribe: Callable[[], None] | None = None

    @property
    def rx_error_counter(self) -> int:
        """The controller's receive error counter (kept by the drive's supervision)."""
        return self.comm.rx_error_counter

    # ------------------------------------------------------------------ lifecycle
    def start(self, *, thread: bool = True) -> CanopenSlave:
        """Subscribe to drive events, boot (boot-up frame, PRE-OPERATIONAL), start the thread
        (`thread=False`: the owner hands each frame to `feed`, e.g. on a virtual clock)."""
        with self.lock:
            self._unsubscribe = self.drive.subscribe(self._on_event)
            self._reset("power-on")
        if not thread:
            return self
        self._stop.clear()
        self._thread = threading.Thread(
            target=self._run, name=f"canopen-{self.node_id}", daemon=True
        )
        self._thread.start()
        return self

    def close(self) -> None:
        """Stop the thread and unsubscribe (the bus stays open: its owner closes it)."""
        self._stop.set()
        if self._thread is not None:
            self._thread.join(timeout=2.0)
            self._thread = None
        if self._unsubscribe is not None:
            self._unsubscribe()
            self._unsubscribe = None

    def __enter__(self) -> CanopenSlave:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()

    def feed(self, msg: can.Message) -> None:
        """Handle one received frame (what the receive thread does with each)."""
        if self._passes_by(msg):
            return
        try:
            with self.lock:
                self.handle_frame(msg)
        except Exception as exc:  # last resort: the face keeps serving the bus
            self.last_resort("receive loop", exc)

    def _run(self) -> None:
        while not self._stop.is_set():
            try:
                msg = self.bus.recv(timeout=0.001 if self.own_timer else 0.05)
            except Exception as exc:  # a closed bus ends the thread
                if self._stop.is_set():
                    return
                self.last_resort("CAN receive", exc)
                time.sleep(0.01)
                continue
            try:
                with self.lock:
                    if msg is not None:
                        self.handle_frame(msg)
                    if self.own_timer:
                        self.tick(self.clock())
            except Exception as exc:  # last resort: the thread keeps serving the bus
                self.last_resort("receive loop", exc)

    # ------------------------------------------------------------------ sending
    def _send(self, can_id: int, data: bytes = b"", remote: bool = False) -> None:
        try:
            self.bus.send(
                can.Message(
                    arbitration_id=can_id, data=data, is_extended_id=False, is_remote_frame=remote
                )
            )
            self.stats["tx"] += 1
        except Exception:  # a full or closed bus must not kill the slave
            self.stats["tx_errors"] += 1

    # ------------------------------------------------------------------ NMT
    def _reset(self, kind: str) -> None:
        """Power-on / reset node / reset communication: reload 1xxx, boot-up, PRE-OP."""
        self.state = "INITIALISING"
        self._emcy_shown = None  # the alarm the last EMCY carried (L17063)
        self._emcy_sent = None  # a boot-up: the master starts its view anew
        if self._fixed_node_id is not None:
            self.node_id = self._fixed_node_id
        else:
            self.node_id = self._param(0x2300) & 0x7F  # P3.000 (L10496)
        if kind in ("power-on", "power cycle") or not self.bitrate:
            z = (self._param(0x2301) >> 8) & 0xF  # P3.001 Z needs power cycle (L10544)
            self.bitrate = BITRATES.get(z, 500_000)
        if not 1 <= self.node_id <= 127:
            log.error("node id %d out of 1..127 (P3.000, L10496): using 127", self.node_id)
            self.node_id = 127
        self._values = {}
        self._full_path_cobs = None
        for (index, sub), e in self.od.entries.items():
            if not (0x2000 <= index <= 0x2FFF or 0x6000 <= index <= 0x6FFF):
                self._values[(index, sub)] = e.default_for(self.node_id)
        if self.pdo_defaults == "harness":
            self._values.update(HARNESS_PDOS)
        self._pdo = {n: PdoRun() for n in range(8)}
        self._transfer = None
        self._hb_next = None
        self._guard_toggle = 0
        self.comm.reset()
        self._send(cop.HEARTBEAT + self.node_id, bytes([cop.STATE_BOOTUP]))  # boot-up
        self._set_state("PRE-OPERATIONAL")
        self._restart_heartbeat(self.clock())

    def _param(self, index: int) -> int:
        return int(self.drive.read_object(index, 0))


    # ------------------------------------------------------------------ monitoring
    def _ip_sync_monitored(self) -> bool:
        """SYNC is monitored in IP mode (6061h = 7) with 1006h > 0 (L17211-17232)."""
        if self._values.get((0x1006, 0), 0) <= 0:
            return False
        return int(self.drive.read_object(0x6061, 0)) == IP_MODE

    # ------------------------------------------------------------------ frames
    def _passes_by(self, msg: can.Message) -> bool:
        """A valid standard frame this node neither consumes nor answers (another node's
        PDO, SDO or heartbeat it does not watch): counted, and passed by without taking the
        lock or advancing the model. On a bus of N drives this keeps a frame's cost O(1) per
        node instead of a model step per node. Error frames, frames while the receive error
        counter is up, and every COB-ID this node's communication objects name (NMT, SYNC,
        its SDO, RPDOs, TPDOs for RTR, its own and its watched heartbeat) go the full way."""
        if msg.is_error_frame or self.comm.rx_error_counter or self.state == "INITIALISING":
            return False
        if msg.is_extended_id:
            return True  # _handle ignores them once the counter is settled
        cobs = self._full_path_cobs
        if cobs is None:
            cobs = self._full_path_cobs = self._cobs_handled()
        if msg.arbitration_id in cobs:
            return False
        self.stats["rx"] += 1
        return True

    def _cobs_handled(self) -> frozenset[int]:
        v, nid = self._values, self.node_id
        cobs = {cop.NMT, cop.HEARTBEAT + nid, v.get((0x1200, 1), cop.SDO_REQUEST + nid) & 0x7FF,
                v.get((0x1005, 0), 0x80) & 0x7FF}
        watched = (v.get((0x1016, 1), 0) >> 16) & 0x7F
        if watched:
            cobs.add(cop.HEARTBEAT + watched)
        for n in range(4):
            cobs.add(v.get((0x1400 + n, 1), 0) & 0x7FF)
            cobs.add(v.get((0x1800 + n, 1), 0) & 0x7FF)
        return frozenset(cobs)

    def handle_frame(self, msg: can.Message) -> None:
        """Dispatch one received frame (call with `lock` held). Never raises."""
        try:
            self._handle(msg)
        except Exception as exc:  # malformed traffic must never stop the slave
            self.last_resort(f"frame 0x{msg.arbitration_id:03X}", exc)
        if self.on_frame is not None and not msg.is_error_frame:
            self._callback("on_frame", self.on_frame, msg, sent_ns(msg), self.clock())

    def _callback(self, name: str, fn: Callable[..., Any], *args: Any) -> None:
        """Call an owner's callback; a failing one must not stop the protocol action."""
        try:
            fn(*args)
        except Exception as exc:
            self.last_resort(name, exc)

    def _handle(self, msg: can.Message) -> None:
        if msg.is_error_frame:
            self.comm.error_frame()
            return
        self.comm.valid_frame()
        if msg.is_extended_id or self.state == "INITIALISING":
            return
        self.stats["rx"] += 1
        cid = msg.arbitration_id
        data = bytes(msg.data)
        nid = self.node_id
        now = self.clock()
        if cid == cop.NMT:
            self._on_nmt(data)
            return
        if cid == cop.HEARTBEAT + nid:
            if msg.is_remote_frame:
                self._on_guard(now)
            return
        if self.state == "STOPPED":
            self._on_heartbeat_in(cid, data, now, msg.is_remote_frame)
            return  # STOPPED: NMT and error control only (L17089-L17095)
        if cid == self._values.get((0x1200, 1), cop.SDO_REQUEST + nid) & 0x7FF:
            if not msg.is_remote_frame:
                self.comm.sdo_request(sent_ns(msg))
                self._sdo_replied = False
                self._on_sdo(data, now)
                if not self._sdo_replied:  # no answer: the buffer is free now
                    self.comm.sdo_answered(clock.time_ns())
            return
        if cid == self._values.get((0x1005, 0), 0x80) & 0x7FF:
            if self.state == "OPERATIONAL" and not msg.is_remote_frame:  # SYNC: a data frame
                period = self._values.get((0x1006, 0), 0) * US
                ip = int(self.drive.read_object(0x6061, 0)) == IP_MODE
                if ip and period <= 0:
                    self.comm.sync_period_error()  # AL305: IP on SYNC, 1006h = 0
                self.comm.sync(sent_ns(msg), now, period, ip and period > 0)
                self._on_sync(now)
            return
        if self._on_heartbeat_in(cid, data, now, msg.is_remote_frame):
            return
        if self.state != "OPERATIONAL":
            return
        for n in range(4):
            cob = self._values[(0x1400 + n, 1)]
            if not cob & 0x80000000 and cid == cob & 0x7FF and not msg.is_remote_frame:
                sent = sent_ns(msg)
                self.comm.rpdo(cid, sent)
                self._on_rpdo(n, data)
                self.comm.rpdo_processed(cid, sent, clock.time_ns())
            tcob = self._values[(0x1800 + n, 1)]
            if msg.is_remote_frame and not tcob & 0xC0000000 and cid == tcob & 0x7FF:
                run = self._pdo[4 + n]
                if self._values[(0x1800 + n, 2)] == 252 and run.sampled is not None:
                    self._send_tpdo(n, now, data=run.sampled)  # what the last SYNC sampled
                else:
                    self._send_tpdo(n, now, force=True)


    # ------------------------------------------------------------------ timers
    def tick(self, now: int) -> None:
        """Timers: heartbeat, guarding, event-driven TPDOs (change, inhibit, event timer),
        SDO timeout. Call with `lock` held (the host does) about every millisecond."""
        try:
            self._tick(now)
        except Exception as exc:
            self.last_resort("tick", exc)

    def _tick(self, now: int) -> None:
        if self.state == "INITIALISING":
            return
        if self._hb_next is not None and now >= self._hb_next:
            state = {"STOPPED": 4, "OPERATIONAL": 5, "PRE-OPERATIONAL": 127}[self.state]
            self._send(cop.HEARTBEAT + self.node_id, bytes([state]))
            period = self._values.get((0x1017, 0), 0) * MS
            self._hb_next = self._hb_next + period if period else None
            if self._hb_next is not None and self._hb_next <= now:
                self._hb_next = now + period  # we were late: do not burst
        if self.comm.timed_out(now):  # AL180
            self._comm_error()
        if self._transfer is not None and now - self._transfer.started > self.sdo_timeout_ns:
            e = self._transfer.entry
            self._transfer = None
            self._sdo_abort(e.index, e.sub, cop.ABORT_TIMEOUT)
        if self.state != "OPERATIONAL":
            return
        self.comm.sync_timed_out(now, self._ip_sync_monitored)  # AL3E3
        for n in range(4):
            if self._tpdo_active(n) and self._values[(0x1800 + n, 2)] >= 254:
                self._event_tpdo(n, now)


    def _on_event(self, ev: Any) -> None:
        """Drive events (delivered under the host lock)."""
        try:
            if isinstance(ev, AlarmChanged):
                if ev.code == "AL185" and not ev.active:
                    self.comm.bus_error_cleared()  # raised again by the next error frame
                self._emcy(ev)
            elif isinstance(ev, PowerCycled):
                self._reset("power cycle")
        except Exception as exc:
            self.last_resort(f"drive event {type(ev).__name__}", exc)

