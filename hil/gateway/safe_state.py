"""The gateway's safe state: the bench's drives reached through the exports, driven by the
one routine in hil/safety.py (also the runner's). Runs when a lease ends badly (holder gone,
lease expired) or the gateway stops with a lease held."""

from __future__ import annotations

from typing import TYPE_CHECKING, Any

import can

from hil.gateway.exports import DioExport
from hil.protocol import canopen
from hil.safety import Unanswered, run_safe_state, wait_quick_stop
from hil.units import S

if TYPE_CHECKING:
    from hil.gateway.gateway import Gateway


def sdo_write_controlword(node: int, value: int) -> can.Message:
    """Expedited SDO download of 2 bytes to 6040h:00 (CiA 301, L16960-L16964)."""
    data = canopen.sdo_expedited_download(0x6040, 0, (value & 0xFFFF).to_bytes(2, "little"))
    return can.Message(arbitration_id=canopen.SDO_REQUEST + node, data=data, is_extended_id=False)


class _GatewayDrive:
    """One drive of the gateway's bench, reached through its exports (hil.safety.SafeDrive)."""

    def __init__(self, gw: Gateway, name: str, d: Any) -> None:
        self.gw, self.name, self.d = gw, name, d
        self.dio: DioExport | None = gw.dio.get(name)

    def gone(self) -> str | None:
        return None  # a real drive: its lines are there even when it does not answer

    def has_controlword(self) -> bool:
        return bool(self.d.can and self.d.node_id and self.d.can in self.gw.can)

    def write_controlword(self, cw: int) -> str | bool:
        export, node = self.gw.can[self.d.can], self.d.node_id
        timeout_s = self.gw.bench.safe_state.timeout_ns / S
        ans = export.request(
            sdo_write_controlword(node, cw),
            lambda m: m.arbitration_id == canopen.SDO_RESPONSE + node
            and bytes(m.data[1:4]) == b"\x40\x60\x00",
            min(timeout_s, 1.0))
        if ans is None:  # sent, but the drive did not say it took it: not confirmed, as
            raise Unanswered(  # the runner's safe state counts it (helper-126)
                f"sent; no SDO answer within {min(timeout_s, 1.0):g} s")
        return "acknowledged" if ans.data[0] == 0x60 else False  # 60h: download response

    def _upload(self, index: int, timeout_s: float) -> int | None:
        """An expedited SDO upload of `index`:00 through the export, signed (None: no
        answer or an abort)."""
        export, node = self.gw.can[self.d.can], self.d.node_id
        req = can.Message(arbitration_id=canopen.SDO_REQUEST + node, is_extended_id=False,
                          data=canopen.sdo_upload_request(index, 0))
        ans = export.request(req, lambda m: m.arbitration_id == canopen.SDO_RESPONSE + node
                             and bytes(m.data[1:4]) == bytes((index & 0xFF, index >> 8, 0)),
                             timeout_s)
        if ans is None or ans.data[0] & 0xE2 != 0x42:  # 42h: expedited, size not given
            return None
        size = 4 - ((ans.data[0] >> 2) & 0x3) if ans.data[0] & 0x01 else 4
        return int.from_bytes(bytes(ans.data[4:4 + size]), "little", signed=True)

    def quick_stop_done(self, timeout_ns: int) -> str | bool:
        """Until the quick stop's ramp has ended (`wait_quick_stop`, objects read by SDO
        through the export): the safe state then writes disable voltage (L18262)."""
        done, what = wait_quick_stop(lambda index: self._upload(index, 0.2), timeout_ns, 0.01)
        return what if done else False

    def di_wired(self, function: str) -> bool:
        return self.dio is not None and function in self.d.di

    def set_di(self, function: str, active: bool) -> Any:
        wire = self.d.di[function]
        assert self.dio is not None
        return self.dio.set(wire.line, wire.level_for(active))

    def has_sto(self) -> bool:
        return self.dio is not None

    def set_sto(self, channel: str, on: bool) -> Any:
        assert self.dio is not None
        return self.dio.set(self.d.sto.get(channel, f"STO_{channel}"), on)

    def has_brkr(self) -> bool:
        return self.dio is not None and "BRKR" in self.d.do

    def brake_engaged(self, timeout_ns: int) -> str | bool:
        port = self.dio.port if self.dio is not None else None
        if port is None:
            return False
        wire = self.d.do["BRKR"]
        port.wait_for(wire.line, wire.level_for(False), timeout_ns / S)
        return "BRKR off: brake engaged"


def default_safe_state(gw: Gateway, reason: str) -> list[dict]:
    """The bench file's `safe_state`, by the one routine (hil/safety.py): controlword by SDO
    to every CAN drive, DI functions (SON off) and STO levels on each drive's lines, then wait
    for BRKR off (brake engaged). Every action is attempted even if an earlier one failed."""

    def record(drive: str, action: str, ok: bool, msg: str, extra: dict[str, Any]) -> None:
        if gw.recorder is not None:
            gw.recorder.safety(action, reason, source="gateway", drive=drive, ok=ok,
                               detail=msg, **extra)

    drives = [_GatewayDrive(gw, name, d) for name, d in gw.bench.drives.items()]
    return run_safe_state(drives, gw.bench.safe_state, reason, record).actions
