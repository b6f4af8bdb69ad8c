"""`open_can(url)`: a python-can bus from a transport URL, optionally tapped for recording.

    socketcan:can0            -> can.Bus(interface="socketcan", channel="can0")
    virtual:bus0              -> python-can's virtual bus "bus0" (hil.transport.inline.InlineBus)
    zenoh:<key>?connect=...   -> ZenohBus(channel=<key>, connect=[...], mode=...)
    pcan:PCAN_USBBUS1?bitrate=500000 -> can.Bus(interface="pcan", ..., bitrate=500000)

Query values are cast like python-can config files (`can.util.cast_from_string`). python-can
config files and CAN_* environment variables are ignored (`ignore_config=True`): the URL is
the whole configuration.
"""

from __future__ import annotations

import errno
import socket
from typing import Any

import can
from can import BusABC, Message

from hil import clock
from hil.record.tap import Tap
from hil.transport.cyclic import ClockPeriodic
from hil.transport.inline import InlineBus, courier_of, raw_virtual
from hil.transport.urls import TransportUrl, TransportUrlError, parse_url

# Interfaces whose msg.timestamp is host receive time rather than a source timestamp.
HOST_TIMESTAMP_INTERFACES = frozenset({"virtual", "sim"})


def can_bus_kwargs(u: TransportUrl) -> dict[str, Any]:
    """The can.Bus keyword arguments a parsed CAN URL stands for."""
    if u.scheme == "zenoh":
        ep = u.zenoh()
        return {"interface": "zenoh", "channel": u.target, "mode": ep.mode,
                "listen": list(ep.listen), "connect": list(ep.connect)}
    kwargs: dict[str, Any] = {"interface": u.scheme, "channel": u.target}
    for name, value in u.params.items():
        kwargs[name] = can.util.cast_from_string(value)
    return kwargs


def open_can(url: str, *, tap: Tap | None = None, name: str | None = None,
             **extra: Any) -> BusABC:
    """Open the CAN bus `url`; with `tap`, every frame sent and received is recorded.

    `name` is the bus name in the recording (default: the URL's channel/key). `extra`
    keyword arguments go to can.Bus (e.g. receive_own_messages=True).
    """
    u = parse_url(url, "can")
    kwargs = can_bus_kwargs(u) | extra
    clk = clock.current()
    if isinstance(clk, clock.VirtualClock):  # the virtual bench on its own clock
        if u.scheme != "virtual":
            raise TransportUrlError(url, f"{u.scheme}: a run on the virtual clock has only "
                                         "virtual: CAN buses (use --clock real)")
        from hil.transport.sim import SimCanBus
        bus: BusABC = SimCanBus(u.target, clock=clk, **{k: v for k, v in kwargs.items()
                                                        if k not in ("interface", "channel")})
        return bus if tap is None else TappedBus(bus, tap, name or u.target, interface="sim")
    try:
        if u.scheme == "virtual":  # in process: answers in the sender's thread (inline.py)
            bus = InlineBus(**{k: v for k, v in kwargs.items() if k != "interface"})
        else:
            bus = can.Bus(ignore_config=True, **kwargs)
    except OSError as e:
        raise _os_error(u, e) from e
    except can.CanInitializationError as e:
        cause = e.__cause__ or e.__context__
        if isinstance(cause, OSError):
            raise _os_error(u, cause) from e
        raise TransportUrlError(url, f"cannot open CAN bus: {e}") from e
    except Exception as e:  # vendor drivers fail in their own ways (e.g. NameError, kvaser)
        raise TransportUrlError(url, f"cannot open CAN bus: {type(e).__name__}: {e}") from e
    if tap is None:
        return bus
    return TappedBus(bus, tap, name or u.target, interface=u.scheme)


def _os_error(u: TransportUrl, e: OSError) -> Exception:
    if u.scheme == "socketcan" and (e.errno == errno.EAFNOSUPPORT
                                    or not hasattr(socket, "AF_CAN")):
        return TransportUrlError(u.url, f"SocketCAN (AF_CAN) is not available on this machine "
                                        f"(kernel without CONFIG_CAN): {e}")
    if u.scheme == "socketcan" and e.errno == errno.ENODEV:
        return TransportUrlError(u.url, f"no CAN interface {u.target!r} (ip link show): {e}")
    return TransportUrlError(u.url, f"cannot open CAN bus: {e}")


def source_time_ns(msg: Message, interface: str) -> int | None:
    """The source's own timestamp of a received frame in ns, where the interface has one."""
    sender = getattr(msg, "sender_time_ns", None)
    if sender is not None:
        return sender
    if interface in HOST_TIMESTAMP_INTERFACES or interface == "zenoh" or not msg.timestamp:
        return None
    return int(msg.timestamp * 1e9)


class TappedBus(ClockPeriodic, BusABC):
    """Wraps a bus: every frame sent ("tx") or received ("rx") goes to the tap.

    Received frames are tapped when read (recv / Notifier), before filtering, so the
    recording has everything that arrived. Filters set on this wrapper are software filters.
    """

    def __init__(self, bus: BusABC, tap: Tap, name: str, *, interface: str = "") -> None:
        self.bus = bus
        self.tap = tap
        self.name = name
        self.interface = interface
        self.channel_info = f"{bus.channel_info} (tapped as {name})"
        self._can_protocol = bus.protocol
        self._raw = raw_virtual(bus)
        from hil.transport.sim import SimCanBus, raw_bus

        sim = raw_bus(bus)
        self._sim = sim if isinstance(sim, SimCanBus) else None
        super().__init__(channel=getattr(bus, "channel", name))

    def send(self, msg: Message, timeout: float | None = None) -> None:
        if clock.is_virtual() or self._inline():  # the answers come inside send: tx first
            if self._sim is not None:  # not on the record as sent if the bus refuses it
                self._sim.check_frame(msg)
            self.tap.can(self.name, msg, "tx", clock.time_ns(), None)
            self.bus.send(msg, timeout)
            return
        self.bus.send(msg, timeout)
        self.tap.can(self.name, msg, "tx", clock.time_ns(), None)

    def _inline(self) -> bool:
        """A receiver on this in-process channel is fed in the sender's thread (inline.py)."""
        raw = self._raw
        return raw is not None and courier_of(raw.channel_id) is not None

    def recv(self, timeout: float | None = None) -> Message | None:
        """python-can's `recv`; with no filter set here and a timeout, one read of the inner
        bus, which waits that long itself (the virtual bus's pump reads every frame so)."""
        if self._filters is None and timeout is not None:
            return self._recv_internal(timeout)[0]
        clk = clock.current()
        if isinstance(clk, clock.VirtualClock):  # python-can's loop counts wall seconds
            from hil.transport.sim import recv_on_clock
            return recv_on_clock(self, clk, timeout)
        return super().recv(timeout)

    def _recv_internal(self, timeout: float | None) -> tuple[Message | None, bool]:
        msg = self.bus.recv(timeout)
        if msg is not None:
            self.tap.can(self.name, msg, "rx", clock.time_ns(),
                         source_time_ns(msg, self.interface))
        return msg, False

    @property
    def state(self) -> can.BusState:
        return self.bus.state

    def flush_tx_buffer(self) -> None:
        self.bus.flush_tx_buffer()

    def fileno(self) -> int:
        return self.bus.fileno()

    def shutdown(self) -> None:
        if self._is_shutdown:
            return
        super().shutdown()
        self.bus.shutdown()
