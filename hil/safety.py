"""The one safe-state routine: the runner's (hil/plan/safety.py) and the gateway's.

Called on any failure, timeout, Ctrl-C/SIGTERM, lost lease and at the end of every plan (like
a plug tearDown: always). Every action is attempted even if an earlier one failed, and each
is reported to `record` (the SAFETY topic and the log). The order follows the manual's
servo-off path: disable voltage (controlword 0x00, L17135-17376) and SON off, optionally cut
STO, then wait for BRKR off, i.e. the brake engaged (§2.9, L1351-1382). Python is never the
last line of defence: hardware interlocks are.

Who drives the lines differs (the runner's session, the gateway's exports); each supplies one
`SafeDrive` per drive, and this module decides what is done, in which order, and what counts
as done.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, Protocol

from hil import clock
from hil.protocol.cia402 import CONTROLWORD

# a drive at rest after a quick stop: 606Ch within the A3's zero-speed level P1.038's
# default, 10 rpm (0.1 rpm units, L8407)
STANDSTILL = 100

__all__ = ["DriveGone", "SafeDrive", "SafeReport", "SafeStateSpec", "Unanswered",
           "run_safe_state", "wait_quick_stop"]


def wait_quick_stop(read: Callable[[int], int | None], timeout_ns: int,
                    period_s: float) -> tuple[bool, str]:
    """After the quick-stop controlword, until the drive has left QUICK STOP ACTIVE by itself
    (6041h bit 2 clear) or is at rest (606Ch within `STANDSTILL`), reading objects with
    `read(index)` (None: no answer, asked again) every `period_s` until `timeout_ns`:
    (done, what was last seen)."""
    end = clock.monotonic_ns() + timeout_ns
    last = "no answer"
    while True:
        sw = read(0x6041)
        if sw is not None and not sw & 0x0004:
            return True, f"statusword 0x{sw & 0xFFFF:04X}: power stage off"
        v = read(0x606C) if sw is not None else None
        if v is not None:
            if abs(v) <= STANDSTILL:
                return True, f"606Ch = {v} (0.1 rpm): at rest"
            last = f"606Ch = {v} (0.1 rpm): still moving"
        left = end - clock.monotonic_ns()
        if left <= 0:
            return False, last
        clock.sleep(min(period_s, left / 1e9))  # the last look at the deadline itself


class DriveGone(Exception):
    """The drive (a virtual drive's process) is gone: no action on it can be confirmed."""


class SafeStateSpec(Protocol):
    """A bench file's `safe_state:` (hil.bench.bench.SafeState)."""

    controlword: str
    di: dict[str, bool]
    sto: dict[str, bool]
    wait_brake: bool
    timeout_ns: int


class SafeDrive(Protocol):
    """One drive as the safe state reaches it. A method returns a detail string (done), False
    (not confirmed) or raises; `None` from a `has_*` / `wired` query means "skip"."""

    name: str

    def gone(self) -> str | None:
        """Why nothing can be sent to this drive (its process died), or None."""

    def has_controlword(self) -> bool: ...

    def write_controlword(self, cw: int) -> str | bool | None: ...

    # optional: read the statusword back until bit 2 "operation enabled" (L18321-18331) is
    # clear, i.e. the power stage is off (SWITCH ON DISABLED, or FAULT), within `timeout_ns`
    # def power_stage_off(self, timeout_ns: int) -> str | bool: ...

    # optional, for the `quick_stop` controlword: until the quick stop's ramp has ended (the
    # motor at rest, or the drive out of QUICK STOP ACTIVE by itself), within `timeout_ns`;
    # the safe state then writes disable voltage (transition 12, L18262)
    # def quick_stop_done(self, timeout_ns: int) -> str | bool: ...

    def di_wired(self, function: str) -> bool: ...

    def set_di(self, function: str, active: bool) -> Any: ...

    def has_sto(self) -> bool: ...

    def set_sto(self, channel: str, on: bool) -> Any: ...

    def has_brkr(self) -> bool: ...

    def brake_engaged(self, timeout_ns: int) -> str | bool: ...


@dataclass
class SafeReport:
    reason: str
    ok: bool = True
    actions: list[dict[str, Any]] = field(default_factory=list)
    duration_ns: int = 0


#: record(drive, action, ok, detail, extra) -> None
Record = Callable[[str, str, bool, str, dict[str, Any]], None]


def _raise(e: Exception) -> None:
    raise e


class Unanswered(TimeoutError):
    """A command was sent but no answer said it was taken (an SDO download without its
    response): not confirmed, but maybe acting (a quick stop's ramp is still waited for)."""


def run_safe_state(drives: list[SafeDrive], safe: SafeStateSpec, reason: str,
                   record: Record | None = None) -> SafeReport:
    """Drive every drive to `safe`; never raises. Returns what was done and whether it held."""
    rep = SafeReport(reason)
    t0 = clock.monotonic_ns()

    def act(drive: str, action: str, fn: Callable[[], Any], **extra: Any) -> None:
        try:
            detail = fn()
            ok = detail is not False
            msg = detail if isinstance(detail, str) else "" if ok else "not confirmed"
        except DriveGone as e:
            ok, msg = False, str(e)
        except Unanswered as e:  # sent: what follows it (a ramp) may still confirm it
            ok, msg, extra = False, f"not confirmed: {e}", {**extra, "sent": True}
        except Exception as e:
            ok, msg = False, f"{type(e).__name__}: {e}"
        except BaseException as e:  # the safe state's watchdog cut it: which drive and
            if record is not None:  # action hung is on the record before it goes on up
                record(drive, action, False, f"{type(e).__name__}: {e}", extra)
            raise
        rep.actions.append({"drive": drive, "action": action, "ok": ok, "detail": msg, **extra})
        if not ok:
            rep.ok = False
        if record is not None:
            record(drive, action, ok, msg, extra)

    live = []
    for d in drives:  # a dead drive: say so, claim nothing
        why = d.gone()
        if why is not None:
            act(d.name, "drive process alive", lambda why=why: _raise(DriveGone(why)))
        else:
            live.append(d)
    cw = CONTROLWORD.get(safe.controlword)
    quick = safe.controlword == "quick_stop"
    sent: dict[str, bool] = {}  # the quick stop written to every drive first: all ramp at once
    if cw is not None and quick:
        for d in live:
            if d.has_controlword():
                act(d.name, f"controlword {safe.controlword} (0x{cw:02X})",
                    lambda d=d, cw=cw: d.write_controlword(cw))
                last = rep.actions[-1]
                sent[d.name] = bool(last["ok"] or last.get("sent"))  # unanswered: may ramp
    # a drive whose quick stop failed is not stopping: it is made safe first, waiting on no
    # other drive's ramp (stable: the others keep their order)
    for d in sorted(live, key=lambda d: sent.get(d.name, True)):
        if cw is not None and d.has_controlword():
            if not quick:
                act(d.name, f"controlword {safe.controlword} (0x{cw:02X})",
                    lambda d=d, cw=cw: d.write_controlword(cw))
            else:
                # the A3 stays in QUICK STOP ACTIVE, the servo on, until a command: transition
                # 12 "Command Disable Voltage" (L18262): after the ramp, the power stage off
                stopped = getattr(d, "quick_stop_done", None)
                if stopped is not None and sent.get(d.name):  # no ramp if 0x02 failed
                    act(d.name, "quick stop ramp ended",
                        lambda s=stopped: s(safe.timeout_ns), timeout_ms=safe.timeout_ns / 1e6)
                act(d.name, f"controlword disable_voltage (0x{CONTROLWORD['disable_voltage']:02X})"
                    " after the quick stop (transition 12)",
                    lambda d=d: d.write_controlword(CONTROLWORD["disable_voltage"]))
            confirm = getattr(d, "power_stage_off", None)
            if confirm is not None and rep.actions[-1]["ok"]:  # the state it left, read back
                act(d.name, "statusword: power stage off",
                    lambda c=confirm: c(safe.timeout_ns), timeout_ms=safe.timeout_ns / 1e6)
        for func, active in safe.di.items():
            if d.di_wired(func):
                act(d.name, f"DI {func} {'on' if active else 'off'}",
                    lambda d=d, f=func, a=active: d.set_di(f, a))
        if d.has_sto():
            for ch, on in safe.sto.items():
                act(d.name, f"STO {ch} {'on' if on else 'off'}",
                    lambda d=d, ch=ch, on=on: d.set_sto(ch, on))
    if safe.wait_brake:
        for d in live:
            if d.has_brkr():
                act(d.name, "wait BRKR off (brake engaged)",
                    lambda d=d: d.brake_engaged(safe.timeout_ns),
                    timeout_ms=safe.timeout_ns / 1e6)
    rep.duration_ns = clock.monotonic_ns() - t0
    return rep
