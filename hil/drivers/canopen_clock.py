"""canopen's own waits on the bench's clock (docs/clock.md "What runs on the virtual clock").

canopen waits with `queue.Queue.get`, `threading.Condition.wait` and loops on `time.time()`.
On a virtual bench nothing moves bench time while a thread waits so: a test's
`hil_drive.cia.node.nmt.wait_for_heartbeat(1.0)` took a wall second, saw no bench time pass
and no heartbeat. `node_on_clock` gives a `RemoteNode` clock-aware replies and conditions
(`hil.clock.ClockQueue`, `ClockCondition`); `network_on_clock` does the same for the
network's LSS master; both point the `time` that canopen's modules loop on at `hil.clock`,
which is the `time` module itself unless a virtual run is current, so nothing changes on the
wall clock. The library's code runs unchanged.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import canopen
from canopen.lss import LssMaster
from canopen.sdo.client import SdoClient

from hil import clock

# the canopen modules that loop on `time.time()`/`monotonic()` or `time.sleep()`
_TIMED_MODULES = ("canopen.nmt", "canopen.emcy", "canopen.lss", "canopen.sdo.client",
                  "canopen.profiles.p402")


class _ClockTime:
    """The `time` module as canopen's loops use it, on `hil.clock`'s current clock."""

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)

    @staticmethod
    def time() -> float:
        return clock.time_ns() / 1e9

    @staticmethod
    def monotonic() -> float:
        return clock.monotonic()

    @staticmethod
    def sleep(seconds: float) -> None:
        clk = clock.current()
        if isinstance(clk, clock.VirtualClock) and clk.in_event:
            return  # a clock event never waits (a listener's callback runs in one)
        clk.sleep(seconds)


CLOCK_TIME = _ClockTime()


def _install_time() -> None:
    import importlib

    for name in _TIMED_MODULES:
        mod = importlib.import_module(name)
        if getattr(mod, "time", None) is not CLOCK_TIME:
            mod.time = CLOCK_TIME  # type: ignore[attr-defined]


class _ClockResponses:
    """A canopen client whose reply queue stays a `hil.clock.ClockQueue`: canopen's SDO client
    and LSS master replace `responses` with a fresh `queue.Queue` when they find a stale reply;
    here that empties the ClockQueue instead, so every later reply timeout still passes in
    bench time."""

    __slots__ = ()  # a mixin: the instance keeps its class's layout (`__class__` is swapped)

    @property
    def responses(self) -> Any:
        return self.__dict__["_clock_responses"]

    @responses.setter
    def responses(self, _fresh: Any) -> None:
        q = self.__dict__.get("_clock_responses")
        if q is None:
            self.__dict__["_clock_responses"] = clock.ClockQueue()
            return
        with contextlib.suppress(Exception):
            while True:
                q.get_nowait()


class _ClockSdoClient(SdoClient, _ClockResponses):
    pass


class _ClockLssMaster(LssMaster, _ClockResponses):
    pass


def _replies_on_clock(obj: Any, cls: type) -> Any:
    obj.__dict__.pop("responses", None)
    obj.__class__ = cls
    obj.__dict__["_clock_responses"] = clock.ClockQueue()
    return obj


def sdo_on_clock(sdo: SdoClient) -> SdoClient:
    """Put a canopen SDO client's reply waits on the current clock (a virtual bench)."""
    return _replies_on_clock(sdo, _ClockSdoClient)


def node_on_clock(node: canopen.RemoteNode) -> canopen.RemoteNode:
    """Every wait of a canopen `RemoteNode` on the current clock: SDO replies, heartbeat and
    boot-up (`nmt.wait_for_heartbeat`/`wait_for_bootup`), EMCY (`emcy.wait`) and each PDO's
    `wait_for_reception`."""
    _install_time()
    sdo_on_clock(node.sdo)
    node.nmt.state_update = clock.ClockCondition()
    node.emcy.emcy_received = clock.ClockCondition()
    for pdo in (node.tpdo, node.rpdo):
        for m in pdo.map.values():
            m.receive_condition = clock.ClockCondition()
    return node


def network_on_clock(network: canopen.Network) -> canopen.Network:
    """The network's LSS master's replies on the current clock."""
    _install_time()
    _replies_on_clock(network.lss, _ClockLssMaster)
    return network
