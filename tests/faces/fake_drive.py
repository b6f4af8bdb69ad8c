"""A small state-machine-correct CiA 402 drive for the CANopen face tests (not the model)."""

from __future__ import annotations

from collections.abc import Callable

from hil.model.comm_supervision import CommSupervision
from hil.model.errors import ObjectError
from hil.model.events import AlarmChanged, PowerCycled, StateChanged
from hil.model.options import ModelOptions
from hil.profile.od import ObjectDictionary
from hil.protocol.canopen import ABORT_NO_OBJECT, ABORT_READ_ONLY

SW = {
    "NOT READY TO SWITCH ON": 0x0000,
    "SWITCH ON DISABLED": 0x0040,
    "READY TO SWITCH ON": 0x0021,
    "SWITCHED ON": 0x0023,
    "OPERATION ENABLED": 0x0027,
    "QUICK STOP ACTIVE": 0x0007,
    "FAULT REACTION ACTIVE": 0x000F,
    "FAULT": 0x0008,
}


class FakeAlarms:
    def __init__(self) -> None:
        self.error_register = 0
        self.error_history: list[int] = []  # 1003h entries, newest first


class FakeDrive:
    """Objects from the OD defaults, a CiA 402 state machine, PP/HM shortcuts, alarms."""

    def __init__(self, od: ObjectDictionary | None = None, node_id: int = 5) -> None:
        od = od or ObjectDictionary.a3()
        self.objects: dict[tuple[int, int], int] = {}
        self.readonly: set[tuple[int, int]] = set()
        for (i, s), e in od.entries.items():
            if 0x6000 <= i <= 0x6FFF or 0x2000 <= i <= 0x2FFF:
                self.objects[(i, s)] = e.default or 0
                if not e.writable:
                    self.readonly.add((i, s))
        self.objects[(0x2300, 0)] = node_id
        self.objects[(0x2301, 0)] = 0x0203
        self.readonly.discard((0x2300, 0))
        self.alarms = FakeAlarms()
        self.comm = CommSupervision(ModelOptions(), self.raise_alarm, lambda: 0x5055)
        self.state = "SWITCH ON DISABLED"
        self.t = 0
        self.writes: list[tuple[int, int, int]] = []
        self.comm_alarms: list[str] = []
        self.nmt_resets: list[str] = []
        self._subs: list[Callable] = []
        self._extra_sw = 0
        self._update_sw()

    # -- seam ---------------------------------------------------------------------------
    def subscribe(self, fn: Callable) -> Callable[[], None]:
        self._subs.append(fn)
        return lambda: self._subs.remove(fn) if fn in self._subs else None

    def _emit(self, ev: object) -> None:
        for fn in list(self._subs):
            fn(ev)

    def read_object(self, index: int, sub: int) -> int:
        try:
            return self.objects[(index, sub)]
        except KeyError:
            raise ObjectError(index, sub, ABORT_NO_OBJECT, "no such object") from None

    def write_object(self, index: int, sub: int, value: int) -> None:
        if (index, sub) not in self.objects:
            raise ObjectError(index, sub, ABORT_NO_OBJECT, "no such object")
        if (index, sub) in self.readonly:
            raise ObjectError(index, sub, ABORT_READ_ONLY, "read-only")
        self.writes.append((index, sub, value))
        old = self.objects.get((index, sub))
        self.objects[(index, sub)] = value
        if index == 0x6040:
            self._controlword(old or 0, value)
        elif index == 0x6060:
            self.objects[(0x6061, 0)] = value

    def raise_alarm(self, code: str) -> None:
        self.comm_alarms.append(code)
        self.alarm(code, 0x8130, True)

    def nmt_reset(self, kind: str) -> None:
        self.nmt_resets.append(kind)

    def power_cycle(self) -> None:
        self._emit(PowerCycled(self.t, True))

    # -- behaviour ----------------------------------------------------------------------
    def alarm(self, code: str, emcy: int, active: bool) -> None:
        if active:
            self.alarms.error_register |= 1
            self.alarms.error_history.insert(0, int(code[2:], 16) << 16 | emcy)
            del self.alarms.error_history[5:]
            self._set_state("FAULT")
        else:
            self.alarms.error_register = 0
        self.objects[(0x603F, 0)] = emcy if active else 0
        self._emit(AlarmChanged(self.t, code, active, emcy if active else 0))

    def _set_state(self, new: str) -> None:
        if new != self.state:
            old, self.state = self.state, new
            self._update_sw()
            self._emit(StateChanged(self.t, old, new))

    def _update_sw(self) -> None:
        self.objects[(0x6041, 0)] = (
            SW[self.state] | 0x0010 * (self.state != "SWITCH ON DISABLED") | self._extra_sw
        )

    def _controlword(self, old: int, cw: int) -> None:
        s = self.state
        if s == "FAULT":
            if cw & 0x80 and not old & 0x80 and self.alarms.error_register == 0:
                self._set_state("SWITCH ON DISABLED")
            return
        if not cw & 0x02:
            new = "SWITCH ON DISABLED"
        elif not cw & 0x04:
            new = "QUICK STOP ACTIVE" if s == "OPERATION ENABLED" else "SWITCH ON DISABLED"
        elif cw & 0x0F == 0x06:  # in QUICK STOP ACTIVE: transition 12 (L18262)
            new = "SWITCH ON DISABLED" if s == "QUICK STOP ACTIVE" else "READY TO SWITCH ON"
        elif cw & 0x0F == 0x07:
            new = "SWITCHED ON" if s != "SWITCH ON DISABLED" else s
        elif cw & 0x0F == 0x0F:
            ok = ("READY TO SWITCH ON", "SWITCHED ON", "QUICK STOP ACTIVE", "OPERATION ENABLED")
            new = "OPERATION ENABLED" if s in ok else s
        else:
            new = s
        if s == "QUICK STOP ACTIVE" and new not in ("SWITCH ON DISABLED",) and cw & 0x0F != 0x0F:
            new = s
        self._set_state(new)
        mode = self.objects[(0x6061, 0)]
        if self.state == "OPERATION ENABLED":
            rising = cw & 0x10 and not old & 0x10
            if mode == 6 and rising:  # HM: attained at once
                self._extra_sw = 0x1400
            elif mode == 1 and rising:  # PP: set-point acknowledge
                self._extra_sw = 0x1000
                self.objects[(0x6064, 0)] = self.objects[(0x607A, 0)]
            elif mode == 1 and not cw & 0x10 and self._extra_sw & 0x1000:
                self._extra_sw = 0x0400  # target reached
        else:
            self._extra_sw = 0
        self._update_sw()


