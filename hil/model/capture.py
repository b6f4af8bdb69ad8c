"""High-speed position CAPTURE (A3 manual §7.2.2, L5148-5176; P5.036-P5.039 L11471-11542).

`attach_capture(core, pr=...)` wires a `Capture` into a drive (core.py). The rules, each
from the manual
(choices: docs/manual-choices.md#capture, `CaptureOptions` under `ModelOptions.extra["capture"]`):

* DI7 triggers, in hardware, in 5 µs (L5150): the terminal edge before the P2.009 filter; the
  capture acts `delay_us` after the edge (value = the capture axis position then; CAP_OK
  then). While CAPTURE is on,
  DI7 feeds no mapped function (L5150). P5.039.Z: 0 NO latches on the contact closing, 1 NC
  on its opening (L11530). `trigger: Z` loops the motor's Z pulse into the capture input
  instead (a bench wiring choice; seed 004 CAPTURE bit 4).
* Capture axis (P5.039.Y, L11524-11528): 3 CN2 = motor feedback Fb_PUU (P5.037 then equals
  monitor 00h and may not be written, L11485); 1 CN5 = the bench's auxiliary encoder
  (`cn5_per_puu` pulses per motor PUU); 2 CN1 = pulse command (not on the virtual bench:
  it stands still); 0 = CAPTURE inactive.
* P5.039.X bit0 starts (P5.038 > 0, DO.CAP_OK off); each capture stores Array[P5.036 + i] and
  decrements P5.038; at 0 CAP_OK on and bit0 clears (L5155); P5.038 stays 0 until written
  (bit0 = 1 with P5.038 = 0 is refused: the count "must be > 0", L5153). Only 0 may be written while
  bit0 = 1 (L5155). bit1: the first point resets the capture axis to P5.076 (first cycle only,
  L5176); bit2: the first point starts COMPARE unless it runs (L5157); bit3: PR#50 after the
  last point (L5158, every cycle L5176). P1.019.X bit0 cyclic: the count reloads and the data
  restart at P5.036 (L8139, L5153). P5.039.U: minimum interval between captures in ms;
  P1.020: masking range in capture-source pulses after each capture when P5.038 > 1 (L8156).
* P5.036 / P5.037 are writable only while CAPTURE is stopped (L11476, L11485); P5.038 reads
  the remaining count while it runs (L11494). Refusals are ParamErrors: SDO abort / Modbus
  exception, and AL213 when a PR WRITE asks for it (pr_engine).
* The last value is monitor 043 (2Bh, L15481) and the base of CAP position commands (L4471).
"""

from __future__ import annotations

from dataclasses import dataclass, fields
from typing import TYPE_CHECKING, Any

from hil.model.errors import OutOfRange, ReadOnly
from hil.model.events import CaptureLatched, ZPulse
from hil.model.motion import counts_to_puu, puu_to_counts
from hil.profile.pr import ARRAY_SIZE
from hil.units import MS, s32

if TYPE_CHECKING:
    from hil.model.compare import Compare
    from hil.model.core import DriveCore
    from hil.model.pr_engine import PrEngine

CAPTURE_DI = 7  # L5150
SOURCES = {0: "off", 1: "CN5", 2: "CN1", 3: "CN2"}  # P5.039.Y (L11524-11528)
TRIGGERS = ("DI7", "Z")


