"""`ZenohBus`: a python-can bus whose frames travel as zenoh samples on one key.

Registered as python-can interface `zenoh` (pyproject entry point `can.interface`):

    can.Bus(interface="zenoh", channel="bench/can0", listen=["tcp/127.0.0.1:7447"])
    can.Bus(interface="zenoh", channel="bench/can0", connect="tcp/127.0.0.1:7447")
    canopen.Network().connect(interface="zenoh", channel="bench/can0", connect=[...])

Wire format, one sample per frame on key `<channel>` (14 bytes + data):
`struct "<IBBq"` arbitration id, flags (EXT 1, RTR 2, ERR 4, FD 8, BRS 16, ESI 32), dlc,
sender time (int ns, `time.time_ns()` at send, or the message's own timestamp with
`preserve_timestamps=True`, e.g. a gateway forwarding hardware-stamped frames), then data.

Received messages are `ZenohMessage`s: `timestamp` = receive time (`time.time()`), and
`sender_time_ns` = the sender's time (behind a `hil gateway`: the bench's capture time).
A gateway lease held in this process (zenoh_net.lease_token) rides as the sample
attachment. Not a CAN simulator: no arbitration, no error frames or bus-off, no wire
time; filters are python-can's software filters.
"""

from __future__ import annotations

import logging
import queue
import struct
import time
from collections.abc import Callable, Iterable
from typing import Any

import can
import zenoh
from can import BusABC, CanInitializationError, CanOperationError, CanProtocol, Message

from hil.transport.urls import check_zenoh_key
from hil.transport.zenoh_net import (
    close_session,
    lease_token,
    make_config,
    open_session,
    undeclare,
    wait_connected,
    wait_matching,
)

log = logging.getLogger(__name__)

HEADER = struct.Struct("<IBBq")
SYNC_CHUNK = "_zenohbus_sync"  # queryable `<channel>/_zenohbus_sync`, see __init__
EXT, RTR, ERR, FD, BRS, ESI = 1, 2, 4, 8, 16, 32


class ZenohMessage(Message):
    """A received frame; `sender_time_ns` is the sender's wall-clock time in ns."""

    __slots__ = ("sender_time_ns",)


def pack(msg: Message, sender_time_ns: int) -> bytes:
    flags = ((EXT if msg.is_extended_id else 0) | (RTR if msg.is_remote_frame else 0)
             | (ERR if msg.is_error_frame else 0) | (FD if msg.is_fd else 0)
             | (BRS if msg.bitrate_switch else 0) | (ESI if msg.error_state_indicator else 0))
    return HEADER.pack(msg.arbitration_id, flags, msg.dlc, sender_time_ns) + bytes(msg.data)


FD_LENGTHS = frozenset((*range(9), 12, 16, 20, 24, 32, 48, 64))  # ISO 11898-1 FD payloads


def _check_frame(can_id: int, flags: int, dlc: int, data: bytes) -> None:
    """A frame a CAN controller could put on the wire (ValueError otherwise: a bad sample is
    dropped and counted, never forwarded to a bus): 11-bit id unless extended (29-bit), a
    classic frame 0-8 bytes matching its DLC (a remote frame: no data, DLC 0-8), an FD frame
    one of the FD lengths."""
    if can_id > (0x1FFFFFFF if flags & EXT else 0x7FF):
        raise ValueError(f"CAN id 0x{can_id:X} beyond {'29' if flags & EXT else '11'} bits")
    if flags & ERR:
        if len(data) > 8 or dlc > 8:
            raise ValueError(f"error frame with {len(data)} data bytes, DLC {dlc}")
        return
    if flags & FD:
        if flags & RTR:
            raise ValueError("an FD frame has no remote form")
        if len(data) not in FD_LENGTHS or dlc != len(data):
            raise ValueError(f"FD frame of {len(data)} bytes, DLC {dlc}")
    elif flags & RTR:
        if data or dlc > 8:
            raise ValueError(f"remote frame with {len(data)} data bytes, DLC {dlc}")
    elif len(data) > 8 or dlc != len(data):
        raise ValueError(f"classic frame of {len(data)} bytes, DLC {dlc}")


def unpack(payload: bytes, timestamp: float, channel: str | None = None) -> ZenohMessage:
    if len(payload) < HEADER.size:
        raise ValueError(f"zenoh CAN sample of {len(payload)} bytes is shorter than the "
                         f"{HEADER.size}-byte header")
    can_id, flags, dlc, sender_ns = HEADER.unpack_from(payload)
    data = payload[HEADER.size:]
    _check_frame(can_id, flags, dlc, data)
    msg = ZenohMessage(
        timestamp=timestamp, arbitration_id=can_id, is_extended_id=bool(flags & EXT),
        is_remote_frame=bool(flags & RTR), is_error_frame=bool(flags & ERR),
        is_fd=bool(flags & FD), bitrate_switch=bool(flags & BRS),
        error_state_indicator=bool(flags & ESI), dlc=dlc,
        data=None if flags & RTR else data, channel=channel, is_rx=True, check=False,
    )
    msg.sender_time_ns = sender_ns
    return msg


def _endpoints(value: str | Iterable[str] | None) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return list(value)


