"""Driving a bench to its declared safe state, and recording that it did.

Called by the runner on any failure, timeout, Ctrl-C/SIGTERM and at the end of every plan
(like a plug tearDown: always). Every action is attempted even if an earlier one failed, and
each is recorded on the SAFETY topic and the log. The order follows the manual's servo-off
path: disable voltage (controlword 0x00, L17135-17376) and SON off, optionally cut STO, then
wait for BRKR off, i.e. the brake engaged (§2.9, L1351-1382). Python is never the last line
of defence: hardware interlocks are.
"""

from __future__ import annotations

import time
from dataclasses import dataclass, field
from typing import Any

from hil.protocol.cia402 import CONTROLWORD


class DriveGone(Exception):
    """The drive (a virtual drive's process) is gone: no action on it can be confirmed."""


def _raise(e: Exception) -> None:
    raise e


@dataclass
class SafeReport:
    reason: str
    ok: bool = True
    actions: list[dict[str, Any]] = field(default_factory=list)
    duration_ns: int = 0


def go_safe(session: Any, reason: str, recorder: Any = None) -> SafeReport:
    """Drive every drive of `session` to `session.bench.safe_state`; never raises."""
    bench = session.bench
    safe = bench.safe_state
    if hasattr(session, "stop_faults"):
        session.stop_faults()  # injected faults end before the safe state needs the wire
    rep = SafeReport(reason)
    t0 = time.monotonic_ns()

    def act(drive: str, action: str, fn: Any, **extra: Any) -> None:
        try:
            detail = fn()
            ok = detail is not False
            msg = detail if isinstance(detail, str) else ""
        except DriveGone as e:
            ok, msg = False, str(e)
        except Exception as e:
            ok, msg = False, f"{type(e).__name__}: {e}"
        rep.actions.append({"drive": drive, "action": action, "ok": ok, "detail": msg, **extra})
        if not ok:
            rep.ok = False
        if recorder is not None:
            recorder.safety(action, reason, drive=drive, ok=ok, detail=msg, **extra)
            recorder.log("warning" if not ok else "info",
                         f"safe state: {drive}: {action} {'done' if ok else 'FAILED'}"
                         f"{': ' + msg if msg else ''} ({reason})", name="hil.safety")

    dead_drives = getattr(session, "dead_drives", None)
    dead = dead_drives() if callable(dead_drives) else {}
    for name, why in dead.items():  # nothing can be sent to it: say so, claim nothing
        act(name, "drive process alive", lambda why=why: _raise(DriveGone(why)))
    for name, d in session.drives.items():
        if name in dead:
            continue
        spec = d.spec
        cw = CONTROLWORD.get(safe.controlword)
        if cw is not None and spec.can and d._cia is not None:
            act(name, f"controlword {safe.controlword} (0x{cw:02X})",
                lambda d=d, cw=cw: d.cia.write(0x6040, 0, cw))
        for func, lv in safe.di.items():
            if func in spec.di:
                act(name, f"DI {func} {'on' if lv else 'off'}",
                    lambda d=d, f=func, lv=lv: d.set_function(f, lv))
        for ch, lv in safe.sto.items():
            if spec.dio:
                line = spec.sto[ch]
                act(name, f"STO {ch} {'on' if lv else 'off'}",
                    lambda d=d, line=line, lv=lv: d.set_line(line, lv))
    if safe.wait_brake:
        for name, d in session.drives.items():
            if "BRKR" not in d.spec.do or d.dio is None or name in dead:
                continue

            def brake(d: Any = d) -> Any:
                end = time.monotonic_ns() + safe.timeout_ns
                while time.monotonic_ns() < end:
                    if not d.do_active("BRKR"):
                        return "BRKR off: brake engaged"
                    time.sleep(0.002)
                return False

            act(name, "wait BRKR off (brake engaged)", brake,
                timeout_ms=safe.timeout_ns / 1e6)
    rep.duration_ns = time.monotonic_ns() - t0
    if recorder is not None:
        recorder.safety("safe_state_reached" if rep.ok else "safe_state_not_confirmed", reason,
                        ok=rep.ok, duration_ms=rep.duration_ns / 1e6)
    return rep