# -- a bench: slave + fake drive + master bus on a private virtual channel -----------------

import itertools  # noqa: E402
import threading  # noqa: E402
import time  # noqa: E402
import uuid  # noqa: E402

import can  # noqa: E402

from hil.faces.canopen_slave import CanopenSlave  # noqa: E402

_seq = itertools.count()


class Bench:
    """Slave on one virtual bus end, raw master bus on another; close() closes everything."""

    def __init__(self, node_id: int = 5, **slave_kw) -> None:
        self.channel = f"canopen-test-{uuid.uuid4().hex[:8]}-{next(_seq)}"
        self.slave_bus = can.Bus(interface="virtual", channel=self.channel)
        self.master = can.Bus(interface="virtual", channel=self.channel)
        self.lock = threading.RLock()
        self.od = slave_kw.pop("od", None) or ObjectDictionary.a3()
        self.drive = FakeDrive(self.od, node_id=node_id)
        self.node_id = node_id
        self.slave = CanopenSlave(
            self.slave_bus, self.drive, lock=self.lock, od=self.od, **slave_kw
        )
        self._networks: list = []
        self.slave.start()

    def send(self, can_id: int, data: bytes = b"", remote: bool = False) -> None:
        self.master.send(
            can.Message(
                arbitration_id=can_id, data=data, is_extended_id=False, is_remote_frame=remote
            )
        )

    def expect(self, can_id: int, timeout: float = 1.0) -> can.Message | None:
        """The next frame with this COB-ID (others are skipped), or None."""
        end = time.monotonic() + timeout
        while (left := end - time.monotonic()) > 0:
            msg = self.master.recv(timeout=left)
            if msg is not None and msg.arbitration_id == can_id:
                return msg
        return None

    def sdo(self, data: bytes, timeout: float = 1.0) -> bytes | None:
        self.send(0x600 + self.node_id, data)
        msg = self.expect(0x580 + self.node_id, timeout)
        return bytes(msg.data) if msg is not None else None

    def drain(self, seconds: float = 0.0) -> list[can.Message]:
        out, end = [], time.monotonic() + seconds
        while True:
            msg = self.master.recv(timeout=max(0.0, end - time.monotonic()))
            if msg is None:
                return out
            out.append(msg)

    def network(self):
        """A canopen Network on its own bus end of the same channel (closed by close())."""
        import canopen

        canopen.Network.NOTIFIER_CYCLE = 0.05  # feasibility §3
        net = canopen.Network()
        net.connect(interface="virtual", channel=self.channel)
        self._networks.append(net)
        return net

    def close(self) -> None:
        for net in self._networks:
            net.disconnect()
        self.slave.close()
        self.slave_bus.shutdown()
        self.master.shutdown()
