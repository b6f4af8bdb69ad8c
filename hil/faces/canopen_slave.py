"""The virtual A3's CANopen face: a CiA 301 slave (NMT, heartbeat, guarding, SDO, PDO, SYNC,
EMCY) on a python-can bus, in front of a `Drive` (2000h-2FFFh and 6000h-6FFFh objects).

Built on python-can only: canopen.LocalNode lacks NMT gating, PDO behaviour and EMCY/1001h/
1003h handling (docs/dev/feasibility.md §3). Choices where the manual is silent:
docs/manual-choices.md#canopen.

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
from collections import deque
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import can

from hil import clock
from hil.faces.last_resort import LastResort
from hil.model import errors
from hil.model.errors import ObjectError
from hil.model.events import AlarmChanged, PowerCycled
from hil.model.options import ModelOptions
from hil.profile.od import Entry, ObjectDictionary
from hil.protocol import canopen as cop
from hil.units import MS, US

log = logging.getLogger(__name__)

# P3.001 digit Z -> bit rate (L10529-L10533; Z=3 is 800 kbit/s there, 750 kbit/s in L16844).
BITRATES = {0: 125_000, 1: 250_000, 2: 500_000, 3: 750_000, 4: 1_000_000}

IP_MODE = 7  # 6060h/6061h interpolated position (L17211)
ERROR_PASSIVE = 128  # AL185: "Rx/Tx error counter > 128" (L20029)


def sent_ns(msg: can.Message) -> int:
    """When the frame was sent (wall ns): the zenoh sender stamp, python-can's timestamp
    (the virtual bus stamps at send), else now."""
    t = getattr(msg, "sender_time_ns", None)
    if t:
        return int(t)
    if msg.timestamp:
        return int(msg.timestamp * 1e9)
    return clock.time_ns()


# Harness default PDOs (option pdo_defaults="harness"); the manual ships none (L17980-L18024).
HARNESS_PDOS: dict[tuple[int, int], int] = {
    (0x1400, 2): 255,
    (0x1600, 1): 0x60400010,
    (0x1600, 2): 0x60600008,
    (0x1600, 0): 2,
    (0x1800, 2): 255,
    (0x1800, 5): 10,  # event timer 10 ms: BaseNode402 needs a cyclic statusword (feas. §3.3)
    (0x1A00, 1): 0x60410010,
    (0x1A00, 2): 0x60610008,
    (0x1A00, 0): 2,
}


@dataclass
class _PdoRun:
    """Run-time state of one PDO (configuration lives in the OD values)."""

    last_data: bytes | None = None
    last_sent: int | None = None
    sync_count: int = 0
    pending: bytes | None = None  # synchronous RPDO waiting for the next SYNC


@dataclass
class _Transfer:
    """A segmented SDO transfer in progress."""

    upload: bool
    entry: Entry
    toggle: int = 0
    data: bytearray = field(default_factory=bytearray)
    size: int | None = None
    started: int = 0


class CanopenSlave:
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
        on_alarm: Callable[[str], None] | None = None,
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
        self.on_alarm = on_alarm or getattr(drive, "raise_alarm", None)
        # (frame, its sender stamp, model time it acted) per frame handled: delivery delay
        self.on_frame = on_frame
        self.on_nmt_reset = on_nmt_reset or getattr(drive, "nmt_reset", None)
        self.on_nmt_stop = getattr(drive, "nmt_stop", None)
        self._fixed_node_id = node_id
        self.node_id = 0
        self.bitrate = 0
        self.state = "INITIALISING"
        self._full_path_cobs: frozenset[int] | None = None  # see _passes_by
        self.stats = {"rx": 0, "tx": 0, "sdo_aborts": 0, "pdo_errors": 0, "tx_errors": 0}
        # anything no CiA 301 rule answers (a model bug, a failing callback): counted, logged
        # once per kind; SDO requests still get the general abort 0800 0000
        self.last_resort = LastResort(log, "CANopen")
        self._values: dict[tuple[int, int], Any] = {}
        self._pdo: dict[int, _PdoRun] = {}
        self._transfer: _Transfer | None = None
        self._hb_next: int | None = None
        self._hb_consumer_deadline: int | None = None
        self._life_deadline: int | None = None
        self._guard_toggle = 0
        self._history_cleared: tuple | None = None
        # communication monitoring (docs/faults.md)
        self._sdo_prev_sent: int | None = None  # sender time of the last SDO request
        self._sdo_answered = 0  # wall ns when the last SDO answer left
        self._sdo_replied = False  # the request being served was answered
        self._pdo_prev: dict[int, tuple[int, int]] = {}  # RPDO COB-ID -> (sent, processed)
        self.rx_error_counter = 0  # receive error counter (AL185, L20029)
        self._bus_error_raised = False
        self._sync_prev_sent: int | None = None
        self._sync_deadline: int | None = None
        self._sync_intervals: deque[int] = deque()
        self._thread: threading.Thread | None = None
        self._stop = threading.Event()
        self._unsubscribe: Callable[[], None] | None = None

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
        if self._fixed_node_id is not None:
            self.node_id = self._fixed_node_id
        else:
            self.node_id = self._param(0x2300, 0x7F) & 0x7F  # P3.000 (L10496)
        if kind in ("power-on", "power cycle") or not self.bitrate:
            z = (self._param(0x2301, 0x0203) >> 8) & 0xF  # P3.001 Z needs power cycle (L10544)
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
        self._pdo = {n: _PdoRun() for n in range(8)}
        self._transfer = None
        self._hb_next = None
        self._hb_consumer_deadline = None
        self._life_deadline = None
        self._guard_toggle = 0
        self._sync_reset()
        self._sdo_prev_sent = None
        self._pdo_prev = {}
        self._send(cop.HEARTBEAT + self.node_id, bytes([cop.STATE_BOOTUP]))  # boot-up
        self._set_state("PRE-OPERATIONAL")
        self._restart_heartbeat(self.clock())

    def _param(self, index: int, default: int) -> int:
        try:
            return int(self.drive.read_object(index, 0))
        except Exception:  # fake drives may not carry P3.xxx
            return default

    def _opt(self, name: str) -> Any:
        """A communication choice or deviation of the drive's ModelOptions."""
        opts = getattr(self.drive, "options", None)
        return getattr(opts if isinstance(opts, ModelOptions) else _DEFAULTS, name)

    def _set_state(self, state: str) -> None:
        if state == "OPERATIONAL" and self.state != "OPERATIONAL":
            for run in self._pdo.values():
                run.last_data = None
                run.last_sent = None
                run.pending = None
        self.state = state

    def _on_nmt(self, data: bytes) -> None:
        if len(data) != 2 or data[1] not in (0, self.node_id):
            return
        cs = data[0]
        if cs == cop.NMT_START:
            self._set_state("OPERATIONAL")
        elif cs == cop.NMT_STOP:
            self._set_state("STOPPED")
            if self.on_nmt_stop is not None:  # the drive decides (nmt_stop_action)
                self._callback("on_nmt_stop", self.on_nmt_stop)
        elif cs == cop.NMT_PRE_OPERATIONAL:
            self._set_state("PRE-OPERATIONAL")
        elif cs in (cop.NMT_RESET_NODE, cop.NMT_RESET_COMMUNICATION):
            kind = "reset node" if cs == cop.NMT_RESET_NODE else "reset communication"
            if self.on_nmt_reset is not None:
                self._callback("on_nmt_reset", self.on_nmt_reset, kind)  # AL401, alarm clearing
            self._reset(kind)

    def _restart_heartbeat(self, now: int) -> None:
        period = self._values.get((0x1017, 0), 0)
        self._hb_next = now + period * MS if period else None

    def _comm_error(self, alarm: str) -> None:
        """Heartbeat consumer / life guarding timeout: AL180 and 1029h (L17806-L17838)."""
        if self.on_alarm is not None:
            self._callback("on_alarm", self.on_alarm, alarm)
        behaviour = self._values.get((0x1029, 1), 0)
        if self._opt("dev_1029h_behaviour") is not None:  # deviation knob: 1029h not honoured
            behaviour = self._opt("dev_1029h_behaviour")
        if behaviour == 0 and self.state == "OPERATIONAL":
            self._set_state("PRE-OPERATIONAL")
        elif behaviour == 2:
            self._set_state("STOPPED")

    # ------------------------------------------------------------------ monitoring
    def _comm_alarm(self, alarm: str) -> None:
        """A communication alarm the drive raises without changing the NMT state."""
        if self.on_alarm is not None:
            self._callback("on_alarm", self.on_alarm, alarm)

    def _check_sdo_flood(self, sent: int) -> None:
        """AL111: a second SDO request within 1 ms, sent before the answer to the previous
        one left, overflows the one-deep SDO Rx buffer (L19933-19937)."""
        prev, self._sdo_prev_sent = self._sdo_prev_sent, sent
        window = self._opt("sdo_flood_window_us") * US
        if prev is None or self._opt("dev_ignore_sdo_flood"):
            return
        if sent - prev < window and sent < self._sdo_answered:
            self._comm_alarm("AL111")

    def _check_pdo_overflow(self, cob: int, sent: int) -> None:
        """AL112: two PDOs with the same COB-ID within 1 ms (L19941-19945), the second sent
        before the drive had processed the first (a one-deep receive buffer)."""
        prev = self._pdo_prev.get(cob)
        window = self._opt("pdo_overflow_window_us") * US
        if prev is None or self._opt("dev_ignore_pdo_overflow"):
            return
        if 0 <= sent - prev[0] < window and sent < prev[1]:
            self._comm_alarm("AL112")

    def _on_error_frame(self) -> None:
        """AL185: an error frame raises the receive error counter; above 128 (L20029)."""
        weight = self._opt("can_error_frame_weight")
        self.rx_error_counter = min(255, self.rx_error_counter + weight)
        limit = self._opt("dev_bus_error_limit") or ERROR_PASSIVE
        if self.rx_error_counter > limit and not self._bus_error_raised:
            self._bus_error_raised = True
            self._comm_alarm("AL185")

    def _ip_sync_monitored(self) -> bool:
        """SYNC is monitored in IP mode (6061h = 7) with 1006h > 0 (L17211-17232)."""
        if self._values.get((0x1006, 0), 0) <= 0:
            return False
        try:
            return int(self.drive.read_object(0x6061, 0)) == IP_MODE
        except Exception:  # fake drives without 6061h
            return False

    def _p3009_e(self) -> int:
        """P3.009 digit E, the sync error range in 10 us (lowest digit, 1-9; L10629-10645)."""
        try:
            e = int(self.drive.params.get("P3.009")) & 0xF
        except Exception:  # fake drives without parameters: the default 0x5055
            e = 5
        return min(max(e, 1), 9)

    def _sync_reset(self) -> None:
        self._sync_prev_sent = None
        self._sync_deadline = None
        self._sync_intervals = deque()

    def _monitor_sync(self, sent: int, now: int) -> None:
        """AL3E2 early SYNC, AL301 cycle != 1006h, and arm the AL3E3 timeout (docs/faults.md;
        thresholds: ModelOptions sync_*)."""
        if not self._ip_sync_monitored():
            self._sync_reset()
            return
        period = self._values[(0x1006, 0)] * US
        prev, self._sync_prev_sent = self._sync_prev_sent, sent
        late = round(self._opt("dev_sync_timeout_extra_ms") * MS)
        self._sync_deadline = now + round(self._opt("sync_timeout_cycles") * period) + late
        if prev is None:
            return
        dt = sent - prev
        early_limit = self._opt("sync_early_ratio") * period
        fail_tol = self._opt("sync_fail_tolerance") * period
        if self._opt("sync_tolerance") == "p3009":  # P3.009 E x 10 us (L10629-10645)
            e_us = self._p3009_e() * 10 * US
            early_limit, fail_tol = period - e_us, e_us
        if dt < early_limit and not self._opt("dev_ignore_early_sync"):
            self._comm_alarm("AL3E2")  # SYNC too early (L20159-20163)
            return
        window = max(1, int(self._opt("sync_fail_window")))
        self._sync_intervals.append(dt)
        while len(self._sync_intervals) > window:
            self._sync_intervals.popleft()
        if len(self._sync_intervals) == window:
            mean = sum(self._sync_intervals) / window
            off = abs(mean - period) > fail_tol
            if off and not self._opt("dev_ignore_sync_cycle"):
                self._comm_alarm("AL301")  # synchronisation failure (L20123-20127)
                self._sync_intervals.clear()

    # ------------------------------------------------------------------ frames
    def _passes_by(self, msg: can.Message) -> bool:
        """A valid standard frame this node neither consumes nor answers (another node's
        PDO, SDO or heartbeat it does not watch): counted, and passed by without taking the
        lock or advancing the model. On a bus of N drives this keeps a frame's cost O(1) per
        node instead of a model step per node. Error frames, frames while the receive error
        counter is up, and every COB-ID this node's communication objects name (NMT, SYNC,
        its SDO, RPDOs, TPDOs for RTR, its own and its watched heartbeat) go the full way."""
        if msg.is_error_frame or self.rx_error_counter or self.state == "INITIALISING":
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
            self._on_error_frame()
            return
        if self.rx_error_counter:
            self.rx_error_counter -= 1  # a valid frame (ISO 11898-1 fault confinement)
            if not self.rx_error_counter:
                self._bus_error_raised = False
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
                self._check_sdo_flood(sent_ns(msg))
                self._sdo_replied = False
                self._on_sdo(data, now)
                if not self._sdo_replied:  # no answer: the buffer is free now
                    self._sdo_answered = clock.time_ns()
            return
        if cid == self._values.get((0x1005, 0), 0x80) & 0x7FF:
            if self.state == "OPERATIONAL":
                self._monitor_sync(sent_ns(msg), now)
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
                self._check_pdo_overflow(cid, sent)
                self._on_rpdo(n, data)
                self._pdo_prev[cid] = (sent, clock.time_ns())
            tcob = self._values[(0x1800 + n, 1)]
            if msg.is_remote_frame and not tcob & 0xC0000000 and cid == tcob & 0x7FF:
                self._send_tpdo(n, now, force=True)

    def _on_guard(self, now: int) -> None:
        state = {"STOPPED": 4, "OPERATIONAL": 5, "PRE-OPERATIONAL": 127}.get(self.state, 0)
        self._send(cop.HEARTBEAT + self.node_id, bytes([self._guard_toggle << 7 | state]))
        self._guard_toggle ^= 1
        guard, factor = self._values.get((0x100C, 0), 0), self._values.get((0x100D, 0), 0)
        late = round(self._opt("dev_heartbeat_extra_ms") * MS)  # deviation knob
        self._life_deadline = now + guard * factor * MS + late if guard and factor else None

    def _on_heartbeat_in(self, cid: int, data: bytes, now: int, remote: bool) -> bool:
        if remote or not (0x701 <= cid <= 0x77F):
            return False
        watch = self._values.get((0x1016, 1), 0)
        node, t_ms = (watch >> 16) & 0x7F, watch & 0xFFFF
        if node and t_ms and cid == cop.HEARTBEAT + node and data:
            # A boot-up restarts monitoring; it starts with the first heartbeat (CiA 301).
            late = round(self._opt("dev_heartbeat_extra_ms") * MS)  # deviation knob
            self._hb_consumer_deadline = None if data[0] == 0 else now + t_ms * MS + late
        return True

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
        if self._hb_consumer_deadline is not None and now > self._hb_consumer_deadline:
            self._hb_consumer_deadline = None
            self._comm_error("AL180")
        if self._life_deadline is not None and now > self._life_deadline:
            self._life_deadline = None
            self._comm_error("AL180")
        if self._transfer is not None and now - self._transfer.started > self.sdo_timeout_ns:
            e = self._transfer.entry
            self._transfer = None
            self._sdo_abort(e.index, e.sub, errors.ABORT_TIMEOUT)
        if self.state != "OPERATIONAL":
            return
        if self._sync_deadline is not None and now > self._sync_deadline:
            self._sync_deadline = None  # re-armed by the next SYNC
            if self._ip_sync_monitored():
                self._comm_alarm("AL3E3")  # SYNC timeout in IP mode (L20165-20169)
                # synchronisation lost: a resumed SYNC starts anew, the gap is no interval
                self._sync_prev_sent = None
                self._sync_intervals.clear()
        for n in range(4):
            if self._tpdo_active(n) and self._values[(0x1800 + n, 2)] >= 254:
                self._event_tpdo(n, now)

    # ------------------------------------------------------------------ PDO
    def _mapping(self, map_index: int) -> list[tuple[int, int, int]]:
        count = self._values[(map_index, 0)]
        out = []
        for s in range(1, count + 1):
            v = self._values[(map_index, s)]
            out.append((v >> 16, (v >> 8) & 0xFF, v & 0xFF))
        return out

    def _tpdo_active(self, n: int) -> bool:
        return not self._values[(0x1800 + n, 1)] & 0x80000000 and self._values[(0x1A00 + n, 0)] > 0

    def _read_mapped(self, index: int, sub: int) -> int:
        if index == 0x1001:
            return self._error_register()
        if index < 0x2000:
            v = self._values.get((index, sub), 0)
            return v if isinstance(v, int) else 0
        return int(self.drive.read_object(index, sub))

    def _tpdo_data(self, n: int) -> bytes | None:
        acc, bits = 0, 0
        for index, sub, length in self._mapping(0x1A00 + n):
            try:
                value = self._read_mapped(index, sub)
            except errors.ModelError:
                self.stats["pdo_errors"] += 1
                return None
            except Exception as exc:
                self.stats["pdo_errors"] += 1
                self.last_resort("TPDO", exc)
                return None
            acc |= (value & ((1 << length) - 1)) << bits
            bits += length
        return acc.to_bytes((bits + 7) // 8, "little")

    def _send_tpdo(
        self, n: int, now: int, *, force: bool = False, data: bytes | None = None
    ) -> None:
        if data is None:
            data = self._tpdo_data(n)
        if data is None:
            return
        run = self._pdo[4 + n]
        self._send(self._values[(0x1800 + n, 1)] & 0x7FF, data)
        run.last_data = data
        run.last_sent = now

    def _event_tpdo(self, n: int, now: int) -> None:
        run = self._pdo[4 + n]
        inhibit = self._values[(0x1800 + n, 3)] * 100 * US
        timer = self._values[(0x1800 + n, 5)] * MS
        if run.last_sent is not None and now - run.last_sent < inhibit:
            return
        data = self._tpdo_data(n)
        if data is None:
            return
        due = timer and run.last_sent is not None and now - run.last_sent >= timer
        if data != run.last_data or due:
            self._send_tpdo(n, now, data=data)

    def _on_sync(self, now: int) -> None:
        for n in range(4):  # TPDOs sample at SYNC (L17055-L17057)
            if not self._tpdo_active(n):
                continue
            tt = self._values[(0x1800 + n, 2)]
            run = self._pdo[4 + n]
            if tt == 0:
                data = self._tpdo_data(n)
                if data is not None and data != run.last_data:
                    self._send_tpdo(n, now, data=data)
            elif 1 <= tt <= 240:
                run.sync_count += 1
                if run.sync_count >= tt:
                    run.sync_count = 0
                    self._send_tpdo(n, now)
        for n in range(4):  # RPDOs of the previous cycle apply at this SYNC (L17051-L17053)
            run = self._pdo[n]
            if run.pending is not None:
                data, run.pending = run.pending, None
                self._apply_rpdo(n, data)

    def _on_rpdo(self, n: int, data: bytes) -> None:
        if self._values[(0x1600 + n, 0)] == 0:
            return
        if self._values[(0x1400 + n, 2)] <= 240:
            self._pdo[n].pending = data
        else:
            self._apply_rpdo(n, data)

    def _apply_rpdo(self, n: int, data: bytes) -> None:
        mapping = self._mapping(0x1600 + n)
        if sum(m[2] for m in mapping) > 8 * len(data):
            self.stats["pdo_errors"] += 1  # too short: not processed (CiA 301 EMCY 8210h)
            return
        acc, bits = int.from_bytes(data, "little"), 0
        for index, sub, length in mapping:
            raw = (acc >> bits) & ((1 << length) - 1)
            bits += length
            e = self.od.entries.get((index, sub))
            if e is not None and e.type in P_SIGNED and raw >= 1 << (length - 1):
                raw -= 1 << length
            try:
                self.drive.write_object(index, sub, raw)
            except errors.ModelError:  # refused: an RPDO has no answer (CiA 301)
                self.stats["pdo_errors"] += 1
            except Exception as exc:
                self.stats["pdo_errors"] += 1
                self.last_resort("RPDO", exc)

    # ------------------------------------------------------------------ EMCY
    def _error_register(self) -> int:
        try:
            return int(self.drive.alarms.error_register) & 0xFF
        except AttributeError:
            return 0

    def _on_event(self, ev: Any) -> None:
        """Drive events (delivered under the host lock)."""
        try:
            if isinstance(ev, AlarmChanged):
                self._emcy(ev)
            elif isinstance(ev, PowerCycled):
                self._reset("power cycle")
        except Exception as exc:
            self.last_resort(f"drive event {type(ev).__name__}", exc)

    def _emcy(self, ev: AlarmChanged) -> None:
        """EMCY (L17061-L17069): code, 1001h, Delta alarm code in bytes 3-4 (little-endian)."""
        cob = self._values.get((0x1014, 0), 0x80 + self.node_id)
        if cob & 0x80000000 or self.state not in ("PRE-OPERATIONAL", "OPERATIONAL"):
            return
        code = ev.emcy_code if ev.active else 0
        alarm = 0
        if ev.active and ev.code.upper().startswith("AL"):
            try:
                alarm = int(ev.code[2:], 16)
            except ValueError:
                alarm = 0
        data = bytes([code & 0xFF, code >> 8 & 0xFF, self._error_register()])
        data += alarm.to_bytes(2, "little") + bytes(3)
        self._send(cob & 0x7FF, data)

    def _history(self) -> list[int]:
        try:
            hist = [int(h) for h in self.drive.alarms.error_history][:5]
        except AttributeError:
            return []
        if self._history_cleared is not None:
            if tuple(hist) == self._history_cleared:
                return []
            if self._history_cleared and self._history_cleared[0] in hist:
                return hist[: hist.index(self._history_cleared[0])]
            self._history_cleared = None
        return hist

    # ------------------------------------------------------------------ SDO
    def _sdo_send(self, data: bytes) -> None:
        # stamped before the answer leaves: a master that sends its next request once it has
        # the answer is never "before the answer" (AL111), however late this thread runs on
        self._sdo_answered = clock.time_ns()
        self._sdo_replied = True
        self._send(self._values.get((0x1200, 2), cop.SDO_RESPONSE + self.node_id) & 0x7FF, data)

    def _sdo_abort(self, index: int, sub: int, code: int) -> None:
        self.stats["sdo_aborts"] += 1
        self._sdo_send(cop.sdo_abort(index, sub, code))

    def _abort_code(self, exc: Exception, download: bool) -> int:
        """The CiA 301 abort for an exception raised while serving an SDO request."""
        if isinstance(exc, ObjectError):
            return exc.abort_code
        if isinstance(exc, errors.ModelError):  # a refusal that names no abort code itself
            return errors.ABORT_VALUE_RANGE if download else errors.ABORT_GENERAL
        self.last_resort("SDO", exc)  # a bug: still answered, with the general abort
        return errors.ABORT_GENERAL

    def _on_sdo(self, data: bytes, now: int) -> None:
        """Serve one SDO request: every request but an abort gets an answer."""
        try:
            self._serve_sdo(data, now)
        except Exception as exc:  # last resort: no SDO goes unanswered
            self._transfer = None
            padded = data.ljust(4, b"\0")
            self._sdo_abort(padded[1] | padded[2] << 8, padded[3], self._abort_code(exc, True))

    def _serve_sdo(self, data: bytes, now: int) -> None:
        if len(data) != 8:  # CiA 301: SDO frames are 8 bytes
            padded = data.ljust(4, b"\0")
            self._transfer = None
            self._sdo_abort(padded[1] | padded[2] << 8, padded[3], errors.ABORT_COMMAND)
            return
        cs = data[0] >> 5
        index, sub = data[1] | data[2] << 8, data[3]
        if cs == cop.CCS_ABORT:
            self._transfer = None
            return
        if cs in (cop.CCS_DOWNLOAD_SEGMENT, cop.CCS_UPLOAD_SEGMENT):
            self._on_segment(cs, data, now)
            return
        self._transfer = None
        try:
            if cs == cop.CCS_INITIATE_UPLOAD:
                self._initiate_upload(index, sub, now)
            elif cs == cop.CCS_INITIATE_DOWNLOAD:
                self._initiate_download(index, sub, data, now)
            else:  # block transfers (5, 6) and 7: the A3 does expedited only (L16942)
                raise ObjectError(
                    index, sub, errors.ABORT_COMMAND, "command specifier not supported"
                )
        except Exception as exc:  # every refusal becomes an abort (CiA 301 §7.2.4.3.17)
            self._transfer = None
            code = self._abort_code(exc, cs == cop.CCS_INITIATE_DOWNLOAD)
            self._sdo_abort(index, sub, code)

    def _initiate_upload(self, index: int, sub: int, now: int) -> None:
        e = self.od.get(index, sub)
        if not e.readable:
            raise ObjectError(index, sub, errors.ABORT_WRITE_ONLY, "write-only object")
        raw = self._read_bytes(e)
        if len(raw) <= 4 and raw:
            self._sdo_send(cop.sdo_expedited_upload_response(index, sub, raw))
            return
        self._transfer = _Transfer(upload=True, entry=e, data=bytearray(raw), started=now)
        size = len(raw).to_bytes(4, "little")
        self._sdo_send(bytes([0x41, index & 0xFF, index >> 8, sub]) + size)

    def _initiate_download(self, index: int, sub: int, data: bytes, now: int) -> None:
        e = self.od.get(index, sub)
        if not e.writable:
            raise ObjectError(index, sub, errors.ABORT_READ_ONLY, "read-only object")
        expedited, sized = bool(data[0] & 2), bool(data[0] & 1)
        if expedited:
            n = 4 - ((data[0] >> 2) & 3) if sized else (e.size or 4)
            self._write_bytes(e, data[4 : 4 + n])
            self._sdo_send(cop.sdo_download_response(index, sub))
            return
        size = int.from_bytes(data[4:8], "little") if sized else None
        if size is not None and e.size is not None and size != e.size:
            code = errors.ABORT_LENGTH_HIGH if size > e.size else errors.ABORT_LENGTH_LOW
            raise ObjectError(index, sub, code, f"{size} bytes for a {e.size}-byte object")
        self._transfer = _Transfer(upload=False, entry=e, size=size, started=now)
        self._sdo_send(cop.sdo_download_response(index, sub))

    def _on_segment(self, cs: int, data: bytes, now: int) -> None:
        t = self._transfer
        toggle = (data[0] >> 4) & 1
        if t is None or t.upload != (cs == cop.CCS_UPLOAD_SEGMENT):
            self._transfer = None
            self._sdo_abort(0, 0, errors.ABORT_COMMAND)
            return
        e = t.entry
        if toggle != t.toggle:
            self._transfer = None
            self._sdo_abort(e.index, e.sub, errors.ABORT_TOGGLE)
            return
        t.started = now
        t.toggle ^= 1
        if t.upload:
            chunk, t.data = bytes(t.data[:7]), t.data[7:]
            last = not t.data
            n = 7 - len(chunk)
            self._sdo_send(bytes([toggle << 4 | n << 1 | int(last)]) + chunk + bytes(n))
            if last:
                self._transfer = None
            return
        n = (data[0] >> 1) & 7
        t.data += data[1 : 8 - n]
        if not data[0] & 1:
            self._sdo_send(bytes([0x20 | toggle << 4]) + bytes(7))
            return
        self._transfer = None
        try:
            if t.size is not None and len(t.data) != t.size:
                raise ObjectError(
                    e.index, e.sub, errors.ABORT_LENGTH, "size indicated != size sent"
                )
            self._write_bytes(e, bytes(t.data))
        except Exception as exc:
            self._sdo_abort(e.index, e.sub, self._abort_code(exc, True))
            return
        self._sdo_send(bytes([0x20 | toggle << 4]) + bytes(7))

    # ------------------------------------------------------------------ object access
    def read(self, index: int, sub: int) -> int | bytes:
        """Value of an object as an SDO upload sees it (call with `lock` held)."""
        e = self.od.get(index, sub)
        raw = self._read_bytes(e)
        return raw if e.size is None else e.decode(raw)

    def _read_bytes(self, e: Entry) -> bytes:
        index, sub = e.index, e.sub
        if 0x2000 <= index <= 0x2FFF or 0x6000 <= index <= 0x6FFF:
            return e.encode(int(self.drive.read_object(index, sub)))
        if index == 0x1001:
            return e.encode(self._error_register())
        if index == 0x1003:
            hist = self._history()
            if sub == 0:
                return e.encode(len(hist))
            return e.encode(hist[sub - 1] if sub <= len(hist) else 0)
        value = self._values.get((index, sub), 0)
        if e.size is None:
            return bytes(value) if not isinstance(value, int) else b""
        return e.encode(value or 0)

    def _write_bytes(self, e: Entry, raw: bytes) -> None:
        index, sub = e.index, e.sub
        if e.size is None:
            self._values[(index, sub)] = bytes(raw)
            return
        if len(raw) != e.size:
            code = errors.ABORT_LENGTH_HIGH if len(raw) > e.size else errors.ABORT_LENGTH_LOW
            raise ObjectError(index, sub, code, f"{len(raw)} bytes for a {e.size}-byte object")
        value = e.decode(raw)
        if value < 0 and e.min is not None and e.min >= 0:
            value += 1 << (8 * e.size)  # hex parameters are carried unsigned
        if e.max is not None and value > e.max:
            raise ObjectError(index, sub, errors.ABORT_VALUE_HIGH, f"{value} > max {e.max}")
        if e.min is not None and value < e.min:
            raise ObjectError(index, sub, errors.ABORT_VALUE_LOW, f"{value} < min {e.min}")
        if 0x2000 <= index <= 0x2FFF or 0x6000 <= index <= 0x6FFF:
            self.drive.write_object(index, sub, value)
            return
        self._write_comm(e, value)

    def _write_comm(self, e: Entry, value: int) -> None:
        index, sub = e.index, e.sub
        if index == 0x1003:
            if value != 0:
                raise ObjectError(index, sub, errors.ABORT_VALUE_RANGE, "only 0 clears 1003h")
            clear = getattr(getattr(self.drive, "alarms", None), "clear_error_history", None)
            if callable(clear):
                clear()
            else:
                self._history_cleared = tuple(self._history())
            return
        if 0x1400 <= index <= 0x1403 or 0x1800 <= index <= 0x1803:
            self._write_pdo_comm(index, sub, value)
        elif 0x1600 <= index <= 0x1603 or 0x1A00 <= index <= 0x1A03:
            self._write_pdo_map(index, sub, value)
        self._values[(index, sub)] = value
        self._full_path_cobs = None
        now = self.clock()
        if index == 0x1017:
            self._restart_heartbeat(now)
        elif index == 0x1016:
            self._hb_consumer_deadline = None
        elif index in (0x100C, 0x100D):
            self._life_deadline = None
        elif index == 0x1006:
            self._sync_reset()

    def _write_pdo_comm(self, index: int, sub: int, value: int) -> None:
        rx = index < 0x1800
        old = self._values[(index, 1)]
        valid = not old & 0x80000000
        if sub == 1:
            if value & 0x20000000 or value & 0x1FFFF800:
                raise ObjectError(
                    index, sub, errors.ABORT_VALUE_RANGE, "29-bit COB-IDs unsupported"
                )
            if valid and not value & 0x80000000 and (value & 0x7FF) != (old & 0x7FF):
                raise ObjectError(
                    index, sub, errors.ABORT_VALUE_RANGE, "COB-ID change while the PDO is valid"
                )
            n = index & 3
            self._pdo[n if rx else 4 + n] = _PdoRun()
        elif sub == 2:
            if 241 <= value <= 251 or (rx and value in (252, 253)):
                raise ObjectError(
                    index, sub, errors.ABORT_VALUE_RANGE, f"transmission type {value}"
                )
        elif sub == 3 and valid and not rx:
            raise ObjectError(index, sub, errors.ABORT_DATA_STATE, "inhibit time while PDO valid")

    def _write_pdo_map(self, index: int, sub: int, value: int) -> None:
        rx = index < 0x1A00
        comm = (0x1400 if rx else 0x1800) + (index & 3)
        if not self._values[(comm, 1)] & 0x80000000:
            raise ObjectError(index, sub, errors.ABORT_DATA_STATE, "mapping change while PDO valid")
        if sub == 0:
            total = 0
            for s in range(1, value + 1):
                total += self._check_map_entry(index, s, self._values[(index, s)], rx)
            if total > 64:
                raise ObjectError(
                    index, sub, errors.ABORT_PDO_LENGTH, f"{total} bits > 64 (L18024)"
                )
            return
        if self._values[(index, 0)] != 0:
            raise ObjectError(index, sub, errors.ABORT_DATA_STATE, "mapping change while sub0 != 0")
        if value:
            self._check_map_entry(index, sub, value, rx)

    def _check_map_entry(self, index: int, sub: int, value: int, rx: bool) -> int:
        t_index, t_sub, bits = value >> 16, (value >> 8) & 0xFF, value & 0xFF
        try:
            target = self.od.get(t_index, t_sub)
        except ObjectError as exc:
            raise ObjectError(index, sub, errors.ABORT_NO_OBJECT, f"maps {exc}") from None
        ok = target.pdo and target.bits == bits and (target.writable if rx else target.readable)
        if not ok:
            raise ObjectError(
                index, sub, errors.ABORT_NOT_MAPPABLE,
                f"{t_index:04X}h sub {t_sub} cannot be mapped"
            )
        return bits


P_SIGNED = {"INTEGER8", "INTEGER16", "INTEGER32"}
_DEFAULTS = ModelOptions()
