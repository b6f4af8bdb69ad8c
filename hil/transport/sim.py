"""In-process buses and lines on a `VirtualClock` (docs/clock.md): the wire's time, no threads.

- `SimCanBus`: a python-can bus on one `CanMedium` per channel. A frame occupies the bus for its
  bit time at the bench's bitrate (the frame's own stuff bits counted, `frame_bits`); frames
  waiting for the bus go by arbitration, the lowest identifier first; every other node gets
  the frame when its last bit has passed (with `receive_own_messages`, the sender too).
- RS-485 on the clock is `hil.transport.serial_line.SimLine`, a `SerialLine` backend.

Receivers are fed inside the clock's events: `pump(bus, fn)` calls `fn(msg)` for each frame
delivered to `bus` (through any wrappers above it, so taps and fault layers see it), instead
of a python-can `Notifier` thread. A sender outside the events (the plan) settles the bus:
its `send` returns once the medium has no frame in flight, so the answers it caused are
delivered (an SDO server answers at once).
"""

from __future__ import annotations

import contextlib
import re
import threading
from collections import deque
from collections.abc import Callable
from typing import Any

import can
from can import BusABC, Message

from hil.clock import VirtualClock
from hil.transport.cyclic import ClockPeriodic
from hil.units import S

# a virtual bus's rate unless its URL says `?bitrate=`: CiA 301's highest. The A3 ships at
# 500 kbit/s (P3.001 = 0x0203, Z = 2: L10512, L16834); the model does not tie the two
DEFAULT_BITRATE = 1_000_000


def _crc15_table() -> tuple[int, ...]:
    table = []
    for byte in range(256):
        crc = byte << 7
        for _ in range(8):
            crc = ((crc << 1) ^ 0x4599) if crc & 0x4000 else crc << 1
            crc &= 0x7FFF
        table.append(crc)
    return tuple(table)


_CRC15 = _crc15_table()


def _crc15(value: int, nbits: int) -> int:
    """CAN's CRC-15 (polynomial 4599h) over the `nbits` low bits of `value`, MSB first: the
    bits that do not fill a byte one at a time, then a byte at a time by table."""
    crc = 0
    head = nbits % 8
    for k in range(nbits - 1, nbits - 1 - head, -1):
        nxt = ((value >> k) & 1) ^ ((crc >> 14) & 1)
        crc = (crc << 1) & 0x7FFF
        if nxt:
            crc ^= 0x4599
    for shift in range(nbits - head - 8, -1, -8):
        crc = ((crc << 8) & 0x7FFF) ^ _CRC15[((crc >> 7) ^ (value >> shift)) & 0xFF]
    return crc


_RUNS = re.compile(r"0{4,}|1{4,}")


def _stuff_bits(bits: str) -> int:
    """Stuff bits ISO 11898-1 inserts into `bits`: one after every 5 equal bits, stuff bits
    counted in the runs. Counted run by run: a stuff bit that ends a run has the next run's
    value, so it carries one into that run; only runs of 4 or more can reach 5."""
    stuffed = carry = 0
    prev_end = -1
    for m in _RUNS.finditer(bits):
        start, end = m.span()
        n = (carry if start == prev_end else 0) + end - start
        k = n // 5
        stuffed += k
        carry = 1 if k and n % 5 == 0 else 0
        prev_end = end
    return stuffed


_BITS_CACHE: dict[tuple, int] = {}


def frame_bits(msg: Message) -> int:
    """Bits a classic CAN frame occupies on the wire, stuff bits and the 3-bit intermission
    included (ISO 11898-1: stuffing from SOF to the end of the CRC sequence)."""
    if msg.is_error_frame:  # error flag (6) + error delimiter (8) + intermission (3)
        return 17
    key = (msg.arbitration_id, msg.is_extended_id, msg.is_remote_frame, msg.dlc,
           bytes(msg.data))
    bits = _BITS_CACHE.get(key)
    if bits is None:  # a bus repeats its frames (polls, SYNC, PDOs): count each once
        if len(_BITS_CACHE) > 65536:
            _BITS_CACHE.clear()
        bits = _BITS_CACHE[key] = _frame_bits(msg)
    return bits


