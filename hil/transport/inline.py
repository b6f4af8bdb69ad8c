"""CAN frames handed to their receivers in the thread that delivers them, on the wall clock
(docs/clock.md, "The real-time path").

python-can's `virtual` interface puts a copy of each frame in every other bus's queue, and a
receiver's thread (a `can.Notifier`, a drive face's loop) wakes to take it. On a host that is
not real-time each hand-off costs a thread wake-up: 0.2 ms at the median and up to 5 ms
(docs/performance.md, session 10), so a SYNC and the TPDO it asks for crossed two of them and
one axis at a 2 ms SYNC missed cycles.

`inline_pump(bus, fn)` swaps the queue of the python-can `VirtualBus` under `bus` for an
`InlineQueue`: a frame put in it is read through `bus` (taps and fault layers see it, as with a
thread) and handed to `fn` by the thread that sent it. Receivers that still read with their
own thread (a sniffer, a gateway export) keep python-can's queue and see the same frames. One
`Courier` per channel hands frames over one at a time in the order they were put: a frame put
while another thread is handing frames over is handed over by that thread, so receivers never
run at the same time and are never re-entered. An `InlineBus` puts its frame in every queue
before any of it is handed over, and no other `InlineBus` puts a frame meanwhile, so an answer
never reaches a receiver before the frame that caused it. On a bus that calls back on each
frame it receives (`set_inline`: `hil.transport.zenoh_can.ZenohBus`) the frame is handed over
in the thread it arrived in.

Inside `fn` a receiver must not wait for a frame of its own channel, nor for a lock that a
sender on the channel holds while it sends (canopen's `Network.send_lock`): the frame it waits
for would be handed over by this very thread. Nothing here does: the CiA 402 driver and the
safe state wait for their SDO answers in the plan's thread, outside any handler.
"""

from __future__ import annotations

import contextlib
import logging
import queue
import threading
import time
import weakref
from collections import deque
from collections.abc import Callable, Iterator
from typing import Any

import can
from can.interfaces.virtual import VirtualBus, channels, channels_lock

log = logging.getLogger(__name__)


class _Receiver:
    """One inline receiver: reads a frame through its bus (taps and all) and hands it on."""

    def __init__(self, read: Callable[[], can.Message | None],
                 fn: Callable[[can.Message], None]) -> None:
        self._read, self._fn = read, fn
        self.stopped = False

    def hand_one(self) -> None:
        """Read one frame through the receiver's bus (its taps) and hand it to `fn`."""
        if self.stopped:
            return
        try:
            msg = self._read()
            if msg is not None:
                self._fn(msg)
        except Exception as exc:  # one receiver's bug: the others still get their frames
            log.error("inline CAN delivery: %s: %s", type(exc).__name__, exc, exc_info=exc)


class Courier:
    """Hands the frames of one channel to its inline receivers, one at a time, in order.

    Robust to an exception that is not the receiver's (Ctrl-C in the main thread): the
    courier's turn is given up in `finally` only if this thread took it (`mine` is set in the
    same statement that takes it, with no call in between where a signal could be raised),
    and the receiver being handed a frame keeps its place in the line."""

    def __init__(self) -> None:
        self._mutex = threading.Lock()  # guards `_busy`; held only for a test and a store
        self._busy = False  # a thread is handing frames over
        self._due: deque[_Receiver] = deque()  # a receiver per frame put, in put order
        self.put_lock = threading.Lock()  # held by an InlineBus putting one frame everywhere
        self.held = 0  # > 0 inside `hold`: frames wait in the line until its end

    def add(self, receiver: _Receiver) -> None:
        """A frame was put for `receiver` (hand it over with `kick`)."""
        self._due.append(receiver)

    def kick(self) -> None:
        """Hand the frames put so far over now, or leave them to the thread doing so."""
        due, mutex = self._due, self._mutex
        while due and not self.held:  # re-checked after the turn: one put meanwhile
            mine = False
            current: _Receiver | None = None
            try:
                with mutex:
                    if self._busy or self.held:
                        return
                    self._busy = mine = True
                while due and not self.held:
                    current = due[0]  # noted before it leaves the line: see the except
                    due.popleft()
                    current.hand_one()
                    current = None
            except BaseException:
                if current is not None:  # interrupted mid-hand-over: its frame may still wait;
                    due.appendleft(current)  # an extra turn reads nothing, a lost one lags
                raise
            finally:
                if mine:
                    with mutex:
                        self._busy = False


