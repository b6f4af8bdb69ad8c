"""Strict CiA 402 master driver (the harness side), on canopen's RemoteNode SDO client.

Every wait has a named timeout (bench file `timeouts`, defaults in DEFAULT_TIMEOUTS) and every
failure raises a `Cia402Error` subclass saying what was expected and what was seen (state,
statusword hex, elapsed time). Unlike canopen's BaseNode402 it never swallows a timeout
(docs/dev/feasibility.md §3.5) and does not depend on a cyclic statusword TPDO (§3.3): the
statusword is polled over SDO, so the same code works on a real A3 that ships with no PDO mapping
(L17980-L18024). Controlword sequences follow L17135-L17376.
"""

from __future__ import annotations

import struct
import threading
from collections.abc import Callable
from pathlib import Path
from typing import Any

import canopen
from canopen.profiles.p402 import State402
from canopen.sdo.exceptions import SdoAbortedError, SdoCommunicationError

from hil import clock
from hil.drivers import sdo_transfer
from hil.drivers.sdo_transfer import SdoMalformedError
from hil.fileio import parsed_once
from hil.profile.od import EDS_PATH
from hil.protocol.canopen import abort_text
from hil.protocol.cia402 import (
    CW_DISABLE_VOLTAGE,
    CW_ENABLE_OPERATION,
    CW_FAULT_RESET,
    CW_QUICK_STOP,
    CW_SHUTDOWN,
    CW_SWITCH_ON,
    MODE_NAMES,
    MODES,
)

DEFAULT_TIMEOUTS: dict[str, float] = {
    "sdo": 0.5,  # one SDO round trip (canopen's client timeout)
    "state": 1.0,  # one power-state transition seen in the statusword
    "mode": 0.5,  # 6061h echoes 6060h
    "setpoint_ack": 1.0,  # PP: statusword bit 12 after the bit 4 edge
    "target_reached": 30.0,  # PP: bit 10 after the set-point
    "homing": 60.0,  # HM: bit 12 attained / bit 13 error
    "fault_reset": 1.0,  # FAULT -> SWITCH ON DISABLED after the bit 7 edge
    "poll": 0.002,  # statusword poll period (not a timeout)
}

# (mask, value) per state: canopen's table, the same as the manual's (L18321-L18331).
STATES: dict[str, tuple[int, int]] = State402.SW_MASK
SW_TARGET_REACHED = 1 << 10
SW_BIT12 = 1 << 12  # PP set-point acknowledge / HM homing attained (L18335-L18338)
SW_BIT13 = 1 << 13  # PP following error / HM homing error


def decode_state(statusword: int) -> str:
    """CiA 402 state name of a statusword (L18321-L18331)."""
    for name, (mask, value) in STATES.items():
        if statusword & mask == value:
            return name
    return "UNKNOWN"


class Cia402Error(Exception):
    """A CiA 402 request the drive did not honour; says what was expected and seen."""


class Cia402Timeout(Cia402Error):
    """A wait ran out: `expected`, last `statusword` and `state`, `elapsed` seconds."""

    def __init__(
        self,
        node: int,
        what: str,
        timeout_name: str,
        timeout: float,
        statusword: int | None,
        elapsed: float,
        detail: str = "",
    ) -> None:
        self.expected = what
        self.statusword = statusword
        self.state = decode_state(statusword) if statusword is not None else "unknown"
        self.elapsed = elapsed
        self.timeout_name = timeout_name
        sw = f"0x{statusword:04X}" if statusword is not None else "none"
        extra = f"; {detail}" if detail else ""
        super().__init__(
            f"node {node}: expected {what} within {timeout:.3f} s (timeouts[{timeout_name!r}]), "
            f"saw state {self.state} (statusword {sw}) after {elapsed:.3f} s{extra}"
        )


def _setpoint_hint(sw: int) -> str:
    """Why a PP set-point may wait for its acknowledge: a move still runs (bit 10 low)."""
    if sw & SW_TARGET_REACHED:
        return ""
    return ("a set-point given while a move runs (bit 5 = 0) is acknowledged only when that "
            "move completes (A3 manual L17172-17174): give timeouts.setpoint_ack the time "
            "of the move before it, or wait for it first")


class Cia402Cancelled(Cia402Error):
    """A wait was given up because its owner cancelled it (`Cia402Driver.cancel`)."""


class Cia402Fault(Cia402Error):
    """The drive entered FAULT while something else was expected."""