def _frame_bits(msg: Message) -> int:
    dlc = min(len(msg.data), 8) if not msg.is_remote_frame else min(msg.dlc, 8)
    data = b"" if msg.is_remote_frame else bytes(msg.data[:8])
    rtr = 1 if msg.is_remote_frame else 0
    if msg.is_extended_id:  # SOF, base id, SRR, IDE, extension, RTR, r1, r0
        ident = msg.arbitration_id & 0x1FFFFFFF
        value, nbits = ((((ident >> 18) << 2 | 3) << 18 | ident & 0x3FFFF) << 1 | rtr) << 2, 35
    else:  # SOF, id, RTR, IDE, r0
        value, nbits = ((msg.arbitration_id & 0x7FF) << 1 | rtr) << 2, 15
    value = (value << 4 | dlc) << 8 * len(data) | int.from_bytes(data, "big")
    nbits += 4 + 8 * len(data)
    value = value << 15 | _crc15(value, nbits)
    nbits += 15
    bits = format(value, f"0{nbits}b")
    # CRC delimiter, ACK slot + delimiter, EOF (7), intermission (3)
    return nbits + _stuff_bits(bits) + 1 + 2 + 7 + 3


def _arbitration_key(msg: Message) -> int:
    """The arbitration field in wire order (a lower value wins): the 11-bit base id, then
    RTR (standard) or SRR = 1 (extended), IDE, the 18-bit extension and RTR (extended). A
    standard data frame beats an extended frame of the same base id, a data frame its RTR."""
    rtr = 1 if msg.is_remote_frame else 0
    if msg.is_extended_id:
        ident = msg.arbitration_id & 0x1FFFFFFF
        return ((ident >> 18) << 21) | (1 << 20) | (1 << 19) | ((ident & 0x3FFFF) << 1) | rtr
    return ((msg.arbitration_id & 0x7FF) << 21) | (rtr << 20)


class SimMessage(Message):
    """A delivered frame; `sender_time_ns`: when its sender queued it (clock ns)."""

    __slots__ = ("sender_time_ns",)

    def __init__(self, *args: Any, sender_time_ns: int | None = None, **kw: Any) -> None:
        super().__init__(*args, **kw)
        self.sender_time_ns = sender_time_ns

    @classmethod
    def frame(cls, timestamp: float, msg: Message, data: bytes, channel: Any,
              sender_time_ns: int | None) -> SimMessage:
        """A classic-CAN copy of `msg` with these fields: what `Message.__init__` makes of
        them (`data` a new bytearray, empty for a remote frame), without its argument
        handling, once per frame and receiver on a virtual bus."""
        m = cls.__new__(cls)
        m.timestamp = timestamp
        m.arbitration_id = msg.arbitration_id
        m.is_extended_id = msg.is_extended_id
        m.is_remote_frame = rtr = msg.is_remote_frame
        m.is_error_frame = msg.is_error_frame
        m.channel = channel
        m.is_fd = m.bitrate_switch = m.error_state_indicator = False
        m.is_rx = True
        m.data = bytearray() if rtr else bytearray(data)
        m.dlc = msg.dlc
        m.sender_time_ns = sender_time_ns
        return m