_local = threading.local()  # .sending: an `InlineBus.send` is putting a frame in the queues


class InlineBus(VirtualBus):
    """python-can's `virtual` bus (what `open_can` gives for `virtual:` on the wall clock)
    that hands its frame to the inline receivers only once it is in every receiver's queue,
    and puts one frame at a time per channel: an answer never reaches a receiver before the
    frame that caused it. A frame a plain `VirtualBus` sends is handed over as it is put, so
    receivers later in python-can's list may see an answer first: the harness and the virtual
    drives send through this class."""

    def send(self, msg: can.Message, timeout: float | None = None) -> None:
        """python-can's `VirtualBus.send` (a copy of `msg` in every other receiver's queue,
        stamped now), then the inline receivers' turn. A plain `can.Message` is copied field
        by field (`copy_frame`) instead of by `deepcopy`, 7 µs a receiver here."""
        put = super().send if type(msg) is not can.Message else self._send_plain
        courier = _couriers.get(self.channel_id)
        if courier is None:
            put(msg, timeout)
            return
        outer = getattr(_local, "sending", False)
        try:
            with courier.put_lock:  # no other frame between this one's queues
                _local.sending = True
                put(msg, timeout)
        finally:
            _local.sending = outer
            courier.kick()  # what was put is handed over even if a queue refused it

    def _send_plain(self, msg: can.Message, timeout: float | None) -> None:
        self._check_if_open()
        stamp = msg.timestamp if self.preserve_timestamps else time.time()
        data, own, chan = bytes(msg.data), self.queue, self.channel_id
        all_sent = True
        for bus_queue in self.channel:
            if bus_queue is own and not self.receive_own_messages:
                continue
            copy = copy_frame(msg, data, stamp, chan, bus_queue is not own)
            try:  # `put` looked up now: a queue swapped meanwhile forwards (inline_pump)
                bus_queue.put(copy, block=True, timeout=timeout)
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


class InlineQueue(_Receiver):
    """What python-can's `VirtualBus` puts frames in and gets them from (`put`, `get`), for a
    receiver fed in the sender's thread. Once stopped, `put` goes to `forward` (python-can's
    queue again)."""

    def __init__(self, courier: Courier, read: Callable[[], can.Message | None],
                 fn: Callable[[can.Message], None]) -> None:
        super().__init__(read, fn)
        self.courier = courier  # kept alive by its queues
        self._items: deque[can.Message] = deque()
        self.forward: Any = None

    def put(self, item: can.Message, block: bool = True, timeout: float | None = None) -> None:
        fwd = self.forward
        if fwd is not None:  # stopped: a sender that still held this queue
            fwd.put(item, block, timeout)
            return
        self._items.append(item)
        self.courier.add(self)
        if not getattr(_local, "sending", False):  # else the sender kicks once it is done
            self.courier.kick()

    def get(self, block: bool = True, timeout: float | None = None) -> can.Message:
        try:
            return self._items.popleft()
        except IndexError:
            if block and timeout != 0:  # a `recv` loop on a pumped bus waits, never spins
                time.sleep(0.05 if timeout is None else min(timeout, 0.05))
            raise queue.Empty from None

    def qsize(self) -> int:
        return len(self._items)

    def empty(self) -> bool:
        return not self._items