class Cia402ModeError(Cia402Error):
    """Unknown mode name, or 6061h did not echo 6060h."""


class HomingError(Cia402Error):
    """Homing reported an error (statusword bit 13, L18337-L18338)."""


class ObjectValueError(Cia402Error):
    """A value the object's EDS type cannot carry: refused before anything is sent."""

    def __init__(self, node: int, index: int, sub: int, value: int, why: str) -> None:
        self.index, self.sub, self.value = index, sub, value
        super().__init__(f"node {node}: {why}: {value} not sent")


# what an SDO access can raise on a drive's bad answer: aborts and silence, and the errors the
# client raises on a frame it cannot take (a short frame: struct.error; an expedited size
# that does not fit the object's type: ObjectDictionaryError)
_SDO_FAILURES = (SdoAbortedError, SdoCommunicationError, struct.error,
                 canopen.objectdictionary.ObjectDictionaryError)


class SdoError(Cia402Error):
    """An SDO access aborted or timed out (abort code and its CiA 301 text)."""

    def __init__(self, node: int, index: int, sub: int, op: str, exc: Exception) -> None:
        self.index, self.sub = index, sub
        self.abort_code = getattr(exc, "code", None)
        if self.abort_code is not None:
            why = f"abort 0x{self.abort_code:08X} ({abort_text(self.abort_code)})"
        elif isinstance(exc, SdoCommunicationError) and not isinstance(exc, SdoMalformedError):
            why = f"no answer ({exc})"
        else:  # an answer the SDO client could not take (too short, wrong size for the type)
            why = f"malformed answer ({type(exc).__name__}: {exc})"
        super().__init__(f"node {node}: SDO {op} {index:04X}h sub {sub}: {why}")


def object_dictionary(eds: str | Path, node_id: int) -> canopen.ObjectDictionary:
    """The EDS as canopen reads it, parsed once per file version and node id in a process
    (`fileio.parsed_once`: a session per plan would parse it again each time; nodes only
    read it)."""
    return parsed_once("EDS", eds, lambda: canopen.import_od(str(eds), node_id), node_id)


def od_variable(od: canopen.ObjectDictionary, index: int, sub: int
                ) -> canopen.objectdictionary.ODVariable | None:
    """The EDS entry of `index:sub` (a plain variable is its own sub 0); None if absent."""
    obj = od.get(index)
    if obj is None:
        return None
    if isinstance(obj, canopen.objectdictionary.ODVariable):
        return obj if sub == obj.subindex else None
    try:
        return obj[sub]
    except KeyError:
        return None


def value_range(var: canopen.objectdictionary.ODVariable) -> tuple[int, int] | str:
    """The integers an object of this EDS type can carry, or its type's name when it holds
    no integer (a string, a domain)."""
    fmt = var.STRUCT_TYPES.get(var.data_type)
    if fmt is None:
        return DATA_TYPE_NAMES.get(var.data_type, f"data type {var.data_type:#x}")
    code = fmt.format.lstrip("<")
    if code == "?":
        return 0, 1
    if code in "fd":  # REAL32 / REAL64 take an integer as its float
        return -(2**31), 2**32 - 1
    bits = 8 * fmt.size
    if code.islower():
        return -(1 << (bits - 1)), (1 << (bits - 1)) - 1
    return 0, (1 << bits) - 1


DATA_TYPE_NAMES = {0x09: "VISIBLE_STRING", 0x0A: "OCTET_STRING", 0x0B: "UNICODE_STRING",
                   0x0F: "DOMAIN"}


def value_refusal(od: canopen.ObjectDictionary, index: int, sub: int, value: int
                  ) -> str | None:
    """Why the EDS type of `index:sub` cannot carry `value` (None: it can, or the EDS has no
    such object, which the driver writes as 32 bits and the drive answers)."""
    var = od_variable(od, index, sub)
    return None if var is None else _refusal(var, index, sub, value)


def _refusal(var: canopen.objectdictionary.ODVariable, index: int, sub: int, value: int
             ) -> str | None:
    rng = value_range(var)
    if isinstance(rng, str):
        return f"{index:04X}h sub {sub} holds a {rng}, not an integer"
    if not rng[0] <= value <= rng[1]:
        return f"{index:04X}h sub {sub} takes {rng[0]}..{rng[1]} by the drive's EDS"
    return None