class CanMedium:
    """One CAN bus on the clock: arbitration, bit time, delivery."""

    def __init__(self, clock: VirtualClock, channel: str, bitrate: int) -> None:
        if isinstance(bitrate, bool) or not isinstance(bitrate, int) or not (
                10_000 <= bitrate <= 1_000_000):
            raise ValueError(f"CAN bitrate {bitrate!r}: a classic CAN rate in bit/s, "
                             "10000-1000000 (CiA 301 lists 10k-1M)")
        self.clock, self.channel, self.bitrate = clock, channel, bitrate
        self.nodes: list[SimCanBus] = []
        self._pending: list[tuple[int, int, SimCanBus, Message]] = []  # (prio, seq, from, msg)
        self._seq = 0
        self.busy_until = 0
        self.in_flight = 0
        self._starting = False  # a start of the next frame is scheduled (`_start_soon`)

    def bit_ns(self, bits: int) -> int:
        """`bits` on the wire, in ns rounded up (never early): exact at CiA 301's rates."""
        return -(-bits * S // self.bitrate)

    def transmit(self, sender: SimCanBus, msg: Message) -> None:
        prio = _arbitration_key(msg)
        self._seq += 1
        self._pending.append((prio, self._seq, sender, msg))
        self.in_flight += 1
        if self.busy_until <= self.clock.time_ns():
            self._start_soon()

    def _start_soon(self) -> None:
        """Start the next frame at this instant, once every node with a frame at it has
        queued it: a late clock event (ISO 11898-1: every node with a frame pending at the
        start of frame takes part in arbitration, whichever queued it first)."""
        if not self._starting:
            self._starting = True
            self.clock.at(self.clock.time_ns(), self._start_next, late=True)

    def _start_next(self) -> None:
        """The next frame on the wire: each node's transmit queue is first in, first out (as
        a PC's SocketCAN queue, or a controller with one transmit buffer), and the heads of
        the nodes' queues go by arbitration, the lowest identifier first."""
        self._starting = False
        pending = self._pending
        if not pending:
            return
        if len(pending) == 1:  # one frame waiting (a poll and its answer): no arbitration
            best = pending.pop()
        else:
            heads: dict[int, tuple[int, int, SimCanBus, Message]] = {}
            for p in pending:  # in queueing order: the first of each sender is its head
                heads.setdefault(id(p[2]), p)
            best = min(heads.values(), key=lambda p: (p[0], p[1]))
            pending.remove(best)
        _, _, sender, msg = best
        dur = self.bit_ns(frame_bits(msg))
        start = max(self.clock.time_ns(), self.busy_until)
        self.busy_until = start + dur
        self.clock.at(self.busy_until, lambda: self._done(sender, msg))

    def _done(self, sender: SimCanBus, msg: Message) -> None:
        self.in_flight -= 1
        t = self.clock.time_ns()
        data, sent = bytes(msg.data), getattr(msg, "sender_time_ns", None)
        try:
            for node in list(self.nodes):
                if node is not sender or node.receive_own_messages:
                    try:  # a copy each: canopen keeps a PDO's buffer and writes into it
                        node._deliver(SimMessage.frame(t / S, msg, data, self.channel, sent))
                    except Exception as exc:  # one receiver's bug: the others get the frame
                        node.errors.append(exc)
        finally:  # the next waiting frame goes on the wire whatever happened; one queued
            if self._pending:  # later at this instant starts it itself (`transmit`)
                self._start_soon()

    def idle(self) -> bool:
        return self.in_flight == 0


class SimCanBus(ClockPeriodic, BusABC):
    """A python-can bus on a `CanMedium` (`virtual:<channel>` under a virtual clock)."""

    def __init__(self, channel: str, *, clock: VirtualClock, bitrate: int | None = None,
                 receive_own_messages: bool = False, **_ignored: Any) -> None:
        key = f"can:{channel}"
        medium = clock.media.get(key)
        if medium is None:
            medium = clock.media[key] = CanMedium(
                clock, channel, DEFAULT_BITRATE if bitrate is None else bitrate)
        self.medium: CanMedium = medium
        self.channel = channel
        self.clock = clock
        self.receive_own_messages = receive_own_messages
        self.channel_info = f"virtual-time CAN {channel} at {medium.bitrate} bit/s"
        self._rx: deque[Message] = deque()
        self.on_rx: Callable[[], None] | None = None
        self.errors: list[BaseException] = []  # raised by what this node's delivery fed
        # another thread reading this bus (a test's python-can Notifier) waits in wall time
        # for what the run's thread delivers: woken by this event while `_foreign` > 0
        self._foreign = 0
        self._arrived = threading.Event()
        medium.nodes.append(self)
        super().__init__(channel=channel)

    def check_frame(self, msg: Message) -> None:
        """Raise `can.CanOperationError` where `send` would refuse `msg`: a closed bus, a
        CAN FD frame or more than 8 data bytes (as SocketCAN on a classic interface)."""
        self._check_open()
        if msg.is_fd or len(msg.data) > 8:
            raise can.CanOperationError(
                f"{self.channel_info}: a classic CAN bus carries at most 8 data bytes and no "
                f"CAN FD frame (got {'an FD frame' if msg.is_fd else 'one'} with "
                f"{len(msg.data)} bytes)")

    def send(self, msg: Message, timeout: float | None = None) -> None:
        self.check_frame(msg)
        clk = self.clock
        out = SimMessage.frame(0.0, msg, bytes(msg.data), self.channel_info, clk.time_ns())
        if not clk.may_wait():  # another thread: the run's thread queues it, at its next wait
            clk.at(clk.time_ns(), lambda: self.medium.transmit(self, out))
            return
        self.medium.transmit(self, out)
        clk.settle(lambda: not self.medium.idle())

    def _deliver(self, msg: Message) -> None:
        """Queue a received frame (this node's own copy)."""
        if self._is_shutdown:
            return
        self._rx.append(msg)
        if self.on_rx is not None:
            self.on_rx()
        if self._foreign:
            self._arrived.set()

    def recv(self, timeout: float | None = None) -> Message | None:
        """python-can's `recv` on this bus's clock, with a short way for a waiting frame and
        no filters set (the pump's `recv(0)` for every frame on every node)."""
        if self._rx and self._filters is None:
            with contextlib.suppress(IndexError):  # another thread may have taken it
                return self._rx.popleft()
        return recv_on_clock(self, self.clock, timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        if not self._rx and (timeout is None or timeout > 0) and not self.clock.in_event:
            if self.clock.may_wait():
                self.clock.wait_for(lambda: bool(self._rx) or self._is_shutdown, timeout)
            else:  # another thread: wall time, for what the run's own thread delivers
                self._foreign += 1
                try:
                    self._arrived.clear()
                    if not self._rx:
                        self._arrived.wait(timeout)
                finally:
                    self._foreign -= 1
        try:
            return self._rx.popleft(), False
        except IndexError:  # nothing came (or another thread took it)
            return None, False

    def _check_open(self) -> None:
        if self._is_shutdown:
            raise can.CanOperationError(f"{self.channel_info}: bus is shut down")

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        if self in self.medium.nodes:
            self.medium.nodes.remove(self)


def recv_on_clock(bus: BusABC, clk: VirtualClock, timeout: float | None) -> Message | None:
    """`BusABC.recv` with its deadline on the virtual clock: python-can's own loop counts wall
    seconds, so a filtered `recv(0.5)` that saw no match ran hours of bench time. Frames
    already received are all read, matching or not, before it gives up (as at `timeout` 0);
    `timeout=None` waits as long as `clock.wait_for` (an hour of bench time), then None."""
    if not clk.may_wait():  # another thread (a Notifier): python-can's own wall-time loop
        return BusABC.recv(bus, timeout)
    limit = 3600 * S if timeout is None else max(0, round(timeout * S))
    end = clk.time_ns() + limit
    while True:
        left = max(0, end - clk.time_ns()) / S
        msg, already_filtered = bus._recv_internal(timeout=left)
        if msg is not None:
            if already_filtered or bus._matches_filters(msg):
                return msg
            continue  # dropped by the filters (python-can's rule); read on
        if clk.time_ns() >= end or clk.in_event or bus._is_shutdown:
            return None


def raw_bus(bus: Any) -> Any:
    """The bus under any wrappers (`.bus` attributes: taps, fault layers)."""
    seen = 0
    while not isinstance(bus, SimCanBus) and getattr(bus, "bus", None) is not None and seen < 8:
        bus, seen = bus.bus, seen + 1
    return bus


def pump(bus: BusABC, fn: Callable[[Message], None]) -> Callable[[], None]:
    """Feed each frame delivered to `bus` (read through `bus`, wrappers and all) to
    `fn(msg)` inside the delivering clock event. Returns a function that stops it."""
    raw = raw_bus(bus)
    if not isinstance(raw, SimCanBus):
        raise TypeError(f"pump: {bus!r} is not on a virtual-time CAN bus")

    def drain() -> None:
        while True:
            msg = bus.recv(0)
            if msg is None:
                return
            fn(msg)

    raw.on_rx = drain

    def stop() -> None:
        raw.on_rx = None

    return stop


class ListenerPump:
    """python-can listeners (canopen's `MessageListener`) fed by `pump` (or another feed such
    as `hil.transport.inline.inline_pump` on the wall clock): a Notifier's stand-in."""

    def __init__(self, bus: BusABC, listeners: list[Any],
                 feed: Callable[[BusABC, Callable[[Message], None]],
                                Callable[[], None]] = pump) -> None:
        self.listeners = listeners
        self.exception: BaseException | None = None  # canopen's send_message checks it
        self._stop = feed(bus, self._dispatch)

    def _dispatch(self, msg: Message) -> None:
        for listener in list(self.listeners):
            try:
                listener.on_message_received(msg)
            except Exception as exc:  # as python-can's Notifier: canopen raises it later
                self.exception = exc

    def add_listener(self, listener: Any) -> None:
        """python-can `Notifier.add_listener`: hear every frame this bus receives (a test's
        `can.BufferedReader` on a session's network, `hil_session.nets[bus].notifier`)."""
        self.listeners.append(listener)

    def remove_listener(self, listener: Any) -> None:
        self.listeners.remove(listener)

    def stop(self, timeout: float = 0) -> None:
        self._stop()

