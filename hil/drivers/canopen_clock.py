"""canopen's own waits on the bench's clock (docs/clock.md "What runs on the virtual clock").

canopen waits with `queue.Queue.get`, `threading.Condition.wait` and loops on `time.time()`.
On a virtual bench nothing moves bench time while a thread waits so: a test's
`hil_drive.cia.node.nmt.wait_for_heartbeat(1.0)` took a wall second, saw no bench time pass
and no heartbeat. A virtual session's networks are `ClockNetwork`s: each client that
subscribes (SDO client, LSS master, NMT master, EMCY consumer, PDO map) gets clock-aware
replies or conditions (`hil.clock.ClockQueue`, `ClockCondition`); the NMT boot-up wait and
the EMCY wait, which canopen loops on `time.time()`, are clock-condition waits of their own;
and the `time` that canopen's other modules loop on reads bench time in the run's own
thread while a virtual run is current, the `time` module itself anywhere else, so nothing
changes on the wall clock. The rest of the library's code runs unchanged.
"""

from __future__ import annotations

import contextlib
import time
from typing import Any

import canopen
from canopen.emcy import EmcyConsumer
from canopen.lss import LssMaster
from canopen.nmt import NmtError, NmtMaster
from canopen.pdo.base import PdoMap
from canopen.sdo.client import SdoClient

from hil import clock

# the canopen modules that loop on `time.time()`/`monotonic()` or `time.sleep()`
# (NMT's boot-up wait and the EMCY wait loop on `time.time()` around a condition: their own
# clock-aware versions below, so that a plain canopen network keeps canopen's behaviour)
_TIMED_MODULES = ("canopen.lss", "canopen.sdo.client", "canopen.profiles.p402",
                  "canopen.timestamp")


def _bench() -> clock.VirtualClock | None:
    """The virtual clock when this thread is the run's (`may_wait`), else None: canopen used
    from a thread of a test's own keeps the wall clock, as its own waits there do."""
    clk = clock.current()
    return clk if isinstance(clk, clock.VirtualClock) and clk.may_wait() else None


class _ClockTime:
    """The `time` module as canopen's loops use it: bench time in the run's own thread while
    a virtual run is current, the wall clock anywhere else."""

    def __getattr__(self, name: str) -> Any:
        return getattr(time, name)

    @staticmethod
    def time() -> float:
        clk = _bench()
        return time.time() if clk is None else clk.time_ns() / 1e9

    @staticmethod
    def monotonic() -> float:
        clk = _bench()
        return time.monotonic() if clk is None else clk.time_ns() / 1e9

    @staticmethod
    def sleep(seconds: float) -> None:
        clk = _bench()
        if clk is None:
            time.sleep(seconds)
        elif not clk.in_event:  # a clock event never waits (a listener's callback runs in one)
            clk.sleep(seconds)


CLOCK_TIME = _ClockTime()


_installed: list[bool] = []  # `_install_time` ran (once per process)


def _install_time() -> None:
    if _installed:
        return
    import importlib

    for name in _TIMED_MODULES:
        importlib.import_module(name).time = CLOCK_TIME  # type: ignore[attr-defined]
    _installed.append(True)


# canopen's `wait_for_bootup` passes 0.1 s over its timeout (canopen/nmt.py, 2.x)
BOOTUP_SLACK_S = 0.1


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


class _ClockNmtMaster(NmtMaster):
    """canopen's NMT master with `wait_for_bootup` on its clock condition: canopen's loops
    on `time.time()` around the condition's wait."""

    def wait_for_bootup(self, timeout: float = 10) -> None:
        """A boot-up within `timeout` + 0.1 s, as canopen's own loop takes one (its last
        pass waits 0.1 s past the timeout: what a real bench accepts)."""
        with self.state_update:
            self._state_received = None
            if not self.state_update.wait_for(lambda: self._state_received == 0,
                                              timeout + BOOTUP_SLACK_S):
                raise NmtError("Timeout waiting for boot-up message")