@dataclass
class CaptureOptions:
    """Choices (manual gaps) and deviation knobs (`dev_*`) of CAPTURE and COMPARE."""

    delay_us: float = 5.0  # DI7 edge -> latch: "執行時間僅需 5 μs" (L5150)
    compare_delay_us: float = 5.0  # compare match -> DO4: "5 μs" (L5188)
    trigger: str = "DI7"  # what drives the capture input on this bench: DI7 or the motor Z
    cn5_per_puu: float = 1.0  # CN5 auxiliary encoder pulses per motor PUU (bench wiring)
    compare_retrigger: bool = True  # a match during a DO4 pulse restarts its width
    # P5.039.Y locked when COMPARE's source is the capture axis (L11528, L11766): "running"
    # = only while COMPARE runs, "always" = whenever P5.059.Y = 0 (the note's letter)
    y_lock: str = "running"
    # --- deviations ---
    dev_capture_delay_us: float = 0.0  # extra latch delay after the edge
    dev_compare_width_extra_ms: float = 0.0  # DO4 pulse longer than P5.059.CBA
    dev_compare_late: int = 0  # DO4 fires this many compare pulses after the point
    dev_compare_positive_only: bool = False  # points match only while the axis moves up

    def __post_init__(self) -> None:
        if self.trigger not in TRIGGERS:
            raise ValueError(f"capture.trigger: {self.trigger!r} not one of {TRIGGERS}")
        if self.y_lock not in ("running", "always"):
            raise ValueError(f"capture.y_lock: {self.y_lock!r} not 'running' or 'always'")

    @classmethod
    def from_dict(cls, data: dict[str, Any] | None) -> CaptureOptions:
        data = dict(data or {})
        known = {f.name for f in fields(cls)}
        bad = sorted(set(data) - known)
        if bad:
            raise ValueError(f"capture options: unknown {', '.join(bad)}; known: "
                             f"{', '.join(sorted(known))}")
        return cls(**data)


