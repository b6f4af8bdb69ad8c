"""The 32-bit position counters: the PUU command and feedback (6062h, 6064h) and what their
overflow means.

* A counter is 32 bits and wraps: 6062h, 6063h and 6064h read modulo 2^32 (cia402.py).
* Once the command or the feedback has passed the 32-bit range, the position coordinate means
  nothing: DO.HOME goes off (L15290: "on ... until the position counter, command or feedback,
  overflows") and DO.OVF (0x12, "position command / feedback overflow", L15310) comes on.
* A positioning command after that gives AL235 "position counter overflow" (L20083-20087,
  incremental system) and is not run (docs/manual-choices.md). A completed homing run clears
  it (L20091: "home again"), as does a power cycle (the counters start again).

The check runs every motion step against a bound in motor counts worked out once per e-gear
ratio, so it costs a comparison.
"""

from __future__ import annotations

from collections.abc import Callable

from hil.model.core import DriveCore

PUU_MAX = 0x7FFFFFFF


class PositionCounters:
    """Overflow of the PUU counters (attach with `attach_counters`)."""

    def __init__(self, drive: DriveCore, lose_home: Callable[[], None]) -> None:
        self.drive = drive
        self._lose_home = lose_home
        self.overflowed = False
        self._gear = drive.params.cached("P1.044", "P1.045")
        self._for: tuple[int, ...] | None = None
        self._bound = float("inf")

    def after_step(self) -> None:
        if self.overflowed:
            return
        gear = self._gear()
        if gear is not self._for:  # counts = PUU x P1.044 / P1.045 (L8518-8533)
            n, m = gear
            self._bound = (PUU_MAX + 0.5) * n / m if n > 0 and m > 0 else float("inf")
            self._for = gear
        ax = self.drive.axis
        b = self._bound
        if -b <= ax.user_position <= b and -b <= ax.user_demand <= b:
            return
        self.overflowed = True
        self.drive.dio.set_do_function("OVF", True)
        self._lose_home()

    def refuse(self) -> bool:
        """True (and AL235) when a positioning command must not run after an overflow."""
        if not self.overflowed:
            return False
        self.drive.alarms.raise_alarm("AL235")
        return True

    def clear(self) -> None:
        """The coordinate was set again (homing) or the drive restarted."""
        if self.overflowed:
            self.overflowed = False
            self.drive.dio.set_do_function("OVF", False)
            self.drive.alarms.clear("AL235")


def attach_counters(drive: DriveCore, lose_home: Callable[[], None]) -> PositionCounters:
    counters = PositionCounters(drive, lose_home)
    drive.hooks.step.append(counters.after_step)
    drive.hooks.boot.append(counters.clear)
    return counters