class ZenohBus(BusABC):
    """python-can bus over zenoh pub/sub (see module docstring)."""

    def __init__(
        self,
        channel: str,
        can_filters: can.typechecking.CanFilters | None = None,
        *,
        listen: str | Iterable[str] | None = None,
        connect: str | Iterable[str] | None = None,
        mode: str = "peer",
        receive_own_messages: bool = False,
        preserve_timestamps: bool = False,
        fd: bool = False,
        connect_timeout: float = 5.0,
        match_timeout: float = 0.5,
        allow_remote: bool = False,
        session: zenoh.Session | None = None,
        **kwargs: Any,
    ) -> None:
        """Open a zenoh session (or use `session`) and join key `channel`.

        listen / connect: endpoints (list or comma-separated string), loopback TCP unless
        `allow_remote`. mode: "peer" (2 processes, or a full mesh) or "client" (through
        `hil.transport.zenoh_net.start_router`). With connect endpoints, waits up to
        `connect_timeout` s for the link and up to `match_timeout` s for a remote subscriber
        so the first frames are not lost. Other kwargs (bitrate, ...) are ignored.
        """
        key = str(channel)
        check_zenoh_key(f"zenoh:{key}", key)
        self.channel_info = f"zenoh key {key}"
        self._key = key
        self._own_session = session is None
        self.receive_own_messages = receive_own_messages
        self.preserve_timestamps = preserve_timestamps
        self._can_protocol = CanProtocol.CAN_FD if fd else CanProtocol.CAN_20
        self._queue: queue.SimpleQueue[Message] = queue.SimpleQueue()
        self._notify: Callable[[], None] | None = None  # set_inline
        self._sub = self._pub = self._sync = None
        listen_l, connect_l = _endpoints(listen), _endpoints(connect)
        what = f"zenoh CAN bus {key!r}"
        if session is None:
            try:
                config = make_config(mode, listen=listen_l, connect=connect_l,
                                     allow_remote=allow_remote)
            except ValueError as e:
                raise CanInitializationError(f"{what}: {e}") from None
            try:
                session = open_session(config, what=what)
            except ConnectionError as e:
                raise CanInitializationError(str(e)) from None
        self._session = session
        try:
            if connect_l:
                wait_connected(session, connect_timeout, what=what, endpoints=connect_l)
            self._sub = session.declare_subscriber(
                key, self._on_sample, allowed_origin=zenoh.Locality.REMOTE)
            sync_key = f"{key}/{SYNC_CHUNK}"
            self._sync = session.declare_queryable(
                sync_key, lambda q: q.reply(sync_key, b""), allowed_origin=zenoh.Locality.REMOTE)
            self._pub = session.declare_publisher(
                key, express=True, congestion_control=zenoh.CongestionControl.BLOCK,
                allowed_destination=zenoh.Locality.REMOTE)
            if connect_l and match_timeout > 0 and wait_matching(self._pub, match_timeout):
                # One round trip: links are FIFO, so once the other buses answer they have
                # seen our subscriber and their first frames reach us.
                for _ in session.get(sync_key, timeout=match_timeout,
                                     allowed_destination=zenoh.Locality.REMOTE):
                    pass
        except (ConnectionError, zenoh.ZError) as e:
            self._close_zenoh()
            raise CanInitializationError(f"{e}") from None
        super().__init__(channel=key, can_filters=can_filters, **kwargs)

    @property
    def session(self) -> zenoh.Session:
        return self._session

    def set_inline(self, notify: Callable[[], None] | None) -> None:
        """Call `notify()` after each received frame is queued, in the thread it arrived in
        (zenoh's): `hil.transport.inline.inline_pump` then reads it at once instead of a
        receive thread. None: frames wait for `recv` again."""
        self._notify = notify

    def pending(self) -> int:
        """Frames waiting for `recv`."""
        return self._queue.qsize()

    def _on_sample(self, sample: zenoh.Sample) -> None:
        t = time.time()
        try:
            self._queue.put(unpack(sample.payload.to_bytes(), t, self._key))
        except ValueError as e:
            log.warning("%s: dropped sample: %s", self.channel_info, e)
            return
        notify = self._notify
        if notify is not None:
            notify()

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        if self._is_shutdown:
            raise CanOperationError(f"{self.channel_info}: bus is shut down")
        try:
            return self._queue.get(timeout=timeout), False
        except queue.Empty:
            return None, False

    def send(self, msg: Message, timeout: float | None = None) -> None:
        if self._is_shutdown or self._pub is None:
            raise CanOperationError(f"{self.channel_info}: bus is shut down")
        if self.preserve_timestamps and msg.timestamp:
            sender_ns = int(msg.timestamp * 1e9)
        else:
            sender_ns = time.time_ns()
        try:
            self._pub.put(pack(msg, sender_ns), attachment=lease_token(self._key))
        except zenoh.ZError as e:
            raise CanOperationError(f"{self.channel_info}: send failed: {e}") from None
        if self.receive_own_messages:
            own = unpack(pack(msg, sender_ns), time.time(), self._key)
            own.is_rx = False
            self._queue.put(own)
            notify = self._notify
            if notify is not None:
                notify()

    def _close_zenoh(self) -> None:
        undeclare(self._sub, self._sync, self._pub)
        self._sub = self._pub = self._sync = None
        if self._own_session and self._session is not None:
            close_session(self._session)

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self._close_zenoh()

    @staticmethod
    def _detect_available_configs() -> list[can.typechecking.AutoDetectedConfig]:
        return []