class Capture:
    """The CAPTURE function of one drive."""

    def __init__(self, drive: DriveCore, options: CaptureOptions, pr: PrEngine) -> None:
        self.drive = drive
        self.pr = pr  # CAP commands' base, PR#50 (L4471, L5158)
        self.compare: Compare | None = None  # set by attach_compare
        self.options = options
        self.offset = 0.0  # capture axis = source position + offset
        self.running = False
        self.count_set = 1  # P5.038 as set when started (reloaded in cyclic mode)
        self.index = 0  # points stored in this cycle
        self.cycle = 0
        self.last_value: int | None = None  # monitor 043 (L15481)
        self.last_t: int | None = None
        self.values: list[tuple[int, int, int]] = []  # (t, array address, value)
        self._step_t = 0  # time of the previous motion step (Z crossing instants)

    # ------------------------------------------------------------------ axis
    @property
    def source(self) -> int:
        return (self.drive.params.get("P5.039") >> 4) & 0xF

    def source_position(self, counts: float | None = None) -> float:
        """Position of the capture source (P5.039.Y) at motor position `counts` (now)."""
        d = self.drive
        ax = d.axis
        user = (d.feedback_counts() if counts is None else counts) - ax.origin  # hardware
        puu = counts_to_puu(user, d.params.get("P1.044"), d.params.get("P1.045"))
        src = self.source
        if src == 3:
            return puu
        if src == 1:
            return puu * self.options.cn5_per_puu
        return 0.0  # CN1 pulse command: no pulses on the virtual bench

    def source_velocity(self) -> float:
        """Capture-source pulses per second now."""
        d = self.drive
        v = counts_to_puu(d.axis.velocity, d.params.get("P1.044"), d.params.get("P1.045"))
        return {3: v, 1: v * self.options.cn5_per_puu}.get(self.source, 0.0)

    def position(self, counts: float | None = None) -> float:
        """Capture axis position (P5.037); on CN2 the motor feedback position, monitor 00h
        (L11487), whatever offset another source left."""
        if self.source == 3:
            return self.source_position(counts)
        return self.source_position(counts) + self.offset

    def set_position(self, value: float) -> None:
        """Redefine the capture axis; on CN2 that redefines the motor coordinate (L11703). A
        COMPARE counting on it sees the jump as no motion: a point is fired when the axis
        passes it (L5093 "通過"), not when the axis is set past it."""
        compare = self.compare
        before = compare.position() if compare is not None and compare.running else None
        self._set_position(value)
        if before is not None:
            compare.shift(compare.position() - before)

    def _set_position(self, value: float) -> None:
        if self.source == 3:
            d = self.drive
            d.axis.set_user_position(puu_to_counts(value, d.params.get("P1.044"),
                                                   d.params.get("P1.045")))
            self.offset = 0.0
        else:
            self.offset = value - self.source_position()

    def power_up(self) -> None:
        """A power cycle stops CAPTURE; no capture has run since, so CAP_OK is off (L15323:
        capture done). P5.038 reads its stored value again (its count-down is RAM's)."""
        if self.running:
            self.stop()
        self.drive.dio.set_do_function("CAP_OK", False)

    # ------------------------------------------------------------------ parameters
    def validate_p5039(self, _name: str, value: int) -> None:
        old = self.drive.params.stored("P5.039")
        if value & 1 and not self.running and self.drive.params.stored("P5.038") <= 0:
            raise OutOfRange("P5.039", "P5.038 is 0: write the capture count first (it must "
                             "be > 0 for CAPTURE to act, L5153)")
        if self.running and value & 1:
            raise OutOfRange("P5.039", "CAPTURE runs (bit0 = 1): only 0 may be written to "
                             "stop it (L5155)")
        compare = self.compare
        if ((value >> 4) & 0xF) != ((old >> 4) & 0xF) and compare is not None \
                and compare.source == 0 \
                and (compare.running or self.options.y_lock == "always"):
            raise OutOfRange("P5.039", "COMPARE's source is the capture axis (P5.059.Y = 0): "
                             "P5.039.Y may not change (L11528)")
        if value & 1 and self.drive.params.stored("P5.036") + \
                self.drive.params.stored("P5.038") > ARRAY_SIZE:
            raise OutOfRange("P5.039", "P5.036 + P5.038 exceeds the 800-entry data array "
                             "(L11494)")

    def on_p5039(self, _name: str, old: int, new: int) -> None:
        if (old >> 4) & 0xF != (new >> 4) & 0xF:
            self.offset = 0.0  # a new source starts without the old one's offset
        if new & 1 and not self.running:
            self.start()
        elif not new & 1 and self.running:
            self.stop()

    def refuse_while_running(self, name: str, _value: int) -> None:
        if self.running:
            raise OutOfRange(name, "writable only while CAPTURE is stopped (L11476, L11485, "
                             "L11494)")
        if name == "P5.037" and self.source == 3:
            raise ReadOnly(name, "the capture axis is the motor feedback (CN2): not "
                           "writable (L11485)")

    # ------------------------------------------------------------------ run
    def start(self, reload: bool = False) -> None:
        """bit0 = 1: arm (L5155); `reload`: started by COMPARE with the previous count."""
        d = self.drive
        if reload:
            if d.params.stored("P5.038") <= 0:  # ended at 0: the previous count
                d.params.set_internal("P5.038", self.count_set, ram_only=True)
            if d.params.stored("P5.036") + d.params.stored("P5.038") > ARRAY_SIZE:
                return  # P5.038 <= P5.010 - P5.036 (L11491): not started, as a write is refused
            d.params.set_internal("P5.039", d.params.stored("P5.039") | 1)
        self.count_set = max(1, d.params.stored("P5.038"))
        self.running = self.source != 0  # Y = 0: "抓取功能不作用" (L11525)
        self.index = 0
        self.cycle = 0
        self.last_t = None
        d.dio.set_do_function("CAP_OK", False)
        d.dio.reserve_di(CAPTURE_DI, self.running and self.options.trigger == "DI7")

    def stop(self) -> None:
        self.running = False
        d = self.drive
        d.dio.reserve_di(CAPTURE_DI, False)
        d.params.set_internal("P5.039", d.params.stored("P5.039") & ~1)

    def on_di(self, n: int, closed: bool) -> None:
        """Raw terminal edge of a DI (before the filter)."""
        if n != CAPTURE_DI or self.options.trigger != "DI7" or not self.running:
            return
        nc = (self.drive.params.get("P5.039") >> 8) & 0xF
        if closed == (nc == 0):  # NO: latch on closing; NC: on opening (L11530)
            delay = round((self.options.delay_us + self.options.dev_capture_delay_us) * 1e3)
            d = self.drive  # the encoder is latched in hardware: between motion steps too
            if delay <= 0:
                self.latch(self.position(), d.now)
            else:  # the hardware latches `delay` later: the position then, CAP_OK then
                d.sched.after(delay, lambda: self.running and self.latch(
                    self.position(), d.now))

    def on_step(self) -> None:
        """`trigger: Z`: the Z pulses the last motion step passed (exact positions)."""
        d = self.drive
        t0, self._step_t = self._step_t, d.now
        if self.options.trigger != "Z" or not self.running:
            return
        ax = d.axis
        delay = (self.options.delay_us + self.options.dev_capture_delay_us) * 1e-6
        span = ax.position - ax.last_position
        for z in d.mech.index_crossed(ax.last_position, ax.position):
            t = t0 + round((d.now - t0) * (z - ax.last_position) / span) if span else d.now
            d.emit(ZPulse(t, self._truth_puu(z)))
            self.latch(self.position(z) + self.source_velocity() * delay, t + round(delay * 1e9))

    def _truth_puu(self, counts: float) -> float:
        d = self.drive
        return counts_to_puu(counts - d.axis.origin, d.params.get("P1.044"), d.params.get("P1.045"))

    def latch(self, value: float, t: int) -> None:
        """One capture: masking checks, store, count down, chained functions."""
        d, p = self.drive, self.drive.params
        min_ns = ((p.get("P5.039") >> 12) & 0xF) * MS  # P5.039.U [ms] (L11531)
        if self.last_t is not None and t - self.last_t < min_ns:
            return
        mask = p.get("P1.020")  # L8156: only when P5.038 > 1
        if self.last_value is not None and self.index and self.count_set > 1 and \
                abs(s32(round(value) - self.last_value)) < mask:  # on the 32-bit axis
            return
        ctrl = p.get("P5.039")
        first = self.index == 0
        if first and ctrl & 2 and self.cycle == 0:  # bit1: reset to P5.076 (L11518, L5176)
            reset = p.get("P5.076")
            self.set_position(reset - (value - self.position()))
            value = reset
        v = s32(round(value))  # a 32-bit axis and array entry (P5.037 range L11482, L5097)
        addr = p.get("P5.036") + self.index
        d.array[addr] = v
        self.index += 1
        self.last_value, self.last_t = v, t
        self.values.append((t, addr, v))
        self.pr.capture_puu = v  # base of CAP commands (L4471)
        remaining = self.count_set - self.index
        p.set_internal("P5.038", remaining, ram_only=True)
        d.emit(CaptureLatched(d.now, addr, v))
        compare = self.compare
        if first and ctrl & 4 and compare is not None and not compare.running:
            compare.start(reload=True)  # bit2 (L5157)
        if first and self.cycle > 0:
            d.dio.set_do_function("CAP_OK", False)  # a new cycle (L5174)
        if remaining > 0:
            return
        d.dio.set_do_function("CAP_OK", True)
        self.cycle += 1
        if ctrl & 8:
            self.pr.trigger(50, "CAPTURE")  # bit3: PR#50 (L5158)
        if p.get("P1.019") & 1:  # cyclic: reload, restart at P5.036 (L8139, L5176)
            self.index = 0
            p.set_internal("P5.038", self.count_set, ram_only=True)
        else:
            self.stop()  # P5.038 stays 0: "為零時抓取結束" (L5155)


def attach_capture(drive: DriveCore, options: CaptureOptions | None = None, *,
                   pr: PrEngine) -> Capture:
    """Create the CAPTURE function of `drive` and wire its parameters and DI7."""
    cap = Capture(drive, options or CaptureOptions.from_dict(drive.options.extra.get("capture")),
                  pr)
    params = drive.params
    params.on_validate("P5.039", cap.validate_p5039)
    params.on_write("P5.039", cap.on_p5039)
    for name in ("P5.036", "P5.037", "P5.038"):
        params.on_validate(name, cap.refuse_while_running)
    params.on_write("P5.037", lambda _n, _o, new: cap.set_position(new))
    params.on_read("P5.037", lambda: s32(round(cap.position())))  # 32 bits (L11482)
    drive.dio.on_raw(cap.on_di)
    drive.hooks.step.append(cap.on_step)
    drive.hooks.boot.append(cap.power_up)
    drive.hooks.monitors[43] = lambda: cap.last_value or 0  # CAP data, the last (L15481)
    return cap


__all__ = ["CAPTURE_DI", "Capture", "CaptureOptions", "attach_capture"]
