"""In-process delivery on the wall clock: a `virtual:` CAN frame handed to its receivers in the
sender's thread (docs/clock.md, "The real-time path").

python-can's `virtual` interface puts a copy of each frame in every other bus's queue, and a
receiver's thread (a `can.Notifier`, a drive face's loop) wakes to take it. On a host that is
not real-time each hand-off costs a thread wake-up: 0.2 ms at the median and up to 5 ms under
the GIL (docs/performance.md, session 10), so a SYNC and the TPDO it asks for crossed two of
them and one axis at a 2 ms SYNC missed cycles.

`inline_pump(bus, fn)` swaps the queue of the python-can `VirtualBus` under `bus` for an
`InlineQueue`: a frame put in it is read through `bus` (taps and fault layers see it, as with a
thread) and handed to `fn` at once, by the thread that sent it. Receivers that still read
with their own thread (a sniffer, a gateway export) keep python-can's queue and see the same
frames. One `Courier` per channel hands frames over one at a time in the order they were
sent: a frame sent while another thread is handing frames over is handed over by that
thread, so receivers never run at the same time, never re-enter, and a receiver's answer
never overtakes the frames sent before it. A receiver must not wait for a frame on its own
channel inside `fn` (nothing here does: the CiA 402 driver waits for an SDO answer outside).
"""

from __future__ import annotations

import logging
import queue
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable
from typing import Any

import can
from can.interfaces.virtual import VirtualBus, channels, channels_lock

log = logging.getLogger(__name__)


class Courier:
    """Hands the frames of one channel to its inline receivers, one at a time, in order."""

    def __init__(self) -> None:
        self._lock = threading.Lock()  # held by the thread handing frames over
        self._due: deque[InlineQueue] = deque()  # a receiver per frame put, in put order

    def kick(self) -> None:
        """Hand the frames put so far over now, or leave them to the thread doing so."""
        due = self._due
        # re-checked after the release: a frame put between the last pop and the release
        while due and self._lock.acquire(blocking=False):
            try:
                while due:
                    due.popleft().hand_one()
            finally:
                self._lock.release()


_local = threading.local()  # .sending: an `InlineBus.send` is putting a frame in the queues


class InlineBus(VirtualBus):
    """python-can's `virtual` bus (what `open_can` gives for `virtual:` on the wall clock)
    that hands its frame to the inline receivers only once it is in every receiver's queue:
    an answer never reaches a receiver before the frame that caused it. A frame a plain
    `VirtualBus` sends is handed over as it is put, so receivers later in python-can's list
    may see an answer first: the harness and the virtual drives send through this class."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """python-can's `VirtualBus.send` (a copy of `msg` in every other receiver's queue,
        stamped now), then the inline receivers' turn. A plain `can.Message` is copied field
        by field (`copy_frame`) instead of by `deepcopy`, 7 µs a receiver here."""
        if type(msg) is not can.Message:  # a subclass may carry more: python-can's own copy
            self._send_each(msg, timeout, super().send)
        else:
            self._send_each(msg, timeout, self._send_plain)
        courier = _couriers.get(self.channel_id)
        if courier is not None:
            courier.kick()

    @staticmethod
    def _send_each(msg: can.Message, timeout: float | None,
                   send: Callable[[can.Message, float | None], None]) -> None:
        outer = getattr(_local, "sending", False)
        _local.sending = True
        try:
            send(msg, timeout)
        finally:
            _local.sending = outer

    def _send_plain(self, msg: can.Message, timeout: float | None) -> None:
        self._check_if_open()
        stamp = msg.timestamp if self.preserve_timestamps else time.time()
        data, own, chan = bytes(msg.data), self.queue, self.channel_id
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            try:
                bus_queue.put(copy_frame(msg, data, stamp, chan, bus_queue is not own),
                              block=True, timeout=timeout)
            except queue.Full:
                all_sent = False
        if not all_sent:
            raise can.CanOperationError("Could not send message to one or more recipients")


def copy_frame(msg: can.Message, data: bytes, timestamp: float, channel: Any,
               is_rx: bool) -> can.Message:
    """What `VirtualBus.send` makes of `msg` for one receiver (`deepcopy`, then the timestamp,
    channel and direction), field by field."""
    m = can.Message.__new__(can.Message)
    m.timestamp = timestamp
    m.arbitration_id = msg.arbitration_id
    m.is_extended_id = msg.is_extended_id
    m.is_remote_frame = msg.is_remote_frame
    m.is_error_frame = msg.is_error_frame
    m.channel = channel
    m.dlc = msg.dlc
    m.data = bytearray(data)
    m.is_fd = msg.is_fd
    m.is_rx = is_rx
    m.bitrate_switch = msg.bitrate_switch
    m.error_state_indicator = msg.error_state_indicator
    return m


_couriers: weakref.WeakValueDictionary[Any, Courier] = weakref.WeakValueDictionary()


def courier_of(channel_id: Any) -> Courier | None:
    """The channel's courier while any receiver on it is inline (else None)."""
    return _couriers.get(channel_id)


