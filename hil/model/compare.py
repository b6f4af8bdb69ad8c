"""High-speed position COMPARE (A3 manual §7.2.3, L5186-5215; P5.056-P5.059 L11692-11781).

`attach_compare(core, capture=..., pr=...)` wires a `Compare` into a drive (after
`attach_capture`). Rules
(choices: docs/manual-choices.md#capture, `CaptureOptions`):

* The compare axis (P5.059.Y, L11751-11756): 0 the capture axis (then P5.039.Y is locked),
  1 CN5, 2 CN1 (still on the virtual bench), 3 CN2 = the motor with 4 x P1.046 pulses per
  revolution (P1.097 = 0; defaults give 10000 per rev, L5190); P5.057 reads it and may be
  written only while COMPARE is stopped and not on Y = 0 / 3 (L11703-11712).
* P5.059.X bit0 starts (P5.058 > 0); point i matches when the compare axis reaches
  CMP_DATA = Array[P5.056 + i] + P1.023 + P1.024 (L8217-8240), in either direction (choice:
  the manual says "相同", equal; a hardware comparator sees the crossing); DO4 pulses for
  P5.059.CBA ms `compare_delay_us` after the match ("5 μs", L5188); P5.059.Z: 0 NO (pulse =
  DO4 on) / 1 NC (pulse = DO4 off). While COMPARE is on, DO4 shows only the compare pulse
  (L5188). Each match decrements P5.058; at 0 COMPARE ends, bit0 clears and P5.058 stays 0
  until written (L11740, L11722).
  bit1 cyclic: P5.058 reloads (L11742); bit2: start CAPTURE after the last point unless it
  runs (L11744); bit3: P5.057 = 0 after the last point (L11746); U bit0: PR#45 after the last
  point (L11762). P1.019.Z bit0: P1.024 is used once, then zeroed (L8131, L8240).
* The match instant is exact: after each motion step the next crossing is predicted from the
  velocity and a timer fires there (the model integrates to timer deadlines); a crossing the
  prediction missed (acceleration) fires at the end of the step that passed it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from hil.model.capture import CaptureOptions
from hil.model.errors import OutOfRange, ReadOnly
from hil.model.events import CompareFired
from hil.model.motion import counts_to_puu
from hil.model.timebase import Timer
from hil.profile.pr import ARRAY_SIZE
from hil.units import MS, s32

if TYPE_CHECKING:
    from hil.model.capture import Capture
    from hil.model.core import DriveCore
    from hil.model.pr_engine import PrEngine

COMPARE_DO = 4  # L5188


class Compare:
    """The COMPARE function of one drive."""

    def __init__(self, drive: DriveCore, options: CaptureOptions, capture: Capture,
                 pr: PrEngine) -> None:
        self.drive = drive
        self.capture = capture  # the capture axis as source (P5.059.Y = 0), bit2 (L11744)
        self.pr = pr  # PR#45 (L11762)
        self.options = options
        self.offset = 0.0
        self.running = False
        self.count_set = 1
        self.index = 0
        self.fired: list[tuple[int, int, int]] = []  # (t of DO4 pulse start, index, target)
        self._last: float | None = None
        self._wake: Timer | None = None
        self._pulse_end: Timer | None = None
        self._pulsing = False

    # ------------------------------------------------------------------ axis
    @property
    def source(self) -> int:
        return (self.drive.params.get("P5.059") >> 4) & 0xF

    def _scale(self) -> float:
        """Compare-source pulses per motor encoder count."""
        d = self.drive
        src = self.source
        if src == 3:  # CN2: encoder output 4 x P1.046 per rev (L5190, L8556, L9053)
            den = d.params.get("P1.097")
            per_rev = 4 * d.params.get("P1.046") / (den if den else 1)
            return per_rev / d.axis.cpr
        puu_per_count = counts_to_puu(1.0, d.params.get("P1.044"), d.params.get("P1.045"))
        if src == 1:
            return puu_per_count * self.options.cn5_per_puu
        if src == 0:
            cap = self.capture
            return puu_per_count * ({3: 1.0, 1: self.options.cn5_per_puu}.get(cap.source, 0.0))
        return 0.0

    def position(self) -> float:
        """Compare axis position (P5.057)."""
        d = self.drive
        src = self.source
        if src == 0:
            return self.capture.position() + self.offset  # offset: only bit3's zeroing
        if src == 3:  # the encoder output counted from where P5.059.Y = 3 set it to monitor
            # 00h; a later homing or CAPTURE redefinition of the feedback does not move it
            # (L11712)
            return d.feedback_counts() * self._scale() + self.offset
        return (d.feedback_counts() - d.axis.origin) * self._scale() + self.offset  # hardware

    def reset_axis(self) -> None:
        """A new compare source (P5.059.Y) starts without the old one's offset; CN2 starts at
        the motor feedback position, monitor 00h (PUU, L11712)."""
        d = self.drive
        self.offset = 0.0
        if self.source == 3:
            fb_puu = counts_to_puu(d.feedback_counts() - d.axis.origin,
                                   d.params.get("P1.044"), d.params.get("P1.045"))
            self.offset = fb_puu - d.feedback_counts() * self._scale()

    def velocity(self) -> float:
        return self.drive.axis.velocity * self._scale()

    def target(self) -> int:
        """CMP_DATA of the next point (L8217-8240; monitor 037)."""
        p = self.drive.params
        addr = p.get("P5.056") + self.index
        base = self.drive.array[addr] if addr < ARRAY_SIZE else 0
        return s32(base + p.get("P1.023") + p.get("P1.024"))

    # ------------------------------------------------------------------ parameters
    def validate_p5059(self, _name: str, value: int) -> None:
        p = self.drive.params
        if self.running and value & 1:
            raise OutOfRange("P5.059", "COMPARE runs (bit0 = 1): only 0 may be written to "
                             "stop it (L11740)")
        if value & 1 and not self.running and p.stored("P5.058") <= 0:
            raise OutOfRange("P5.059", "P5.058 is 0: write the compare count first (it must "
                             "be > 0 for COMPARE to act, L5190)")
        if value & 1 and p.stored("P5.056") + p.stored("P5.058") > ARRAY_SIZE:
            raise OutOfRange("P5.059", "P5.056 + P5.058 exceeds the 800-entry data array "
                             "(L11717)")

    def on_p5059(self, _name: str, old: int, new: int) -> None:
        if (old >> 4) & 0xF != (new >> 4) & 0xF:
            self.reset_axis()
        if new & 1 and not self.running:
            self.start()
        elif not new & 1 and self.running:
            self.stop()

    def refuse_while_running(self, name: str, _value: int) -> None:
        if self.running:
            raise OutOfRange(name, "writable only while COMPARE is stopped (L11703, L11717)")
        if name == "P5.057" and self.source in (0, 3):
            raise ReadOnly(name, "the compare axis is the capture axis or CN2: not writable "
                           "(L11708-11712)")

    def set_position(self, value: float) -> None:
        jump = value - self.position()
        self.offset += jump
        self.shift(jump)

    def shift(self, jump: float) -> None:
        """The axis was redefined by `jump`: a redefinition passes no point (L5093 "通過")."""
        if self._last is not None:
            self._last += jump
        if self.running:
            self._predict()

    # ------------------------------------------------------------------ run
    def _idle_level(self) -> bool:
        return bool((self.drive.params.get("P5.059") >> 8) & 1)  # Z: 1 NC -> DO4 on idle

    def start(self, reload: bool = False) -> None:
        d = self.drive
        if reload:  # started by CAPTURE bit2 with the previous count (L5157)
            if d.params.stored("P5.058") <= 0:  # ended at 0: the previous count
                d.params.set_internal("P5.058", self.count_set, ram_only=True)
            if d.params.stored("P5.056") + d.params.stored("P5.058") > ARRAY_SIZE:
                return  # P5.058 <= P5.010 - P5.056 (L11719): not started, as a write is refused
            d.params.set_internal("P5.059", d.params.stored("P5.059") | 1)
        self.count_set = max(1, d.params.stored("P5.058"))
        self.index = 0
        self.running = True
        self._last = self.position()
        if not self._pulsing:
            d.dio.force_do(COMPARE_DO, self._idle_level())
        self._predict()

    def stop(self) -> None:
        d = self.drive
        self.running = False
        self._cancel_wake()
        d.params.set_internal("P5.059", d.params.stored("P5.059") & ~1)
        if not self._pulsing:
            d.dio.force_do(COMPARE_DO, None)

    def on_step(self) -> None:
        if not self.running:
            return
        self._check(exact=False)
        self._predict()

    @staticmethod
    def _near(goal: float, ref: float) -> float:
        """`goal`, a point of the 32-bit axis (P5.057, L11705), as the position nearest `ref`
        that the axis reads as it: past +2^31 - 1 the axis reads -2^31 (the position is
        counted unwrapped, the registers wrap). `goal` itself, exactly, when it is nearest."""
        gap = goal - ref
        if -0x80000000 <= gap < 0x80000000:
            return goal
        return goal + round((s32(gap) - gap) / 0x100000000) * 0x100000000  # whole turns

    def _crossed(self, last: float, now: float, tgt: float) -> bool:
        if self.options.dev_compare_positive_only:
            return last < tgt <= now
        return last < tgt <= now or last > tgt >= now

    def _check(self, exact: bool) -> None:
        p = self.position()
        last = self._last if self._last is not None else p
        self._last = p
        late = self.options.dev_compare_late
        while self.running:
            tgt = self.target()
            direction = 1 if p >= last else -1
            goal = self._near(tgt + late * direction, last)
            hit = self._crossed(last, p, goal)
            if exact and not hit:  # the predicted instant: rounding may leave p a hair short
                hit = abs(p - goal) <= max(1e-6, abs(self.velocity()) * 2e-9) and (
                    not self.options.dev_compare_positive_only or direction > 0)
                if hit:  # the point counts as passed: the next step must not cross it again
                    self._last = goal
            if not hit:
                return
            self._fire(tgt)
            last = goal
            exact = False  # a point at the same place fires when the axis passes it again

    def _predict(self) -> None:
        self._cancel_wake()
        if not self.running:
            return
        d = self.drive
        v = self.velocity()
        if v == 0:
            return
        p = self.position()
        goal = self._near(self.target() + self.options.dev_compare_late * (1 if v > 0 else -1), p)
        if goal == self._last:
            return  # the point just passed (a cyclic single point, equal points): not again
        dt = (goal - p) / v
        if 0 < dt * 1e9 <= 2 * d.step_ns:
            self._wake = d.sched.at(d.now + max(1, round(dt * 1e9)), self._on_wake)

    def _on_wake(self) -> None:
        self._wake = None
        if self.running:
            self._check(exact=True)
            self._predict()

    def _cancel_wake(self) -> None:
        if self._wake is not None:
            self._wake.cancel()
        self._wake = None

    def _fire(self, tgt: int) -> None:
        d, p = self.drive, self.drive.params
        d.emit(CompareFired(d.now, self.index, tgt))
        delay = max(0, round(self.options.compare_delay_us * 1e3))
        self.fired.append((d.now + delay, self.index, tgt))
        d.sched.after(delay, self._pulse_on) if delay else self._pulse_on()
        ctrl = p.get("P5.059")
        if p.get("P1.019") & 0x100:  # Z bit0: P1.024 used once, then 0 (L8131, L8240)
            p.set_internal("P1.024", 0)
        self.index += 1
        remaining = self.count_set - self.index
        p.set_internal("P5.058", remaining, ram_only=True)
        if remaining > 0:
            return
        if ctrl & 8:  # bit3: compare axis to 0 (L11746)
            self.set_position(0)
            self._last = 0.0
        cap = self.capture
        if ctrl & 4 and not cap.running:  # bit2: start CAPTURE (L11744)
            cap.start(reload=True)
        if (ctrl >> 12) & 1:  # U bit0: PR#45 (L11762)
            self.pr.trigger(45, "COMPARE")
        if ctrl & 2:  # cyclic: reload (L11742)
            self.index = 0
            p.set_internal("P5.058", self.count_set, ram_only=True)
        else:
            self.stop()  # P5.058 stays 0 (L11722)

    def _width_ns(self) -> int:
        cba = (self.drive.params.get("P5.059") >> 16) & 0xFFF  # CBA [ms] (L11770)
        return round((cba + self.options.dev_compare_width_extra_ms) * MS)

    def _pulse_on(self) -> None:
        d = self.drive
        if self._pulsing and not self.options.compare_retrigger:
            return
        self._pulsing = True
        d.dio.force_do(COMPARE_DO, not self._idle_level())
        if self._pulse_end is not None:
            self._pulse_end.cancel()
        self._pulse_end = d.sched.after(self._width_ns(), self._pulse_off)

    def _pulse_off(self) -> None:
        self._pulse_end = None
        self._pulsing = False
        d = self.drive
        d.dio.force_do(COMPARE_DO, self._idle_level() if self.running else None)


def attach_compare(drive: DriveCore, options: CaptureOptions | None = None, *,
                   capture: Capture, pr: PrEngine) -> Compare:
    """Create the COMPARE function of `drive` and wire its parameters."""
    cmp_ = Compare(drive, options or capture.options, capture, pr)
    capture.compare = cmp_
    params = drive.params
    params.on_validate("P5.059", cmp_.validate_p5059)
    params.on_write("P5.059", cmp_.on_p5059)
    for name in ("P5.056", "P5.057", "P5.058"):
        params.on_validate(name, cmp_.refuse_while_running)
    params.on_write("P5.057", lambda _n, _o, new: cmp_.set_position(new))
    params.on_read("P5.057", lambda: s32(round(cmp_.position())))  # 32 bits (L11705)
    drive.hooks.step.append(cmp_.on_step)
    drive.hooks.boot.append(lambda: cmp_.running and cmp_.stop())
    drive.hooks.boot.append(cmp_.reset_axis)  # the counters start afresh at power-up
    drive.hooks.monitors[37] = cmp_.target  # CMP_DATA of the next point (L15476, L8240)
    return cmp_


__all__ = ["COMPARE_DO", "Compare", "attach_compare"]
