"""The runner's side of the safe state: the session's drives as `hil.safety.SafeDrive`s.

The routine itself (what is done, in which order, what counts as done) is `hil/safety.py`,
shared with the gateway. This module adapts a `Session` to it and records each action on the
SAFETY topic and the log.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

from hil import clock
from hil.drivers.cia402 import decode_state
from hil.plan.context import SafeStateHung, safe_state_watchdog
from hil.protocol.cia402 import CONTROLWORD
from hil.safety import DriveGone, SafeReport, run_safe_state, wait_quick_stop

__all__ = ["CONTROLWORD", "DriveGone", "SafeReport", "go_safe"]


class _SessionDrive:
    """One `DriveIO` of a runner session, as the safe state reaches it."""

    def __init__(self, name: str, d: Any, gone: str | None) -> None:
        self.name, self.d, self._gone = name, d, gone

    def gone(self) -> str | None:
        return self._gone

    def has_controlword(self) -> bool:
        return bool(self.d.spec.can) and self.d._cia is not None

    def write_controlword(self, cw: int) -> Any:
        return self.d.cia.write(0x6040, 0, cw)

    def power_stage_off(self, timeout_ns: int) -> str:
        """6041h read back until bit 2 "operation enabled" is clear (L18321-18331): the
        state the controlword left is on the record (a timing spec judges it there)."""
        end = clock.monotonic_ns() + timeout_ns
        while True:
            sw = self.d.cia.statusword
            if not sw & 0x0004:
                return f"statusword 0x{sw:04X}: {decode_state(sw)}"
            left = end - clock.monotonic_ns()
            if left <= 0:
                raise TimeoutError(f"statusword 0x{sw:04X} ({decode_state(sw)}) after "
                                   f"{timeout_ns / 1e6:g} ms: the power stage is still on")
            clock.sleep(min(0.002, left / 1e9))  # the last look at the timeout itself

    def quick_stop_done(self, timeout_ns: int) -> str:
        """After the quick-stop controlword: until the ramp has ended (`wait_quick_stop`;
        a lost SDO answer is asked again until the deadline, the ramp goes on)."""
        def read(index: int) -> int | None:
            try:
                return self.d.cia.read(index)
            except Exception:  # SdoError, a timeout: the bus may be busy
                return None

        done, what = wait_quick_stop(read, timeout_ns, 0.002)
        if not done:
            raise TimeoutError(f"{what} after {timeout_ns / 1e6:g} ms")
        return what

    def di_wired(self, function: str) -> bool:
        return function in self.d.spec.di

    def set_di(self, function: str, active: bool) -> Any:
        return self.d.set_function(function, active)

    def has_sto(self) -> bool:
        return bool(self.d.spec.dio)

    def set_sto(self, channel: str, on: bool) -> Any:
        return self.d.set_line(self.d.spec.sto[channel], on)

    def has_brkr(self) -> bool:
        return "BRKR" in self.d.spec.do and self.d.dio is not None

    def brake_engaged(self, timeout_ns: int) -> str | bool:
        end = clock.monotonic_ns() + timeout_ns
        while True:  # looked at every 2 ms and at the timeout itself (helper-131: a BRKR off
            if not self.d.do_active("BRKR"):  # at the timeout was reported still on)
                return "BRKR off: brake engaged"
            left = end - clock.monotonic_ns()
            if left <= 0:
                break
            clock.sleep(min(0.002, left / 1e9))
        raise TimeoutError(f"BRKR still on after {timeout_ns / 1e6:g} ms: the brake may be "
                           "released")


def go_safe_watched(session: Any, reason: str, recorder: Any = None,
                    tail: Callable[[Any], None] | None = None) -> SafeReport:
    """`go_safe`, then `tail(session)` (the bench recorded on after it), on a virtual clock
    under the safe state's wall-clock watchdog (`safe_state_watchdog`): a clock event that
    hangs the run's thread is stopped, and the safe state is recorded and reported as not
    confirmed, saying so. The runner's plans and the `hil_session` fixture both go safe
    here; never raises SafeStateHung."""
    rep: SafeReport | None = None
    try:
        with safe_state_watchdog(session.bench.safe_state.timeout_ns):
            rep = go_safe(session, reason, recorder)
            if tail is not None:
                tail(session)
    except SafeStateHung as e:
        # in the safe state: which action hung is on the record (run_safe_state); after it,
        # in the tail, the safe state was reached and the record says so before this
        action = "safe_state_not_confirmed" if rep is None else "safe_tail_hung"
        hung = {"drive": "*", "action": action, "ok": False, "detail": str(e)}
        if recorder is not None:
            recorder.safety(action, reason, ok=False, detail=str(e))
            recorder.log("error", f"safe state: {e} ({reason})", name="hil.safety")
        rep = SafeReport(reason, ok=False, actions=[*(rep.actions if rep else []), hung],
                         duration_ns=rep.duration_ns if rep else 0)
    return rep


def go_safe(session: Any, reason: str, recorder: Any = None) -> SafeReport:
    """Drive every drive of `session` to `session.bench.safe_state`; never raises."""
    if hasattr(session, "stop_faults"):
        # injected faults end before the safe state needs the wire; a stuck DI stays at
        # its stuck level (not back to what the plan last asked) until the safe state sets it
        session.stop_faults(restore=False)
    stopped = session.stop_streams() if hasattr(session, "stop_streams") else 0
    if stopped and recorder is not None:  # set-point streams end before anything is disabled
        recorder.safety("setpoint_streams_stopped", reason, ok=True,
                        detail=f"{stopped} cyclic set-point stream(s) stopped")
    dead_drives = getattr(session, "dead_drives", None)
    dead = dead_drives() if callable(dead_drives) else {}
    drives = [_SessionDrive(n, d, dead.get(n)) for n, d in session.drives.items()]
    drives += [_SessionDrive(n, None, why) for n, why in dead.items()
               if n not in session.drives]

    def record(drive: str, action: str, ok: bool, msg: str, extra: dict[str, Any]) -> None:
        if recorder is None:
            return
        recorder.safety(action, reason, drive=drive, ok=ok, detail=msg, **extra)
        recorder.log("warning" if not ok else "info",
                     f"safe state: {drive}: {action} {'done' if ok else 'FAILED'}"
                     f"{': ' + msg if msg else ''} ({reason})", name="hil.safety")

    rep = run_safe_state(drives, session.bench.safe_state, reason, record)
    if recorder is not None:
        failed = "; ".join(f"{a['drive']}: {a['action']}: {a['detail']}"
                           for a in rep.actions if not a["ok"])
        recorder.safety("safe_state_reached" if rep.ok else "safe_state_not_confirmed", reason,
                        ok=rep.ok, duration_ms=rep.duration_ns / 1e6,
                        **({"detail": failed} if failed else {}))
    return rep