class InlineQueue:
    """What python-can's `VirtualBus` puts frames in and gets them from (`put`, `get`), for a
    receiver fed in the sender's thread."""

    def __init__(self, courier: Courier, read: Callable[[], can.Message | None],
                 fn: Callable[[can.Message], None]) -> None:
        self.courier = courier  # kept alive by its queues
        self._items: deque[can.Message] = deque()
        self._read, self._fn = read, fn

    def put(self, item: can.Message, block: bool = True, timeout: float | None = None) -> None:
        self._items.append(item)
        self.courier._due.append(self)
        if not getattr(_local, "sending", False):  # else the sender kicks once it is done
            self.courier.kick()

    def get(self, block: bool = True, timeout: float | None = None) -> can.Message:
        try:
            return self._items.popleft()
        except IndexError:
            raise queue.Empty from None

    def qsize(self) -> int:
        return len(self._items)

    def empty(self) -> bool:
        return not self._items

    def hand_one(self) -> None:
        """Read one frame through the receiver's bus (its taps) and hand it to `fn`."""
        try:
            msg = self._read()
            if msg is not None:
                self._fn(msg)
        except Exception as exc:  # one receiver's bug: the others still get their frames
            log.error("inline CAN delivery: %s: %s", type(exc).__name__, exc, exc_info=exc)


def raw_virtual(bus: Any) -> VirtualBus | None:
    """The python-can `VirtualBus` under any wrappers (`.bus` attributes), if that is what
    `bus` is."""
    for _ in range(8):
        if isinstance(bus, VirtualBus):
            return bus
        bus = getattr(bus, "bus", None)
        if bus is None:
            return None
    return None


def inline_pump(bus: can.BusABC, fn: Callable[[can.Message], None]) -> Callable[[], None]:
    """Feed each frame received on `bus` (read through `bus`, wrappers and all) to `fn(msg)`
    in the thread that sent it. `bus` must be a python-can `virtual` bus, wrapped or not.
    Returns a function that stops it (frames then wait in python-can's queue again)."""
    raw = raw_virtual(bus)
    if raw is None:
        raise TypeError(f"inline_pump: {bus!r} is not a python-can virtual bus")
    with channels_lock:
        courier = _couriers.get(raw.channel_id)
        if courier is None:
            courier = _couriers[raw.channel_id] = Courier()
        old = raw.queue
        new = InlineQueue(courier, lambda: bus.recv(0), fn)
        _swap(raw, old, new)
    while True:  # frames that were waiting in python-can's queue go first
        try:
            new.put(old.get_nowait())
        except queue.Empty:
            break

    def stop() -> None:
        with channels_lock:
            if raw.queue is not new:
                return
            plain: queue.Queue[can.Message] = queue.Queue()
            for msg in list(new._items):
                plain.put(msg)
            _swap(raw, new, plain)

    return stop


def _swap(raw: VirtualBus, old: Any, new: Any) -> None:
    """Put `new` in place of `old` as `raw`'s queue and in its channel's list of receivers."""
    raw.queue = new
    members = channels.get(raw.channel_id)
    if members is not None:
        for i, q in enumerate(members):
            if q is old:
                members[i] = new