class Cia402Driver:
    """Strict CiA 402 master for one node on a `canopen.Network`."""

    def __init__(
        self,
        network: canopen.Network,
        node_id: int,
        *,
        eds: str | Path | None = None,
        timeouts: dict[str, float] | None = None,
        recorder: Any = None,
        clock: Callable[[], float] = clock.monotonic,
    ) -> None:
        unknown = set(timeouts or {}) - set(DEFAULT_TIMEOUTS)
        if unknown:
            raise ValueError(
                f"timeouts: unknown names {sorted(unknown)}; known: {sorted(DEFAULT_TIMEOUTS)}"
            )
        self.timeouts = {**DEFAULT_TIMEOUTS, **(timeouts or {})}
        self.node_id = node_id
        self.recorder = recorder
        self.clock = clock
        self.node = canopen.RemoteNode(node_id, object_dictionary(eds or EDS_PATH, node_id))
        network.add_node(self.node)
        self.node.sdo.RESPONSE_TIMEOUT = self.timeouts["sdo"]
        self._controlword = 0
        # One SDO transaction at a time: a step thread polling 6041h and the safe-state
        # routine share this client (canopen's SdoClient pairs replies by arrival order).
        self.lock = threading.RLock()
        # Set by the owner (the plan runner) to end waits early; None: never cancelled.
        self.cancel: threading.Event | None = None

    # ------------------------------------------------------------------ objects
    def _step(self, name: str, **fields: Any) -> None:
        step = getattr(self.recorder, "step", None)
        if callable(step):
            step(name, node=self.node_id, **fields)

    def read(self, index: int, sub: int = 0) -> int:
        """SDO upload decoded with the EDS type (raises SdoError)."""
        try:
            with self.lock:
                var = od_variable(self.node.object_dictionary, index, sub)
                data = sdo_transfer.upload(self.node.sdo, index, sub)
                if var is None:  # not in the EDS: the bytes the drive gives, little-endian
                    return int.from_bytes(data, "little")
                if var.fixed_size and len(data) > len(var) // 8:
                    data = data[:len(var) // 8]  # a U32 answer for a U16 (canopen's rule)
                return var.decode_raw(data)
        except _SDO_FAILURES as exc:
            raise SdoError(self.node_id, index, sub, "upload", exc) from None

    def write(self, index: int, sub: int, value: int) -> None:
        """SDO download encoded with the EDS type; an object the EDS lacks goes as 32 bits
        (the drive answers, e.g. abort 0602 0000). Raises SdoError, or ObjectValueError for a
        value its EDS type cannot carry (nothing is sent)."""
        var = od_variable(self.node.object_dictionary, index, sub)
        why = None if var is None else _refusal(var, index, sub, value)
        if why is not None:
            raise ObjectValueError(self.node_id, index, sub, value, why)
        data = ((value & 0xFFFFFFFF).to_bytes(4, "little") if var is None
                else var.encode_raw(value))
        self._step("sdo_write", index=index, sub=sub, value=value)
        try:
            with self.lock:
                sdo_transfer.download(self.node.sdo, index, sub, data)
        except _SDO_FAILURES as exc:
            raise SdoError(self.node_id, index, sub, "download", exc) from None

    @property
    def statusword(self) -> int:
        return self.read(0x6041)

    @property
    def state(self) -> str:
        return decode_state(self.statusword)

    def _cw(self, value: int) -> None:
        self._controlword = value
        self.write(0x6040, 0, value)

    # ------------------------------------------------------------------ waiting
    def _wait(
        self,
        what: str,
        timeout_name: str,
        ok: Callable[[int], bool],
        fail: Callable[[int], str | None] | None = None,
        hint: Callable[[int], str] | None = None,  # why, from the last statusword, on a timeout
    ) -> int:
        timeout = self.timeouts[timeout_name]
        t0 = self.clock()
        sw = None
        while True:
            sw = self.statusword
            if ok(sw):
                return sw
            reason = fail(sw) if fail else None
            elapsed = self.clock() - t0
            if reason:
                raise (HomingError if "homing" in reason else Cia402Fault)(
                    f"node {self.node_id}: expected {what}, saw {reason}: state "
                    f"{decode_state(sw)} (statusword 0x{sw:04X}) after {elapsed:.3f} s"
                )
            if elapsed >= timeout:
                raise Cia402Timeout(self.node_id, what, timeout_name, timeout, sw, elapsed,
                                    hint(sw) if hint is not None else "")
            self._pause(timeout - elapsed)  # the last look at the timeout, not a poll past it

    def _pause(self, at_most: float | None = None) -> None:
        """One poll interval (`at_most` shorter); raises Cia402Cancelled once `cancel` is set."""
        period = self.timeouts["poll"] if at_most is None else min(self.timeouts["poll"], at_most)
        if self.cancel is None:
            clock.sleep(period)
        elif clock.wait(self.cancel, period):
            raise Cia402Cancelled(f"node {self.node_id}: wait cancelled")

    def wait_state(self, name: str, timeout: float | None = None) -> int:
        """Wait until the statusword decodes to `name`; returns the statusword."""
        if name not in STATES:
            raise Cia402Error(f"unknown CiA 402 state {name!r}; known: {sorted(STATES)}")
        mask, value = STATES[name]
        saved = self.timeouts["state"]
        if timeout is not None:
            self.timeouts["state"] = timeout
        try:

            def fault(sw: int) -> str | None:
                return "FAULT" if name != "FAULT" and sw & 0x08 else None

            return self._wait(name, "state", lambda sw: sw & mask == value, fault)
        finally:
            self.timeouts["state"] = saved

    # ------------------------------------------------------------------ power states
    def _go(self, cw: int, target: str) -> None:
        self._step("controlword", value=cw, target=target)
        self._cw(cw)
        self.wait_state(target)

    def enable_operation(self) -> None:
        """0x06 -> 0x07 -> 0x0F (L17150-L17161), each step confirmed in the statusword."""
        state = self.state
        if state == "FAULT":
            raise Cia402Fault(
                f"node {self.node_id}: expected a non-FAULT state to enable, "
                f"saw FAULT (statusword 0x{self.statusword:04X}); fault_reset()"
            )
        if state == "OPERATION ENABLED":
            return
        if state in ("SWITCH ON DISABLED", "NOT READY TO SWITCH ON", "QUICK STOP ACTIVE"):
            if state == "QUICK STOP ACTIVE":
                self._go(CW_DISABLE_VOLTAGE, "SWITCH ON DISABLED")
            self._go(CW_SHUTDOWN, "READY TO SWITCH ON")
        if self.state == "READY TO SWITCH ON":
            self._go(CW_SWITCH_ON, "SWITCHED ON")
        self._go(CW_ENABLE_OPERATION, "OPERATION ENABLED")

    def shutdown(self) -> None:
        """Controlword 0x06 -> READY TO SWITCH ON (transitions 2, 6, 8); from QUICK STOP
        ACTIVE through SWITCH ON DISABLED (12: the A3 takes 0x00 or 0x06 there, L18262)."""
        if self.state == "QUICK STOP ACTIVE":
            self._go(CW_DISABLE_VOLTAGE, "SWITCH ON DISABLED")
        self._go(CW_SHUTDOWN, "READY TO SWITCH ON")

    def disable_voltage(self) -> None:
        """Controlword 0x00 -> SWITCH ON DISABLED (transitions 7, 9, 10, 12)."""
        self._go(CW_DISABLE_VOLTAGE, "SWITCH ON DISABLED")

    def quick_stop(self) -> None:
        """Controlword 0x02 from OPERATION ENABLED -> QUICK STOP ACTIVE (transition 11)."""
        self._go(CW_QUICK_STOP, "QUICK STOP ACTIVE")

    def fault_reset(self) -> None:
        """Bit 7 rising edge (0x00 then 0x80) -> SWITCH ON DISABLED (transition 15).

        Outside FAULT the edge still resets alarms: "NMT reset or 0x6040 reset" clears
        AL111/AL112/AL3E3 (servo-on alarms / warnings, L19937, L19945, L20169). It is sent
        on top of the present controlword (read back: a plan may have written 6040h by
        other means), which is then restored: the power state stays."""
        if self.state != "FAULT":
            cw = self.read(0x6040, 0) & ~CW_FAULT_RESET
            self._step("controlword", value=cw | CW_FAULT_RESET, target="alarm reset")
            self._cw(cw | CW_FAULT_RESET)
            self._cw(cw)
            return
        self._cw(CW_DISABLE_VOLTAGE)
        self._cw(CW_FAULT_RESET)
        mask, value = STATES["SWITCH ON DISABLED"]
        try:
            self._wait(
                "SWITCH ON DISABLED after fault reset", "fault_reset", lambda sw: sw & mask == value
            )
        finally:
            self._cw(CW_DISABLE_VOLTAGE)

    # ------------------------------------------------------------------ modes
    def set_mode(self, mode: str) -> None:
        """Write 6060h and wait until 6061h shows it (raises, never logs-and-continues)."""
        if mode not in MODES:
            raise Cia402ModeError(
                f"unknown mode {mode!r}; the A3 supports {sorted(MODES)} "
                "(6502h = 0x6D, L19250-L19278)"
            )
        code = MODES[mode]
        self.write(0x6060, 0, code)
        t0, timeout = self.clock(), self.timeouts["mode"]
        while True:
            shown = self.read(0x6061)
            if shown == code:
                return
            elapsed = self.clock() - t0
            if elapsed >= timeout:
                raise Cia402ModeError(
                    f"node {self.node_id}: expected 6061h = {code} ({mode}) within "
                    f"{timeout:.3f} s (timeouts['mode']), saw {shown} "
                    f"({MODE_NAMES.get(shown, '?')}) after {elapsed:.3f} s"
                )
            self._pause(timeout - elapsed)

    def move_to(
        self,
        target: int,
        velocity: int,
        accel: int,
        decel: int,
        relative: bool = False,
        wait: bool = True,
    ) -> None:
        """PP move (L17143-L17206): set-point handshake on bits 4/12, then bit 10."""
        self.set_mode("PP")
        self.write(0x607A, 0, target)
        self.write(0x6081, 0, velocity)
        self.write(0x6083, 0, accel)
        self.write(0x6084, 0, decel)
        self.enable_operation()
        base = CW_ENABLE_OPERATION | (0x40 if relative else 0)
        self._cw(base)  # bit 4 low before the edge
        self._cw(base | 0x10)
        try:
            self._wait(
                "set-point acknowledge (bit 12)",
                "setpoint_ack",
                lambda sw: bool(sw & SW_BIT12),
                self._fault_reason,
                hint=_setpoint_hint,
            )
        except Cia402Timeout:
            self._cw(base)  # taken back: a set-point still waiting for a move never runs
            raise
        self._cw(base)
        if wait:
            self._wait(
                "target reached (bit 10)",
                "target_reached",
                lambda sw: bool(sw & SW_TARGET_REACHED) and not sw & SW_BIT12,
                self._fault_reason,
            )

    def jog(self, velocity: int) -> None:
        """PV (L17299-L17331): 60FFh = 0 before enabling, then the target velocity."""
        self.set_mode("PV")
        if self.state != "OPERATION ENABLED":
            self.write(0x60FF, 0, 0)
            self.enable_operation()
        self.write(0x60FF, 0, velocity)

    def torque(self, target: int) -> None:
        """PT (L17343-L17374): 6071h = 0 before enabling, then the target torque (0.1 %)."""
        self.set_mode("PT")
        if self.state != "OPERATION ENABLED":
            self.write(0x6071, 0, 0)
            self.enable_operation()
        self.write(0x6071, 0, target)

    def home(
        self,
        method: int,
        speeds: tuple[int, int] = (100, 20),
        accel: int = 100,
        offset: int = 0,
        timeout: float | None = None,
    ) -> int:
        """HM (L17249-L17288): 607Ch, 6098h, 6099h, 609Ah, bit 4 edge, wait bit 12 / 13."""
        self.set_mode("HM")
        self.write(0x607C, 0, offset)
        self.write(0x6098, 0, method)
        self.write(0x6099, 1, speeds[0])
        self.write(0x6099, 2, speeds[1])
        self.write(0x609A, 0, accel)
        self.enable_operation()
        self._cw(CW_ENABLE_OPERATION)
        self._cw(CW_ENABLE_OPERATION | 0x10)
        saved = self.timeouts["homing"]
        if timeout is not None:
            self.timeouts["homing"] = timeout
        try:

            def fail(sw: int) -> str | None:
                if sw & SW_BIT13:
                    return "homing error (bit 13)"
                return self._fault_reason(sw)

            sw = self._wait(
                "homing attained (bit 12)",
                "homing",
                lambda sw: bool(sw & SW_BIT12) and not sw & SW_BIT13,
                fail,
            )
        finally:
            self.timeouts["homing"] = saved
            self._cw(CW_ENABLE_OPERATION)
        return sw

    @staticmethod
    def _fault_reason(sw: int) -> str | None:
        return "FAULT" if sw & 0x08 else None