@contextlib.contextmanager
def hold(bus: Any) -> Iterator[None]:
    """Frames put on `bus`'s in-process channel inside the block are handed over only at its
    end, back to back: a master's burst (an SDO flood, duplicate PDOs) that reaches the
    drive before the drive has answered any of it, as on a wire (AL111/AL112). Nothing to
    do on another bus (zenoh delivers in order on its own time)."""
    raw = raw_virtual(bus)
    courier = courier_of(raw.channel_id) if raw is not None else None
    if courier is None:
        yield
        return
    with courier._mutex:
        courier.held += 1
    try:
        yield
    finally:
        with courier._mutex:
            courier.held -= 1
        courier.kick()


def _under(bus: Any, test: Callable[[Any], bool]) -> Any:
    """The bus under any wrappers (`.bus` attributes) that passes `test`, or None."""
    for _ in range(8):
        if test(bus):
            return bus
        bus = getattr(bus, "bus", None)
        if bus is None:
            return None
    return None


def raw_virtual(bus: Any) -> VirtualBus | None:
    """The python-can `VirtualBus` under any wrappers, if that is what `bus` is."""
    return _under(bus, lambda b: isinstance(b, VirtualBus))


def _hooked(bus: Any) -> Any:
    """The bus under any wrappers that calls back on each received frame (`set_inline`, as
    `hil.transport.zenoh_can.ZenohBus`), or None."""
    return _under(bus, lambda b: callable(getattr(b, "set_inline", None)))


def can_inline(bus: Any) -> bool:
    """`inline_pump` can feed this bus's receiver in the thread that delivers its frames."""
    return raw_virtual(bus) is not None or _hooked(bus) is not None


def inline_pump(bus: can.BusABC, fn: Callable[[can.Message], None]) -> Callable[[], None]:
    """Feed each frame received on `bus` (read through `bus`, wrappers and all) to `fn(msg)`
    in the thread that delivers it: on a python-can `virtual` bus the sender's thread, on a
    bus with `set_inline` (zenoh) the thread its frames arrive in. Returns a function that
    stops it: `fn` gets no frame after it returns, and frames wait for `recv` again."""
    raw = raw_virtual(bus)
    if raw is None:
        hooked = _hooked(bus)
        if hooked is None:
            raise TypeError(f"inline_pump: {bus!r} is neither a python-can virtual bus nor "
                            "a bus with set_inline")
        return _hook_pump(bus, hooked, fn)
    with channels_lock:
        courier = _couriers.get(raw.channel_id)
        if courier is None:
            courier = _couriers[raw.channel_id] = Courier()
        old = raw.queue
        new = InlineQueue(courier, lambda: bus.recv(0), fn)
        with courier._mutex:  # nothing handed over until the new queue is in place
            courier.held += 1
        try:
            # a sender from now on, or one already inside the old queue's `put`, puts in
            # the new one; what waited in the old one goes before it, in order
            old.put = new.put
            if isinstance(old, queue.Queue):
                old._put = new.put  # type: ignore[attr-defined]
            waiting: list[can.Message] = []
            while True:
                try:
                    waiting.append(old.get_nowait())
                except queue.Empty:
                    break
            new._items.extendleft(reversed(waiting))
            for _ in waiting:
                courier.add(new)
            _swap(raw, old, new)
        finally:
            with courier._mutex:
                courier.held -= 1
    courier.kick()

    def stop() -> None:
        with channels_lock:
            if raw.queue is not new:
                return
            plain: queue.Queue[can.Message] = queue.Queue()
            new.stopped = True  # entries still in the courier's line hand nothing over
            for msg in list(new._items):
                plain.put(msg)
            new._items.clear()
            new.forward = plain
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


def _hook_pump(bus: can.BusABC, hooked: Any,
               fn: Callable[[can.Message], None]) -> Callable[[], None]:
    """A bus that calls back on each frame (`set_inline(notify)`, `pending()`): each frame
    handed over in the thread it arrived in, one at a time, in arrival order."""
    courier = Courier()
    receiver = _Receiver(lambda: bus.recv(0), fn)

    def notify() -> None:
        courier.add(receiver)
        courier.kick()

    hooked.set_inline(notify)
    for _ in range(hooked.pending()):  # frames that came before
        notify()

    def stop() -> None:
        hooked.set_inline(None)
        receiver.stopped = True

    return stop
