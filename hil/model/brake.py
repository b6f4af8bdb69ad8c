"""Electromagnetic brake control: DO.BRKR per section 2.9.

BRKR On = brake coil energised = shaft free; BRKR Off = brake holds (§2.9, L1353).

* Servo on: BRKR On `P1.042` ms after the servo is enabled (P1.042 MBT1, L8492-8501).
* Servo off: BRKR Off at the earlier of `P1.043` ms after servo off and the motor speed
  below `P1.038` (L1359-1362, L8512-8515). "Below" is a level test, so a motor already at
  rest engages at once.
* A servo off caused by an alarm (except AL022) or by EMGS treats a negative P1.043 as 0
  (L8516). What a negative P1.043 means otherwise is undefined: `ModelOptions.negative_p1043`.
* The mechanical brake (`HoldingBrake`) is bench hardware: its coil hangs on one DO line
  (`Mechanics.brake_do`) and follows that line's level after the motor's release/engage
  times (Appendix A, L20485-20494: at most 70 ms; `Mechanics.brake_release_ms/engage_ms`).
  BRKR mapped to no DO (P2.041 = 0 ...) controls nothing (L15286, L9603).
"""

from __future__ import annotations

from collections.abc import Callable

from hil.model.options import ModelOptions
from hil.model.timebase import Scheduler, Timer, ms


class HoldingBrake:
    """The motor's spring-applied brake: coil energised = shaft free, after a delay."""

    def __init__(
        self,
        sched: Scheduler,
        on_clamp: Callable[[bool], None],
        release_ms: float = 20.0,
        engage_ms: float = 50.0,
    ) -> None:
        self._sched = sched
        self._on_clamp = on_clamp
        self.release_ms = release_ms
        self.engage_ms = engage_ms
        self.energised = False
        self.clamped = True  # mechanical state: the shaft is held
        self._mech: Timer | None = None

    def coil(self, energised: bool) -> None:
        """The coil's supply changed (the DO line it hangs on)."""
        energised = bool(energised)
        if energised == self.energised:
            return
        self.energised = energised
        if self._mech:
            self._mech.cancel()
        delay = self.release_ms if energised else self.engage_ms
        self._mech = self._sched.after(ms(delay), lambda: self._mechanical(not energised))

    def power_up(self, energised: bool | None) -> None:
        """Settle at power-up: `energised` = coil level now; None = no coil wired, no brake."""
        if self._mech:
            self._mech.cancel()
            self._mech = None
        self.energised = bool(energised)
        self.clamped = energised is not None and not energised
        self._on_clamp(self.clamped)

    def _mechanical(self, clamped: bool) -> None:
        self._mech = None
        if clamped != self.clamped:
            self.clamped = clamped
            self._on_clamp(clamped)


class Brake:
    """BRKR logic (the DO function); the mechanics is the bench's `HoldingBrake`."""

    def __init__(
        self,
        sched: Scheduler,
        param: Callable[[str], int],
        speed_rpm: Callable[[], float],
        on_brkr: Callable[[bool], None],
        options: ModelOptions,
    ) -> None:
        self._sched = sched
        self._param = param
        self._speed = speed_rpm
        self._on_brkr = on_brkr
        self._opt = options
        self.brkr = False  # DO function state: True = release the brake
        self._pending: Timer | None = None  # BRKR change waiting for its delay
        self._watch_speed = False  # servo off, waiting for |v| < P1.038

    # -- events from the drive -------------------------------------------------------------
    def servo_on(self) -> None:
        """Power stage enabled: BRKR On after P1.042 (L8499)."""
        self._cancel()
        delay = ms(self._param("P1.042") + self._opt.dev_brake_on_delay_ms)
        self._pending = self._sched.after(delay, lambda: self._set(True))

    def servo_off(self, cause: str = "normal", alarm: str | None = None) -> int:
        """Servo turned off. Returns ns the drive must keep torque (negative P1.043 only).

        `cause` is "normal" (SON dropped / controlword), "alarm" or "emgs".
        """
        self._cancel()
        p1043 = self._param("P1.043")  # ms, -1000..1000 (L8503-8516)
        fault_stop = cause == "emgs" or (cause == "alarm" and alarm != "AL022")
        if fault_stop and self._opt.dev_emgs_ignores_negative_rule:
            fault_stop = False  # deviation: the negative value is honoured on fault stops
        if p1043 < 0 and fault_stop:
            p1043 = 0  # L8516: negative value ignored, acts as 0
        if p1043 < 0:
            if self._opt.negative_p1043 == "as_zero":
                p1043 = 0
            else:  # "brake_first": clamp now, hold torque |P1.043| ms
                self._set(False)
                return ms(-p1043)
        delay = ms(p1043 + self._opt.dev_brake_off_delay_ms)
        if not self.brkr:
            return 0
        if delay <= 0 or (self._below_zspd() and not self._opt.dev_ignore_speed_rule):
            self._set(False)
            return 0
        self._pending = self._sched.after(delay, lambda: self._set(False))
        self._watch_speed = not self._opt.dev_ignore_speed_rule
        return 0

    def after_step(self) -> None:
        """Called after each motion substep: the speed rule of L1362."""
        if self._watch_speed and self._below_zspd():
            self._cancel()
            self._set(False)

    def reset(self) -> None:
        """Power off: no timer survives, BRKR off (the brake engages)."""
        self._cancel()
        self._set(False)

    # -- internals -------------------------------------------------------------------------
    def _below_zspd(self) -> bool:
        return abs(self._speed()) < self._param("P1.038") / 10.0  # P1.038 in 0.1 rpm

    def _cancel(self) -> None:
        self._watch_speed = False
        if self._pending:
            self._pending.cancel()
            self._pending = None

    def _set(self, release: bool) -> None:
        self._pending = None
        self._watch_speed = False
        if release == self.brkr:
            return
        self.brkr = release
        self._on_brkr(release)
