"""The seam between `Drive` and its parts: what a part may see of the drive.

Homing, PR, CAPTURE, COMPARE, the DI functions and the pulse-train input each get a
`DriveCore` (the shared pieces: parameters, DI/DO, axis, alarms, clock) plus the other parts
they work with, passed by name when they are attached. None imports `drive.py`, and each can
be built on a small core of its own in a test (tests/model/test_core_seam.py). brake.py and
sto.py go further and take only callables.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import TYPE_CHECKING, Protocol

from hil.profile.pr import ARRAY_SIZE

if TYPE_CHECKING:
    from hil.model.alarms import AlarmManager
    from hil.model.cia402 import Cia402
    from hil.model.dio import DigitalIO
    from hil.model.events import DriveEvent
    from hil.model.mechanics import Mechanics
    from hil.model.motion import Axis
    from hil.model.options import ModelOptions
    from hil.model.params import ParameterStore
    from hil.model.timebase import Scheduler


class Hooks:
    """Where parts hook into the drive's cycle: each list is called in order."""

    def __init__(self) -> None:
        self.step: list[Callable[[], None]] = []  # after each motion substep
        self.servo_on: list[Callable[[], None]] = []  # after the servo turned on
        self.servo_off: list[Callable[[], None]] = []  # after the servo turned off
        self.boot: list[Callable[[], None]] = []  # at power-up, before outputs settle
        # monitor codes (table L15440-L15483) a part computes, read through P0.009-P0.013
        self.monitors: dict[int, Callable[[], int]] = {}


def new_data_array() -> list[int]:
    """The data array (L5097: 800 32-bit entries) that PR, CAPTURE and COMPARE share."""
    return [0] * ARRAY_SIZE


class DriveCore(Protocol):
    """What a part of the drive may use (implemented by `hil.model.drive.Drive`)."""

    name: str
    options: ModelOptions
    sched: Scheduler
    params: ParameterStore
    dio: DigitalIO
    axis: Axis
    alarms: AlarmManager
    cia402: Cia402
    mech: Mechanics
    hooks: Hooks
    array: list[int]
    servo_on: bool
    powered: bool
    step_ns: int  # the motion grid (ModelOptions.motion_step_ms)

    @property
    def now(self) -> int: ...

    def emit(self, event: DriveEvent) -> None:
        """Hand a model event to the drive's subscribers (the ground truth, the faces)."""

    def commit_cycle(self) -> None:
        """An input inside a motion cycle acts from the next cycle (drive.py)."""

    def p5003_decel(self, digit: int) -> float:
        """Deceleration time (ms per 3000 rpm) of P5.003 digit `digit` (L11084-11100)."""

    def clear_position_error(self) -> None:
        """The motor position becomes the command end point (L7477-7491)."""

    def refresh_outputs(self) -> None:
        """Recompute the DO functions whose inputs changed outside a motion step."""

    def feedback_counts(self) -> float:
        """The motor position now, between two motion steps too."""

    def tpos(self) -> bool:
        """DO.TPOS (P1.054)."""

    def control_mode(self) -> str:
        """The table 8.1 control mode: "PT" "PR" "S" "T" "Sz" "Tz" or ""."""


__all__ = ["DriveCore", "Hooks", "new_data_array"]