class _ClockEmcyConsumer(EmcyConsumer):
    """canopen's EMCY consumer with `wait` on its clock condition (canopen's loops on
    `time.time()`): the first EMCY with `emcy_code` (any, if None) that comes within
    `timeout`, else None."""

    def wait(self, emcy_code: int | None = None, timeout: float = 10) -> Any:
        with self.emcy_received:
            start = len(self.log)

            def first() -> Any:
                return next((e for e in self.log[start:]
                             if emcy_code is None or e.code == emcy_code), None)
            self.emcy_received.wait_for(lambda: first() is not None, timeout)
            return first()


class _ClockLssMaster(LssMaster, _ClockResponses):
    pass


def _replies_on_clock(obj: Any, cls: type) -> Any:
    obj.__dict__.pop("responses", None)
    obj.__class__ = cls
    obj.__dict__["_clock_responses"] = clock.ClockQueue()
    return obj


def sdo_on_clock(sdo: SdoClient) -> SdoClient:
    """Put a canopen SDO client's reply waits on the current clock (a virtual bench)."""
    if isinstance(sdo, _ClockSdoClient):
        return sdo
    return _replies_on_clock(sdo, _ClockSdoClient)


def _condition_on_clock(obj: Any, name: str) -> None:
    if not isinstance(getattr(obj, name, None), clock.ClockCondition):
        setattr(obj, name, clock.ClockCondition())


def on_clock(obj: Any) -> None:
    """One canopen client object's waits on the current clock: an SDO client's or the LSS
    master's reply queue, an NMT master's heartbeat and boot-up condition, an EMCY consumer's,
    a PDO map's reception condition. Anything else is left as it is."""
    _install_time()
    if isinstance(obj, SdoClient):
        sdo_on_clock(obj)
    elif isinstance(obj, LssMaster):
        if not isinstance(obj, _ClockLssMaster):
            _replies_on_clock(obj, _ClockLssMaster)
    elif isinstance(obj, NmtMaster):
        _condition_on_clock(obj, "state_update")
        obj.__class__ = _ClockNmtMaster
    elif isinstance(obj, EmcyConsumer):
        _condition_on_clock(obj, "emcy_received")
        obj.__class__ = _ClockEmcyConsumer
    elif isinstance(obj, PdoMap):
        _condition_on_clock(obj, "receive_condition")


def node_on_clock(node: canopen.RemoteNode) -> canopen.RemoteNode:
    """Every wait of a canopen `RemoteNode` on the current clock: SDO replies, heartbeat and
    boot-up (`nmt.wait_for_heartbeat`/`wait_for_bootup`), EMCY (`emcy.wait`) and each PDO's
    `wait_for_reception`. A `ClockNetwork` does it for every node as the node subscribes."""
    for sdo in node.sdo_channels:
        on_clock(sdo)
    on_clock(node.nmt)
    on_clock(node.emcy)
    for pdo in (node.tpdo, node.rpdo):
        for m in pdo.map.values():
            on_clock(m)
    return node


class ClockNetwork(canopen.Network):
    """A canopen `Network` whose clients wait on the current clock: each one gets its clock
    queue or condition as it subscribes (`on_clock`), so the LSS master, the driver's node,
    a node a test adds itself (`net.add_node`, `node.associate_network(net)`) and a PDO it
    subscribes all wait in bench time. On the wall clock the same objects behave as canopen's."""

    def subscribe(self, can_id: int, callback: Any) -> None:
        on_clock(getattr(callback, "__self__", None))
        super().subscribe(can_id, callback)

    def __setitem__(self, node_id: int, node: Any) -> None:
        """`add_node` / `net[id] = node`: the node's PDO maps too, subscribed or not (an
        unsubscribed map's `wait_for_reception` then times out in bench time)."""
        if isinstance(node, canopen.RemoteNode):
            node_on_clock(node)
        super().__setitem__(node_id, node)
