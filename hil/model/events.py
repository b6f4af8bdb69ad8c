"""Events the model emits to whoever subscribed (faces, recorder). `t` is model time in ns."""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True, slots=True)
class DoChanged:
    """A DO line changed electrical level (True = output transistor conducting)."""

    t: int
    n: int
    level: bool
    function: str  # e.g. "BRKR", "ABSR", "" when unmapped


@dataclass(frozen=True, slots=True)
class FdbkChanged:
    """The STO feedback output FDBK changed (True = closed / short)."""

    t: int
    closed: bool


@dataclass(frozen=True, slots=True)
class BrakeChanged:
    """The motor's mechanical brake clamped or freed the shaft (`brake_release_ms` /
    `brake_engage_ms` after BRKR changed, §2.9 L1351-1382)."""

    t: int
    clamped: bool


@dataclass(frozen=True, slots=True)
class StateChanged:
    """The CiA 402 state changed (names as in CiA 402, e.g. "OPERATION ENABLED")."""

    t: int
    old: str
    new: str


@dataclass(frozen=True, slots=True)
class AlarmChanged:
    """An alarm or warning became active (active=True) or was cleared."""

    t: int
    code: str  # "AL500"
    active: bool
    emcy_code: int  # CiA 301/402 error code for the EMCY producer (0 when cleared/unknown)


@dataclass(frozen=True, slots=True)
class AlarmReset:
    """An alarm reset was asked for: "di" (ARST), "p0001" (P0.001 := 0), "6040h" (a fault
    reset): what L20199 names as clearing AL500 (`AlarmManager.reset`; a CANopen NMT reset,
    which clears only its own alarms, is none)."""

    t: int
    source: str


@dataclass(frozen=True, slots=True)
class ParamChanged:
    """A parameter's stored value changed (name like "P3.000")."""

    t: int
    name: str
    value: int


@dataclass(frozen=True, slots=True)
class PowerCycled:
    """The drive was power cycled (battery: whether the absolute encoder kept its data)."""

    t: int
    battery: bool


@dataclass(frozen=True, slots=True)
class InputChanged:
    """A DI terminal changed level (the bench's sensors, or `Drive.set_di`)."""

    t: int
    n: int
    closed: bool


@dataclass(frozen=True, slots=True)
class HomingPhase:
    """The homing engine entered a phase ("" idle, search, cross, index, stop, return ...)."""

    t: int
    phase: str


@dataclass(frozen=True, slots=True)
class CaptureLatched:
    """CAPTURE stored `value` (capture-source pulses) at data array `address` (capture.py)."""

    t: int
    address: int
    value: int


@dataclass(frozen=True, slots=True)
class CompareFired:
    """COMPARE matched point `index` (CMP_DATA `target`) and drove DO4 (compare.py)."""

    t: int
    index: int
    target: int


@dataclass(frozen=True, slots=True)
class ZPulse:
    """Ground truth: the motor passed its Z mark at `position_puu` (virtual mechanics)."""

    t: int
    position_puu: float


DriveEvent = (
    DoChanged | FdbkChanged | StateChanged | AlarmChanged | AlarmReset | ParamChanged
    | PowerCycled
    | InputChanged | HomingPhase | BrakeChanged | CaptureLatched | CompareFired | ZPulse
)
